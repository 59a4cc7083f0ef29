#!/usr/bin/env python3
"""Where queues of scripts/campaign.sh stand: each line's state and the episodes left.

usage: python3 scripts/campaign_status.py QUEUE_FILE [QUEUE_FILE ...] [--all]
       python3 scripts/campaign_status.py QUEUE_FILE --seconds NAME SEED [--threads N]

A line is `archived` (docs/campaign/results/NAME-seedS/summary.json), `done` (finished in
runs/campaign, not archived yet), `running` (a live process names its run directory), `stopped`
(a run directory without a summary: started again it resumes or starts over), `copied` (a fork's
directory made from its source at design K, its own episodes not begun), `prefix` (a fork whose
source's first K designs are being run again, its directory gone) or `pending`. Episodes left:
the run's schedule (its config.toml, or the queue's CONFIG with its overrides and `--designs`)
minus the rows of its episodes.csv, and the minutes of one lane they take (--seconds below); a
fork line counts from its design K; a retrain line counts two trainings of 30 episodes. The last
line per queue sums them with the hours they take at the pace of the queue's finished co-
adaptation runs, when there are some: episodes per hour of one lane, from the learner's clock in
the last rows of episodes.csv (every start of a resumed run; a fork's own rows only;
summary.json's seconds count the last start alone). --all lists the finished lines too.

--seconds NAME SEED prints the seconds of one lane the line NAME SEED of QUEUE_FILE needs from
where it stands (what `scripts/campaign.sh --until` asks before it starts a line), or exits 3
when no finished run gives a pace. It counts what the line would run first: a fork source's
prefix run again (its directory gone), an --init-population source run again; a retrain line
whose source is not finished has no estimate. The pace is, in order: the line's own rows (a run
under way or stopped: ten rows at least after its initial designs and a fork's prefix), the
archived runs of the same NAME (other seeds), else the same robot's (config's `env`) times the
method's pace relative to FEAR's on the other robots (at most 1), else the queue's finished
runs, each scaled by this machine's speed against the archive (its run directories' own paces);
a retrain line's, the same robot's archived retrains' seconds per training seed. --threads 2 (a
lone lane of THREADS=2) divides what the archive gives by 1.6, the measured gain of a second
thread.
"""
import csv
import functools
import os
import re
import sys
import tomllib

RESULTS = "docs/campaign/results"
RUNS = "runs/campaign"


# The MuJoCo bridge's address before 2026-12-03 (the design service's default port), in the
# archived MuJoCo configs; the campaign runs them against the bridge where it is now
# (scripts/campaign_lines.sh, bridge_here), and a robot's pace is looked up by its env.
OLD_BRIDGE = "dm-env-rpc://127.0.0.1:50061"


def load(path):
    with open(path, "rb") as f:
        cfg = tomllib.load(f)
    if cfg.get("env") == OLD_BRIDGE:
        cfg["env"] = "dm-env-rpc://" + os.environ.get("MUJOCO_BRIDGE", "127.0.0.1:50071")
    return cfg


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
    try:
        f = open(queue)
    except OSError as e:
        sys.exit(f"campaign_status: cannot read queue file {queue}: {e.strerror}")
    with f:
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


def median(xs):
    xs = sorted(xs)
    return xs[len(xs) // 2] if xs else None


def env_of(path):
    try:
        return load(path).get("env")
    except (OSError, tomllib.TOMLDecodeError):
        return None


def fork_k(run_dir):
    """A fork's K (its forked-from.txt: `... at the start of design K ...`), else 0."""
    try:
        m = re.search(r"at the start of design (\d+)", open(f"{run_dir}/forked-from.txt").read())
    except OSError:
        return 0
    if not m:
        return 0
    k = int(m.group(1))
    try:
        return sum(episodes_per_design(load(f"{run_dir}/config.toml"))[:k])
    except (OSError, tomllib.TOMLDecodeError):
        return 0


@functools.lru_cache(maxsize=None)
def archived(config):
    """(name, env, run dir) of every archived run, the env read from the run's CONFIG (a path
    inside it)."""
    try:
        runs = sorted(os.listdir(RESULTS))
    except OSError:
        return []
    out = []
    for run in runs:
        m = re.fullmatch(r"(.+)-seed\d+", run)
        d = f"{RESULTS}/{run}"
        if m and os.path.exists(f"{d}/summary.json"):
            out.append((m.group(1), env_of(f"{d}/{config}"), d))
    return out


def own_skip(run_dir):
    """Episodes of a run directory's rows that are not its own pace: its initial designs' (the
    networks train less per episode there) or a fork's copied prefix, whichever is more; None
    without a config."""
    try:
        cfg = load(f"{run_dir}/config.toml")
    except (OSError, tomllib.TOMLDecodeError):
        return None
    initial = len(cfg.get("schedule", {}).get("initial-designs", [])) or 1
    return max(fork_k(run_dir), sum(episodes_per_design(cfg)[:initial]))


@functools.lru_cache(maxsize=None)
def speed():
    """This machine's pace against the archive's: the median, over the run directories here
    with ten rows of their own at least, of their own pace over what the archive gives for them
    (AVX-512 machines ran 1.5-2.75x the archived paces), within [0.5, 3]; 1 without any. The
    archive it is set against leaves out the runs made here (their run directories are here):
    else every run that ends here and is archived pulls the factor towards 1."""
    return speed_detail()[0]


@functools.lru_cache(maxsize=None)
def speed_detail():
    """(speed(), the unclamped median, how many run directories it is over)."""
    ratios = []
    for run in sorted(here_runs()):
        m = re.fullmatch(r"(.+)-seed\d+", run)
        d = f"{RUNS}/{run}"
        skip = own_skip(d) if m and os.path.isdir(d) else None
        if skip is None or rows(f"{d}/episodes.csv") - skip < 10:
            continue
        own, archive = pace_of(d, skip), archive_pace(m.group(1), env_of(f"{d}/config.toml"), None, here_runs())
        if own and archive:
            ratios.append(own / archive)
    if not ratios:
        return 1.0, None, 0
    raw = median(ratios)
    return min(3.0, max(0.5, raw)), raw, len(ratios)


def coadapt_pace(name, env, queue_pace):
    """Episodes per hour for a co-adaptation line on this machine: see --seconds."""
    return archive_pace(name, env, queue_pace, scaled=True)


@functools.lru_cache(maxsize=None)
def here_runs():
    """The names of the run directories here: the archived runs made on this machine."""
    try:
        return frozenset(os.listdir(RUNS))
    except OSError:
        return frozenset()


def machine_factor(d):
    """How much faster this machine runs than the one that made the archived run D: 1 for a run
    made here, speed() for one made elsewhere (paces are multiplied by it, seconds divided)."""
    return 1.0 if os.path.basename(d) in here_runs() else speed()


@functools.lru_cache(maxsize=None)
def archive_pace(name, env, queue_pace, without=frozenset(), scaled=False):
    """Episodes per hour for a co-adaptation line by the archive's paces (leaving out the
    archived runs named in WITHOUT); SCALED: each in this machine's terms (machine_factor)."""
    runs = [(n, e, d) for n, e, d in archived("config.toml")
            if os.path.exists(f"{d}/episodes.csv") and os.path.basename(d) not in without]

    def one(d):
        x = pace_of(d, fork_k(d))
        return x * machine_factor(d) if x and scaled else x

    def pace(pick):
        return median([x for x in (one(d) for n, e, d in runs if pick(n, e)) if x])

    same_name = pace(lambda n, e: n == name)
    if same_name:
        return same_name
    # The same robot's pace times the method's cost relative to FEAR on the other robots (its
    # name without the robot's prefix: `daisy-bench-sim-pso` is `sim-pso`, 0.7 of FEAR's pace on
    # HalfCheetah, Walker and Hopper): a method's own work (the simulation baseline's rollouts)
    # can cost more than the robot's episodes.
    robot = pace(lambda n, e: env is not None and e == env)
    if not robot:
        # QUEUE_PACE is in this machine's terms already (queue_pace): the runs made here were
        # scaled again by speed() before, the archive's other runs once.
        return queue_pace
    method = method_of(name)
    ratios = []
    for n2 in {n for n, e, d in runs if method_of(n) == method and n != name}:
        fear = n2[: len(n2) - len(method)] + "fear"
        a, b = pace(lambda n, e: n == n2), pace(lambda n, e: n == fear)
        if a and b and fear != n2:
            ratios.append(a / b)
    return robot * min(1.0, median(ratios) or 1.0)


def method_of(name):
    """A line's method: its name without the robot's prefix (`hc-`, `walker-bench-`, ...)."""
    return re.sub(r"^[a-z]+-bench-|^hc-", "", name)


@functools.lru_cache(maxsize=None)
def seconds_per_train_seed(env):
    """Median seconds of one training seed of a retrain line (episodes.csv's wall_s at its end), on
    this machine; for a robot without retrains, sized by its co-adaptation pace."""
    def secs(d):
        out = []
        for k in (1, 2):
            try:
                with open(f"{d}/train-seed{k}/episodes.csv") as f:
                    last = list(csv.DictReader(f))[-1]
                out.append(float(last["wall_s"]))
            except (OSError, IndexError, KeyError, ValueError):
                pass
        return out
    # The same work for every method (plain SAC on one body): the robot's retrains.
    # Each in this machine's terms: seconds shrink as paces grow.
    retrains = [(e, x / machine_factor(d)) for n, e, d in archived("train-seed1/config.toml")
                if e is not None for x in secs(d) if x > 0]
    own = median([x for e, x in retrains if e == env])
    if own or env is None:
        return own
    # A robot never retrained: its co-adaptation runs' pace times what a training seed costs in
    # co-adaptation episodes on the robots that were (30 episodes of SAC on one body cost 24 to
    # 36 of FEAR's on HalfCheetah, Walker, Hopper and Daisy): else --until never starts the line.
    here = robot_pace(env)
    costs = [median([x for e2, x in retrains if e2 == e]) * p / 3600
             for e in sorted({e for e, _ in retrains}) for p in [robot_pace(e)] if p]
    cost = median(costs)
    return cost * 3600 / here if here and cost else None


def robot_pace(env):
    """Episodes per hour of the archived co-adaptation runs on ENV (median, this machine's
    terms), or None."""
    return median([x * machine_factor(d) for n, e, d in archived("config.toml") if e == env
                   and os.path.exists(f"{d}/episodes.csv") for x in [pace_of(d, fork_k(d))] if x])


# A run with two threads (THREADS=2, a lone lane) against one: the reference run measured 1.6x
# (EXPERIMENTS 5.13; more threads were not measured, two cores being the machine).
TWO_THREADS = 1.6


def queue_pace(lines):
    """The median pace of a queue's finished co-adaptation runs (archived, or done here), their
    own rows only (a fork's copied prefix left out), each in this machine's terms
    (machine_factor), or None. Retrains (plain SAC, updates per step) keep another pace: not
    mixed in."""
    paces = []
    for n2, s2, seed2, f2 in lines:
        if s2.startswith("retrain:"):
            continue
        for d in (f"{RESULTS}/{n2}-seed{seed2}", f"{RUNS}/{n2}-seed{seed2}"):
            if os.path.exists(f"{d}/summary.json"):
                eps, k = plan(n2, s2, seed2, f2, lines)
                p = pace_of(d, sum(eps[:k]) if eps and k else 0)
                if p:
                    paces.append(p * machine_factor(d))
                break
    return median(paces)


def line_seconds(queue, name, seed, threads=1):
    """Seconds of one lane the line NAME SEED of QUEUE needs from where it stands, or None, for
    a lane of THREADS threads (the archive's paces are of one)."""
    t = TWO_THREADS if threads >= 2 else 1.0
    s = line_seconds_one_thread(queue, name, seed)
    if s is None:
        return None
    seconds, own = s
    # A line under way already goes at its own threads' pace.
    return seconds if own else seconds / t


def line_seconds_one_thread(queue, name, seed):
    """(seconds, whether its own pace set them) for line_seconds, or None."""
    lines = parse(queue)
    line = next((l for l in lines if l[0] == name and l[2] == seed), None)
    if line is None:
        sys.exit(f"campaign_status: {queue} has no line {name} {seed}")
    _, spec, _, flags = line
    d = f"{RUNS}/{name}-seed{seed}"
    if spec.startswith("retrain:"):
        src = spec[len("retrain:"):].split(":")[0]
        src_dirs = [f"{RESULTS}/{src}-seed{seed}", f"{RUNS}/{src}-seed{seed}"]
        src_dir = next((x for x in src_dirs if os.path.exists(f"{x}/summary.json")), None)
        if src_dir is None:
            return None
        per_seed = seconds_per_train_seed(env_of(f"{src_dir}/config.toml"))
        left = sum(1 for k in (1, 2) if not os.path.exists(f"{d}/train-seed{k}/summary.json"))
        return None if per_seed is None else (left * per_seed, False)
    q_pace = queue_pace(lines)
    eps, k = plan(name, spec, seed, flags, lines)
    if not eps:
        return None
    episodes = max(0, sum(eps[k:]) - max(0, rows(f"{d}/episodes.csv") - sum(eps[:k])))
    seconds = 0.0
    env = None
    if spec.startswith("fork:"):
        src = spec[len("fork:"):].split(":")[0]
        src_dir, src_arch = f"{RUNS}/{src}-seed{seed}", f"{RESULTS}/{src}-seed{seed}"
        env = env_of(f"{src_arch}/config.toml") or env_of(f"{src_dir}/config.toml")
        # A source that is a line of the queue and has not run yet: its config's robot.
        for n2, s2, seed2, _ in lines:
            if env is None and n2 == src and seed2 == seed and not s2.startswith(("fork:", "retrain:")):
                try:
                    env = config_of(s2[len("random-only:"):] if s2.startswith("random-only:") else s2).get("env")
                except (OSError, ValueError, tomllib.TOMLDecodeError):
                    pass
        if not os.path.exists(d) and not os.path.exists(src_dir):
            if not os.path.exists(f"{src_arch}/summary.json"):
                # Its source has not started (a line skipped, or a later one): nothing to wait by.
                return None
            # The prefix is run again (its partial run's rows count as done).
            prefix = max(0, sum(eps[:k]) - rows(f"{src_dir}.prefix/episodes.csv"))
            p = coadapt_pace(src, env, q_pace)
            if not p:
                return None
            seconds += prefix / p * 3600
        elif not os.path.exists(d):
            # Its source runs (another lane): the fork waits for it to reach design K.
            behind = max(0, sum(eps[:k]) - rows(f"{src_dir}/episodes.csv"))
            p = coadapt_pace(src, env, q_pace)
            if behind and not p:
                return None
            seconds += behind / p * 3600 if behind else 0.0
    else:
        base = spec[len("random-only:"):] if spec.startswith("random-only:") else spec
        try:
            env = config_of(base).get("env")
        except (OSError, ValueError, tomllib.TOMLDecodeError):
            env = None
    if "--init-population" in flags:
        src = flags[flags.index("--init-population") + 1].rstrip("/")
        run = os.path.basename(src)
        arch = f"{RESULTS}/{run}"
        if not os.path.exists(src) and os.path.exists(f"{arch}/summary.json"):
            m = re.fullmatch(r"(.+)-seed\d+", run)
            p = coadapt_pace(m.group(1) if m else run, env_of(f"{arch}/config.toml"), q_pace)
            if not p:
                return None
            seconds += rows(f"{arch}/episodes.csv") / p * 3600
    # A line already under way goes at its own pace, over its rows after the initial designs
    # (ten at least; before them the networks train less per episode) and a fork's prefix.
    skip = own_skip(d)
    own = pace_of(d, skip) if skip is not None and rows(f"{d}/episodes.csv") - skip >= 10 else None
    p = own or coadapt_pace(name, env, q_pace)
    if not p:
        return None
    return seconds + episodes / p * 3600, own is not None


def main():
    if "--seconds" in sys.argv:
        i = sys.argv.index("--seconds")
        threads = 1
        if i == 2 and len(sys.argv) == 7 and sys.argv[5] == "--threads" and sys.argv[6].isdigit():
            threads = int(sys.argv[6])
        elif i != 2 or len(sys.argv) != 5:
            sys.exit("usage: campaign_status.py QUEUE_FILE --seconds NAME SEED [--threads N]")
        s = line_seconds(sys.argv[1], sys.argv[3], sys.argv[4], threads)
        if s is None:
            print("unknown")
            sys.exit(3)
        print(round(s))
        return
    args = [a for a in sys.argv[1:] if a != "--all"]
    if not args or "-h" in args or "--help" in args:
        print(__doc__.strip())
        sys.exit(0 if args else 2)
    show_all = "--all" in sys.argv
    # Every queue is read before anything is printed: a mistyped name fails alone.
    parsed = [(queue, parse(queue)) for queue in args]
    live = live_dirs()
    factor, raw, n = speed_detail()
    if n:
        clamp = "" if factor == raw else f", taken as {factor:.2f}"
        dirs = "run directory" if n == 1 else "run directories"
        print(f"this machine: {raw:.2f}x the archive's pace (median over {n} {dirs} here{clamp}); the estimates are scaled by it")
    for queue, lines in parsed:
        counts, left = {}, 0
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
            elif os.path.realpath(d) in live:
                state = "running"
            elif os.path.exists(d):
                # A fork's watcher copies it when its source reaches design K; until its lane
                # starts it, it holds the source's rows only.
                own = rows(f"{d}/episodes.csv") - (sum(eps[:k]) if eps and k else 0)
                state = "copied" if k and own <= 0 else "stopped"
            else:
                state = "pending"
            note = ""
            if state == "pending" and spec.startswith("fork:"):
                # Its source's first K designs being run again (the source's directory is gone).
                prefix = f"{RUNS}/{spec[len('fork:'):].split(':')[0]}-seed{seed}.prefix"
                if os.path.realpath(prefix) in live and eps:
                    state = "prefix"
                    note = f"; its source's first {k} designs again: {min(rows(f'{prefix}/episodes.csv'), sum(eps[:k]))}/{sum(eps[:k])}"
            counts[state] = counts.get(state, 0) + 1
            rest = None if total is None else max(0, total - done_rows)
            if state not in ("archived", "done"):
                left += rest or 0
            if state not in ("archived", "done") or show_all:
                progress = "?" if total is None else f"{min(done_rows, total)}/{total} episodes"
                if state not in ("archived", "done"):
                    est = line_seconds(queue, name, seed)
                    progress += "" if est is None else f", about {est / 60:.0f} min"
                print(f"  {state:8} {run:40} {progress}{note}")
        pace = queue_pace(lines)
        hours = f", about {left / pace:.1f} lane-hours at the median pace of its finished runs ({pace:.0f} episodes/h)" if pace and left else ""
        tally = ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "no lines"
        print(f"  -- {tally}; {left} episodes left{hours}")


if __name__ == "__main__":
    main()
