"""Does the critic order bodies the way the robot does? (issue 28, section 2: calibration.)

usage: python3 scripts/calibration_report.py [RUNS_ROOT, default docs/campaign/results] [--methods a,b,...]
           [--tables pairs,within] [--partial]

Reads every RUN/calibration.csv (written by the optimiser at each exploitation request: the
Eq. 5.6 objective, with that request's networks and start states, of the chosen design, of the
random design proposed next, and of every design trained before) beside RUN/designs.csv (the
best evaluation return each design reached once trained). RUN is named METHOD-seedN; runs
without summary.json are skipped unless --partial.

Two tables, per method (rows in --methods order):

1. pairs: the chosen design against the exploration design trained right after it (the same
   critic scored both; the controller trained them one after the other): how often the
   predicted order is the achieved order, the Spearman rank correlation of predicted and
   achieved differences over those pairs, and the least-squares slope of achieved against
   predicted difference (what a difference of 1 in predicted objective was worth in return),
   with the same over every pair of the chosen design and a design trained before it;
2. within: at each request, Spearman's rho between the predicted objective and the achieved
   best return over every design trained so far plus the chosen one; mean ± sample sd over
   requests (n stated).

Pure Python (no numpy), so it runs with the system python3.
"""
import csv
import math
import os
import statistics
import sys

from campaign_runs import flag_value, run_dirs


def option(name, default):
    return flag_value(name, default, "calibration_report")


def ranks(v):
    order = sorted(range(len(v)), key=lambda i: v[i])
    r = [0.0] * len(v)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and v[order[j + 1]] == v[order[i]]:
            j += 1
        for k in range(i, j + 1):
            r[order[k]] = (i + j) / 2
        i = j + 1
    return r


def pearson(x, y):
    if len(x) < 3:
        return float("nan")
    mx, my = statistics.mean(x), statistics.mean(y)
    sx = math.sqrt(sum((a - mx) ** 2 for a in x))
    sy = math.sqrt(sum((b - my) ** 2 for b in y))
    if sx == 0 or sy == 0:
        return float("nan")
    return sum((a - mx) * (b - my) for a, b in zip(x, y)) / (sx * sy)


def spearman(x, y):
    return pearson(ranks(x), ranks(y))


def slope(x, y):
    if len(x) < 2:
        return float("nan")
    mx, my = statistics.mean(x), statistics.mean(y)
    sxx = sum((a - mx) ** 2 for a in x)
    return float("nan") if sxx == 0 else sum((a - mx) * (b - my) for a, b in zip(x, y)) / sxx


def fmt(x, digits=2):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def read_run(path):
    best = {}
    designs = {}
    with open(os.path.join(path, "designs.csv")) as f:
        for r in csv.DictReader(f):
            if r.get("prototype") == "rejected" or not r["best_eval_return"]:
                continue
            best[int(r["index"])] = float(r["best_eval_return"])
            designs[int(r["index"])] = [float(x) for x in r["design"].split(";")]
    requests = {}
    with open(os.path.join(path, "calibration.csv")) as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        req = int(r["request"])
        # A request answered again after a restart writes its rows again: keep the last set.
        if r["candidate"] == "chosen":
            requests[req] = []
        requests.setdefault(req, []).append(r)
    return best, designs, requests


def same(a, b):
    return len(a) == len(b) and all(abs(x - y) <= 1e-4 * max(1.0, abs(y)) for x, y in zip(a, b))


def main():
    args = [a for i, a in enumerate(sys.argv[1:], 1) if not a.startswith("--") and sys.argv[i - 1] not in {"--methods", "--tables"}]
    root = args[0] if args else "docs/campaign/results"
    keep = option("--methods", None)
    keep = keep.split(",") if keep else None
    tables = option("--tables", "pairs,within").split(",")
    partial = "--partial" in sys.argv
    per_method = {}
    for method, seed, path in run_dirs(root, "calibration.csv", keep, partial):
        per_method.setdefault(method, []).append((seed, read_run(path)))
    methods = keep if keep is not None else sorted(per_method)
    methods = [x for x in methods if x in per_method]
    if not methods:
        sys.exit(f"calibration_report: no run with calibration.csv under {root}")

    if "pairs" in tables:
        print("| method | seeds | chosen vs next random: pairs | predicted order right | Spearman of differences | return per unit predicted | chosen vs earlier designs: pairs | predicted order right | Spearman of differences | return per unit predicted |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for method in methods:
            nxt_p, nxt_a, old_p, old_a = [], [], [], []
            for _seed, (best, designs, requests) in per_method[method]:
                for req, rows in requests.items():
                    chosen = next((r for r in rows if r["candidate"] == "chosen"), None)
                    if chosen is None or req not in best:
                        continue
                    pc = float(chosen["predicted_objective"])
                    for r in rows:
                        if r["candidate"] == "next-random" and req + 1 in best:
                            # Only when the next design trained is the one scored.
                            if same([float(x) for x in r["design"].split(";")], designs[req + 1]):
                                nxt_p.append(pc - float(r["predicted_objective"]))
                                nxt_a.append(best[req] - best[req + 1])
                        elif r["candidate"] == "trained" and int(r["trained_index"]) in best:
                            old_p.append(pc - float(r["predicted_objective"]))
                            old_a.append(best[req] - best[int(r["trained_index"])])

            def cols(p, a):
                if not p:
                    return "0 | - | - | -"
                right = sum((x > 0) == (y > 0) for x, y in zip(p, a) if x != 0 and y != 0)
                return f"{len(p)} | {right}/{len(p)} | {fmt(spearman(p, a))} | {fmt(slope(p, a), 1)}"

            print(f"| {method} | {len(per_method[method])} | {cols(nxt_p, nxt_a)} | {cols(old_p, old_a)} |")

    if "within" in tables:
        if "pairs" in tables:
            print()
        print("| method | requests | Spearman of predicted objective and achieved return over the designs trained so far: mean ± sd |")
        print("|---|---|---|")
        for method in methods:
            rhos = []
            for _seed, (best, designs, requests) in per_method[method]:
                for req, rows in requests.items():
                    p, a = [], []
                    for r in rows:
                        idx = req if r["candidate"] == "chosen" else int(r["trained_index"]) if r["candidate"] == "trained" else None
                        if idx is not None and idx in best:
                            p.append(float(r["predicted_objective"]))
                            a.append(best[idx])
                    rho = spearman(p, a)
                    if not math.isnan(rho):
                        rhos.append(rho)
            if not rhos:
                print(f"| {method} | 0 | - |")
            elif len(rhos) == 1:
                print(f"| {method} | 1 | {rhos[0]:.2f} |")
            else:
                print(f"| {method} | {len(rhos)} | {statistics.mean(rhos):.2f} ± {statistics.stdev(rhos):.2f} |")


if __name__ == "__main__":
    main()
