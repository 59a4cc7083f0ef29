"""Tables of the transfer sweep (issue 31, thesis 6.1) from the archive.

usage: python3 scripts/transfer_report.py RESULTS_DIR [--target R] [--frictions 0.1,0.2,0.8,1.6]

RESULTS_DIR holds the run directories `transfer-f<y>-seed<k>` (started from the population
networks of `transfer-src-seed<k>`, FEAR at the robot's own friction 0.4) and
`scratch-f<y>-seed<k>` (the same protocol from scratch), each with designs.csv and
episodes.csv. For every friction y and arm it gives, over the seeds present (mean ± sample sd,
n stated):
  * episodes to R: the first training episode (counted over the whole run) whose evaluation
    return reaches R (default 300), or "not reached" (counted apart);
  * designs to R: the designs (prototypes) played up to and including that episode;
  * best evaluation return of the run, and the quality of the chosen designs (the mean best
    evaluation return of the exploitation designs);
and the simulator gap: `mujoco-transfer-seed<k>` (MuJoCo's cheetah through the bridge, from the
same sources) against `mujoco-bench-fear-seed<k>` (the design benchmark's FEAR runs of it, the
same config and seed from scratch), as the last target world. Then, paired by seed, transfer
minus scratch for each (episodes to R only where both reached it;
a run that did not reach R counts as its length, marked "≥"). Pure Python, no packages.
"""
import csv
import math
import os
import re
import statistics
import sys


def flag(name, default):
    if name in sys.argv:
        i = sys.argv.index(name)
        return sys.argv[i + 1]
    return default


# The simulator gap's target world: MuJoCo's cheetah through the bridge. Its transfer arm is
# `mujoco-transfer-seed<k>` (from `transfer-src-seed<k>`), its from-scratch arm the design
# benchmark's `mujoco-bench-fear-seed<k>` (the same config and seed without the copied networks).
MUJOCO = "MuJoCo"


def runs(root):
    pat = re.compile(r"^(transfer|scratch)-f([0-9.]+)-seed(\d+)$")
    gap = re.compile(r"^mujoco-(transfer|bench-fear)-seed(\d+)$")
    out = {}
    for name in sorted(os.listdir(root)):
        if not os.path.isfile(os.path.join(root, name, "summary.json")):
            continue
        m = pat.match(name)
        if m:
            out[(m.group(1), float(m.group(2)), int(m.group(3)))] = os.path.join(root, name)
        m = gap.match(name)
        if m:
            arm = "transfer" if m.group(1) == "transfer" else "scratch"
            out[(arm, MUJOCO, int(m.group(2)))] = os.path.join(root, name)
    return out


def world(y):
    return y if y == MUJOCO else f"{y:g}"


def read(path, target):
    with open(os.path.join(path, "episodes.csv")) as f:
        eps = list(csv.DictReader(f))
    with open(os.path.join(path, "designs.csv")) as f:
        designs = list(csv.DictReader(f))
    reached = None
    for i, e in enumerate(eps):
        v = e.get("eval_return", "")
        if v and float(v) >= target:
            reached = (i + 1, int(e["design"]) + 1)
            break
    best = max((float(d["best_eval_return"]) for d in designs if d["best_eval_return"]), default=float("nan"))
    chosen = [float(d["best_eval_return"]) for d in designs if d["kind"] == "exploit" and d["best_eval_return"]]
    quality = statistics.mean(chosen) if chosen else float("nan")
    return {"episodes": len(eps), "designs": len(designs), "reached": reached, "best": best, "quality": quality}


def spread(v, sign=""):
    v = [x for x in v if not math.isnan(x)]
    if not v:
        return "-"
    if len(v) == 1:
        return f"{v[0]:{sign}.1f}"
    return f"{statistics.mean(v):{sign}.1f} ± {statistics.stdev(v):.1f}"


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    if sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        return
    root = sys.argv[1]
    if not os.path.isdir(root):
        sys.exit(f"transfer_report: {root}: not a directory (the archive, e.g. docs/campaign/results)")
    target = float(flag("--target", "300"))
    # Target worlds: the frictions asked for, then the simulator gap.
    worlds = [float(x) for x in flag("--frictions", "0.1,0.2,0.8,1.6").split(",")] + [MUJOCO]
    found = runs(root)
    data = {k: read(p, target) for k, p in found.items()}
    sources = sorted(n for n in os.listdir(root) if re.match(r"^transfer-src-seed\d+$", n) and os.path.isfile(os.path.join(root, n, "summary.json")))
    print(f"| source (friction 0.4) | designs | episodes to {target:g} | designs to {target:g} | best eval return | quality of chosen designs |")
    print("|---|---|---|---|---|---|")
    for n in sources:
        r = read(os.path.join(root, n), target)
        reached = r["reached"] or ("not reached", "-")
        print(f"| {n} | {r['designs']} | {reached[0]} | {reached[1]} | {r['best']:.1f} | {r['quality']:.1f} |")
    print()
    print(f"| target world (friction, or {MUJOCO}'s cheetah) | arm | seeds | reached {target:g} | episodes to {target:g} | designs to {target:g} | best eval return | quality of chosen designs |")
    print("|---|---|---|---|---|---|---|---|")
    for y in worlds:
        for arm in ("transfer", "scratch"):
            rs = [v for (a, f, _), v in sorted(data.items(), key=lambda kv: kv[0][2]) if a == arm and f == y]
            if not rs:
                print(f"| {world(y)} | {arm} | 0 | - | - | - | - | - |")
                continue
            hit = [r for r in rs if r["reached"]]
            print(
                f"| {world(y)} | {arm} | {len(rs)} | {len(hit)}/{len(rs)} | {spread([r['reached'][0] for r in hit])} | "
                f"{spread([r['reached'][1] for r in hit])} | {spread([r['best'] for r in rs])} | {spread([r['quality'] for r in rs])} |"
            )
    print()
    print("| target world | pairs (by seed) | transfer minus scratch: episodes to target | designs to target | best eval return | quality of chosen designs |")
    print("|---|---|---|---|---|---|")
    for y in worlds:
        seeds = sorted({s for (a, f, s) in data if f == y and ("transfer", y, s) in data and ("scratch", y, s) in data})
        if not seeds:
            print(f"| {world(y)} | 0 | - | - | - | - |")
            continue
        t = [data[("transfer", y, s)] for s in seeds]
        c = [data[("scratch", y, s)] for s in seeds]
        # A run that never reached the target counts as its whole length (a lower bound).
        ep = [(a["reached"] or (a["episodes"], a["designs"]))[0] - (b["reached"] or (b["episodes"], b["designs"]))[0] for a, b in zip(t, c)]
        de = [(a["reached"] or (a["episodes"], a["designs"]))[1] - (b["reached"] or (b["episodes"], b["designs"]))[1] for a, b in zip(t, c)]
        censored = any(not (a["reached"] and b["reached"]) for a, b in zip(t, c))
        mark = " (≥: a run did not reach it)" if censored else ""
        print(
            f"| {world(y)} | {len(seeds)} | {spread(ep, '+')}{mark} | {spread(de, '+')} | "
            f"{spread([a['best'] - b['best'] for a, b in zip(t, c)], '+')} | {spread([a['quality'] - b['quality'] for a, b in zip(t, c)], '+')} |"
        )


if __name__ == "__main__":
    main()
