#!/usr/bin/env python3
"""Compares `coadapt search` run directories: the mean policy's summed end-effector distance
after the last iteration (mean, sample sd over runs, and at chosen iterations), and two-sided
exact Mann-Whitney U tests between every pair of methods (no scipy: the U distribution is
counted exactly).

    python3 scripts/search_report.py runs/search/groups4 runs/search/power ...
"""
import csv
import functools
import itertools
import math
import os
import sys


def final_costs(d, at=None):
    by_run = {}
    with open(os.path.join(d, "iterations.csv"), newline="") as f:
        for r in csv.DictReader(f):
            it = int(r["iteration"])
            if at is None or it <= at:
                run = int(r["run"])
                if it >= by_run.get(run, (0, 0))[0]:
                    by_run[run] = (it, float(r["mean_policy_cost"]))
    return [c for _, c in sorted(by_run.values())]


@functools.lru_cache(maxsize=None)
def count(n1, n2, u):
    """Orderings of n1 x's and n2 y's with exactly u pairs (x, y) where x comes after y."""
    if u < 0:
        return 0
    if n1 == 0 or n2 == 0:
        return 1 if u == 0 else 0
    return count(n1 - 1, n2, u - n2) + count(n1, n2 - 1, u)


def mann_whitney(a, b):
    u = sum((x > y) + 0.5 * (x == y) for x in a for y in b)
    n1, n2 = len(a), len(b)
    total = math.comb(n1 + n2, n1)
    lo = min(u, n1 * n2 - u)
    p = 2 * sum(count(n1, n2, k) for k in range(int(math.floor(lo)) + 1)) / total
    return u, min(1.0, p)


def main():
    dirs = sys.argv[1:]
    if not dirs:
        sys.exit(__doc__)
    rows = {os.path.basename(d.rstrip("/")): d for d in dirs}
    print("| method | runs | after 25 iterations | after 50 | after 100 (final) |")
    print("|---|---|---|---|---|")
    finals = {}
    for name, d in rows.items():
        cells = []
        for at in (25, 50, None):
            c = final_costs(d, at)
            m = sum(c) / len(c)
            sd = math.sqrt(sum((x - m) ** 2 for x in c) / max(1, len(c) - 1))
            cells.append(f"{m:.1f} ± {sd:.1f}")
        finals[name] = final_costs(d)
        print(f"| {name} | {len(finals[name])} | " + " | ".join(cells) + " |")
    print()
    print("| pair (final cost) | U | two-sided exact p | lower median |")
    print("|---|---|---|---|")
    for x, y in itertools.combinations(finals, 2):
        u, p = mann_whitney(finals[x], finals[y])
        mx = sorted(finals[x])[len(finals[x]) // 2]
        my = sorted(finals[y])[len(finals[y]) // 2]
        print(f"| {x} vs {y} | {u:.0f} | {p:.4f} | {x if mx < my else y} |")


if __name__ == "__main__":
    main()
