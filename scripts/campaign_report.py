"""Tables for docs/EXPERIMENTS.md from a campaign's run directories (scripts/campaign.sh).

usage: python3 scripts/campaign_report.py [RUNS_ROOT, default runs/campaign] [--initial 5]
           [--methods a,b,...] [--baseline random-only] [--split K]

--methods keeps only those methods (e.g. one protocol's runs out of docs/campaign/results);
--baseline names the method the others are paired against (section 2); --split K adds a table
of the mean best return of chosen designs before design index K and from K on, per method and
paired against the baseline (does a gap open as the critic gets more data?).

Reads every RUN/designs.csv under RUNS_ROOT whose RUN is named METHOD-seedN (only finished runs,
with summary.json, unless --partial) and prints Markdown:

1. per run and per method (mean and sample standard deviation over seeds): the best evaluation
   return of any design, the mean over the chosen designs (after the initial ones) of each
   design's best evaluation return, the same over exploitation designs only, and the design
   rollouts spent;
2. between runs: each method against `random-only` seed by seed (the same seed gives the same
   initial designs and the same networks up to the first chosen design, so the seed pairs them);
3. within runs, for methods that alternate: each exploitation design's best return minus that
   of the exploration design after it (the issue's paired difference), and minus the mean of
   the exploration designs on both sides (which cancels a linear trend of the policy improving
   over time, which favours whichever design comes later), with a sign test;
4. where chosen designs sit in the box: how many exploitation designs have a coordinate on a
   face (within 0.1 % of the width of a bound) and how many have every coordinate on one
   (a corner).

Pure Python (no numpy), so it runs with the system python3.
"""
import csv
import json
import math
import os
import re
import statistics
import sys

BOUNDS = {
    "half-cheetah": ([0.8] * 6, [2.0] * 6),
    "walker": ([0.5] * 6, [1.5] * 6),
    "hopper": ([0.5] * 5, [4.0, 2.0, 2.0, 2.0, 2.0]),
    "daisy": ([0.12] * 6 + [-0.2] * 3, [0.5] * 6 + [0.2] * 3),
}


def read_run(path):
    with open(os.path.join(path, "designs.csv")) as f:
        # A proposal rejected at the prototype step (schedule.confirm-designs) was never trained
        # on: the row after it holds the design built for that index.
        rows = [r for r in csv.DictReader(f) if r.get("prototype") != "rejected"]
    env = "half-cheetah"
    cfg = os.path.join(path, "config.toml")
    if os.path.exists(cfg):
        m = re.search(r'^env\s*=\s*"([^"]+)"', open(cfg).read(), re.M)
        if m:
            env = m.group(1)
    out = []
    for r in rows:
        out.append({
            "index": int(r["index"]),
            "kind": r["kind"],
            "design": [float(x) for x in r["design"].split(";")],
            "best": float(r["best_eval_return"]) if r["best_eval_return"] else float("nan"),
            "rollouts": int(r["design_rollouts"] or 0),
            "method": r["method"],
        })
    return env, out


def mean_sd(v):
    v = [x for x in v if not math.isnan(x)]
    if not v:
        return "-"
    if len(v) == 1:
        return f"{v[0]:.1f}"
    return f"{statistics.mean(v):.1f} ± {statistics.stdev(v):.1f}"


def sign_test(diffs):
    """Two-sided sign test p-value (ties dropped)."""
    pos = sum(d > 0 for d in diffs)
    neg = sum(d < 0 for d in diffs)
    n = pos + neg
    if n == 0:
        return float("nan")
    k = min(pos, neg)
    p = sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n
    return min(1.0, 2 * p)


def on_face(design, low, high, tol=1e-3):
    flags = [min(abs(x - lo), abs(x - hi)) <= tol * (hi - lo) for x, lo, hi in zip(design, low, high)]
    return any(flags), all(flags)


def option(name, default):
    if name not in sys.argv:
        return default
    i = sys.argv.index(name)
    if i + 1 >= len(sys.argv):
        sys.exit(f"campaign_report: {name} needs a value")
    return sys.argv[i + 1]


def main():
    valued = {"--initial", "--methods", "--baseline", "--split"}
    args = [a for i, a in enumerate(sys.argv[1:], 1) if not a.startswith("--") and sys.argv[i - 1] not in valued]
    root = args[0] if args else "runs/campaign"
    partial = "--partial" in sys.argv
    n_init = int(option("--initial", 5))
    keep = option("--methods", None)
    keep = set(keep.split(",")) if keep else None
    baseline = option("--baseline", "random-only")
    split = option("--split", None)
    split = int(split) if split is not None else None
    runs = {}
    for name in sorted(os.listdir(root)):
        m = re.fullmatch(r"(.+)-seed(\d+)", name)
        path = os.path.join(root, name)
        if not m or not os.path.exists(os.path.join(path, "designs.csv")):
            continue
        if keep is not None and m.group(1) not in keep:
            continue
        if not partial and not os.path.exists(os.path.join(path, "summary.json")):
            continue
        env, rows = read_run(path)
        if not rows:
            continue
        runs.setdefault(m.group(1), {})[int(m.group(2))] = (env, rows)

    def metrics(rows):
        chosen = [r for r in rows if r["index"] >= n_init]
        exploit = [r for r in chosen if r["kind"] == "exploit"]
        return {
            "best": max(r["best"] for r in rows),
            "chosen": statistics.mean(r["best"] for r in chosen) if chosen else float("nan"),
            "exploit": statistics.mean(r["best"] for r in exploit) if exploit else float("nan"),
            "rollouts": sum(r["rollouts"] for r in rows),
            "designs": len(rows),
        }

    print("### Per run\n")
    print("| method | seed | designs | best | mean best of chosen designs | mean best of exploitation designs | design rollouts |")
    print("|---|---|---|---|---|---|---|")
    per_method = {}
    for method, seeds in runs.items():
        for seed, (env, rows) in sorted(seeds.items()):
            mt = metrics(rows)
            per_method.setdefault(method, []).append((seed, mt))
            print(f"| {method} | {seed} | {mt['designs']} | {mt['best']:.1f} | {mt['chosen']:.1f} | {mt['exploit']:.1f} | {mt['rollouts']:,} |")

    print("\n### Per method (mean ± sample standard deviation over seeds)\n")
    print("| method | seeds | best | mean best of chosen designs | mean best of exploitation designs | design rollouts per run |")
    print("|---|---|---|---|---|---|")
    for method, ms in per_method.items():
        col = lambda k: [m[k] for _, m in ms]
        print(f"| {method} | {len(ms)} | {mean_sd(col('best'))} | {mean_sd(col('chosen'))} | {mean_sd(col('exploit'))} | {statistics.mean(col('rollouts')):,.0f} |")

    if baseline in per_method:
        base = dict(per_method[baseline])
        print(f"\n### Between runs: each method minus {baseline}, paired by seed\n")
        print("| method | seeds paired | best | mean best of chosen designs |")
        print("|---|---|---|---|")
        for method, ms in per_method.items():
            if method == baseline:
                continue
            pairs = [(m, base[s]) for s, m in ms if s in base]
            if not pairs:
                continue
            d_best = [a["best"] - b["best"] for a, b in pairs]
            d_chosen = [a["chosen"] - b["chosen"] for a, b in pairs]
            print(f"| {method} | {len(pairs)} | {mean_sd(d_best)} | {mean_sd(d_chosen)} |")

    if split is not None:
        print(f"\n### Mean best return of chosen designs, indices {n_init}-{split - 1} and {split} on\n")
        print(f"| method | seed | {n_init}-{split - 1} | {split} on | later - earlier |")
        print("|---|---|---|---|---|")
        halves = {}
        for method, seeds in runs.items():
            for seed, (env, rows) in sorted(seeds.items()):
                a = [r["best"] for r in rows if n_init <= r["index"] < split]
                b = [r["best"] for r in rows if r["index"] >= split]
                if not a or not b:
                    continue
                halves.setdefault(method, {})[seed] = (statistics.mean(a), statistics.mean(b))
                print(f"| {method} | {seed} | {statistics.mean(a):.1f} | {statistics.mean(b):.1f} | {statistics.mean(b) - statistics.mean(a):+.1f} |")
        if baseline in halves:
            print(f"\nMinus {baseline}, paired by seed (mean ± sd over seeds):\n")
            print(f"| method | seeds paired | {n_init}-{split - 1} | {split} on |")
            print("|---|---|---|---|")
            for method, hs in halves.items():
                if method == baseline:
                    continue
                pairs = [(h, halves[baseline][s]) for s, h in hs.items() if s in halves[baseline]]
                if pairs:
                    print(f"| {method} | {len(pairs)} | {mean_sd([h[0] - b[0] for h, b in pairs])} | {mean_sd([h[1] - b[1] for h, b in pairs])} |")

    print("\n### Within runs: exploitation design minus exploration designs (best evaluation return)\n")
    print("| method | pairs | exploit - next explore: mean ± sd | exploit wins | sign test p | exploit - mean of neighbouring explores: mean ± sd | exploit wins | sign test p |")
    print("|---|---|---|---|---|---|---|---|")
    for method, seeds in runs.items():
        d_next, d_both = [], []
        for seed, (env, rows) in seeds.items():
            by_index = {r["index"]: r for r in rows}
            for r in rows:
                if r["index"] < n_init or r["kind"] != "exploit":
                    continue
                nxt = by_index.get(r["index"] + 1)
                prv = by_index.get(r["index"] - 1)
                if nxt and nxt["kind"] == "explore":
                    d_next.append(r["best"] - nxt["best"])
                    if prv and prv["kind"] == "explore":
                        d_both.append(r["best"] - (nxt["best"] + prv["best"]) / 2)
        if not d_next:
            continue
        wins = lambda d: f"{sum(x > 0 for x in d)}/{len(d)}"
        print(f"| {method} | {len(d_next)} | {mean_sd(d_next)} | {wins(d_next)} | {sign_test(d_next):.2f} | "
              f"{mean_sd(d_both) if d_both else '-'} | {wins(d_both) if d_both else '-'} | {sign_test(d_both) if d_both else float('nan'):.2f} |")

    print("\n### Where the exploitation designs sit (face: a coordinate within 0.1 % of the box's width of a bound; corner: every coordinate; near: within 2 %)\n")
    print("| method | exploitation designs | on a face | on a corner | coordinates on a bound | coordinates near a bound |")
    print("|---|---|---|---|---|---|")
    for method, seeds in runs.items():
        n = face = corner = coords = near = total = 0
        for seed, (env, rows) in seeds.items():
            low, high = BOUNDS.get(env, (None, None))
            if low is None:
                continue
            for r in rows:
                if r["index"] < n_init or r["kind"] != "exploit":
                    continue
                f, c = on_face(r["design"], low, high)
                n += 1
                face += f
                corner += c
                coords += sum(min(abs(x - lo), abs(x - hi)) <= 1e-3 * (hi - lo) for x, lo, hi in zip(r["design"], low, high))
                near += sum(min(abs(x - lo), abs(x - hi)) <= 2e-2 * (hi - lo) for x, lo, hi in zip(r["design"], low, high))
                total += len(r["design"])
        if n:
            print(f"| {method} | {n} | {face} | {corner} | {coords}/{total} | {near}/{total} |")


if __name__ == "__main__":
    main()
