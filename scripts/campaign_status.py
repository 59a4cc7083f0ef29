#!/usr/bin/env python3
"""Where queues of scripts/campaign.sh stand: each line's state and the episodes left.

usage: python3 scripts/campaign_status.py QUEUE_FILE [QUEUE_FILE ...] [--all]

A line is `archived` (docs/campaign/results/NAME-seedS/summary.json), `done` (finished in
runs/campaign, not archived yet), `running` (a live process names its run directory),
`stopped` (a run directory without a summary: started again it resumes or starts over),
`copied` (a fork's directory made from its source at design K, its own episodes not begun) or
`pending`. Episodes left: the run's schedule (its config.toml, or the queue's CONFIG with its
overrides and `--designs`) minus the rows of its episodes.csv; a fork line counts from its
design K; a retrain line counts two trainings of 30 episodes. The last line per queue sums them
with the hours they take at the pace of the queue's finished co-adaptation runs, when there are
some: episodes per hour of one lane, from the learner's clock in the last rows of episodes.csv
(every start of a resumed run; a fork's own rows only; summary.json's seconds count the last
start alone). --all lists the finished lines too.
"""
import csv
import os
import re
import sys
import tomllib

RESULTS = "docs/campaign/results"
RUNS = "runs/campaign"


def load(path):
    with open(path, "rb") as f:
        return tomllib.load(f)


def config_of(spec):
    """The config dict of a queue CONFIG (`base+key.path=value+...`)."""
    base, *overrides = spec.split("+")
    cfg = load(base)
    for o in overrides:
        key, value = o.split("=", 1)
        *path, leaf = key.split(".")
        t = cfg
        for p in path:
            t = t.setdefault(p, {})
        t[leaf] = tomllib.loads(f"v = {value}")["v"]
    return cfg


def episodes_per_design(cfg, designs=None):
    """Episodes of each design of a run of this config, in order."""
    s = cfg.get("schedule", {})
    n = designs or s.get("designs", 1)
    initial = len(s.get("initial-designs", [])) or 1
    return [s.get("initial-episodes", 0) if i < initial else s.get("episodes-per-design", 0) for i in range(n)]


def rows(path):
    try:
        with open(path) as f:
            return sum(1 for _ in csv.DictReader(f))
    except OSError:
        return 0


def pace_of(run_dir, skip):
    """Episodes per hour of the rows of run_dir/episodes.csv after the first `skip` (a fork's
    copied prefix), by the learner's clock (the seconds column, which goes on across resumes),
    or None."""
    try:
        with open(f"{run_dir}/episodes.csv") as f:
            secs = [float(r["seconds"]) for r in csv.DictReader(f)]
    except (OSError, KeyError, ValueError, TypeError):
        return None
    start = secs[skip - 1] if 0 < skip <= len(secs) else 0.0
    if len(secs) <= skip or secs[-1] <= start:
        return None
    return (len(secs) - skip) / ((secs[-1] - start) / 3600)


def live_dirs():
    """Run directories (real paths) named on the command line of a live process that is not a
    fork's watcher (scripts/fork_run.sh names the fork it waits to make)."""
    out = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            args = [a.decode(errors="replace") for a in open(f"/proc/{pid}/cmdline", "rb").read().split(b"\0")]
            cwd = os.readlink(f"/proc/{pid}/cwd")
        except OSError:
            continue
        if any(a.endswith("fork_run.sh") for a in args):
            continue
        for a in args:
            if "runs/campaign/" in a:
                path = os.path.realpath(os.path.join(cwd, a.rstrip("/")))
                out.add(path)
                # A retrain line's `coadapt train` names a seed's directory inside the run's.
                if re.fullmatch(r"train-seed\d+", os.path.basename(path)):
                    out.add(os.path.dirname(path))
    return out


def parse(queue):
    lines = []
    with open(queue) as f:
        for n, line in enumerate(f, 1):
            words = line.split()
            if not words or words[0].startswith("#"):
                continue
            if len(words) < 3:
                sys.exit(f"campaign_status: {queue}:{n}: want NAME CONFIG SEED, got {line.strip()!r}")
            lines.append((words[0], words[1], words[2], words[3:]))
    return lines


def plan(name, spec, seed, flags, queue_lines):
    """Episodes of the whole run and the design it starts at (a fork's K), or None."""
    designs = None
    if "--designs" in flags:
        designs = int(flags[flags.index("--designs") + 1])
    if spec.startswith("retrain:"):
        return [30, 30], 0
    if spec.startswith("fork:"):
        src, rest = spec[len("fork:"):].split(":", 1)
        k = int(rest.split("+")[0])
        for n2, s2, seed2, f2 in queue_lines:
            if n2 == src and seed2 == seed and not s2.startswith(("fork:", "retrain:")):
                eps, _ = plan(n2, s2, seed2, f2, queue_lines)
                return eps, k
        for d in (f"{RESULTS}/{src}-seed{seed}", f"{RUNS}/{src}-seed{seed}"):
            if os.path.exists(f"{d}/config.toml"):
                return episodes_per_design(load(f"{d}/config.toml")), k
        return None, k
    base = spec[len("random-only:"):] if spec.startswith("random-only:") else spec
    try:
        return episodes_per_design(config_of(base), designs), 0
    except (OSError, ValueError, tomllib.TOMLDecodeError):
        return None, 0


def main():
    args = [a for a in sys.argv[1:] if a != "--all"]
    if not args or "-h" in args or "--help" in args:
        print(__doc__.strip())
        sys.exit(0 if args else 2)
    show_all = "--all" in sys.argv
    live = live_dirs()
    for queue in args:
        lines = parse(queue)
        counts, left, paces = {}, 0, []
        print(f"== {queue}")
        for name, spec, seed, flags in lines:
            run = f"{name}-seed{seed}"
            d, a = f"{RUNS}/{run}", f"{RESULTS}/{run}"
            eps, k = plan(name, spec, seed, flags, lines)
            total = sum(eps[k:]) if eps else None
            done_rows = 0 if spec.startswith("retrain:") else rows(f"{d}/episodes.csv")
            if spec.startswith("retrain:"):
                done_rows = sum(rows(f"{d}/train-seed{i}/episodes.csv") for i in (1, 2))
            elif eps and k:
                done_rows = max(0, done_rows - sum(eps[:k]))
            summary = next((p for p in (f"{a}/summary.json", f"{d}/summary.json") if os.path.exists(p)), None)
            if summary:
                state = "archived" if summary.startswith(RESULTS) else "done"
                if not spec.startswith("retrain:"):
                    # Retrains (plain SAC, updates per step) keep another pace: not mixed in.
                    p = pace_of(os.path.dirname(summary), sum(eps[:k]) if eps and k else 0)
                    if p:
                        paces.append(p)
            elif os.path.realpath(d) in live:
                state = "running"
            elif os.path.exists(d):
                # A fork's watcher copies it when its source reaches design K; until its lane
                # starts it, it holds the source's rows only.
                own = rows(f"{d}/episodes.csv") - (sum(eps[:k]) if eps and k else 0)
                state = "copied" if k and own <= 0 else "stopped"
            else:
                state = "pending"
            counts[state] = counts.get(state, 0) + 1
            rest = None if total is None else max(0, total - done_rows)
            if state not in ("archived", "done"):
                left += rest or 0
            if state not in ("archived", "done") or show_all:
                progress = "?" if total is None else f"{min(done_rows, total)}/{total} episodes"
                print(f"  {state:8} {run:40} {progress}")
        pace = sorted(paces)[len(paces) // 2] if paces else None
        hours = f", about {left / pace:.1f} lane-hours at the median pace of its finished runs ({pace:.0f} episodes/h)" if pace and left else ""
        tally = ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "no lines"
        print(f"  -- {tally}; {left} episodes left{hours}")


if __name__ == "__main__":
    main()
