"""Episodes to a return with and without exploration through the learned action space (issue 31
section 2), from an archive written by scripts/latent_exploration.sh.

usage: python3 scripts/latent_exploration_report.py ARCHIVE [--target R]

ARCHIVE holds designs.json and {latent,sac}-d<k>-seed<s>/episodes.csv. Per run: the first episode
whose mean over the last 10 episodes reaches R (default: half the best such mean of all runs in
the archive, so the target is one every arm can be asked about), its best 10-episode mean and
its last. Then, paired by (design, seed), latent minus SAC: mean and sample sd (n pairs), and
the exact two-sided sign-flip p. A run that never reaches R counts its episodes plus one
(censored; said in the table).

Pure Python, no packages; the statistics are campaign_report's and design_bench_report's.
"""
import csv
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import campaign_report as cr  # noqa: E402
from design_bench_report import sign_flip_p  # noqa: E402


def curve(path):
    return [float(r["mean_return_last_10"]) for r in csv.DictReader(open(path))]


def mean_sd(v):
    return f"{cr.signed_sd(v)} (n = {len(v)})" if v else "-"


def main():
    args = sys.argv[1:]
    if not args:
        raise SystemExit(__doc__)
    root = args[0]
    target = float(args[args.index("--target") + 1]) if "--target" in args else None
    meta = json.load(open(os.path.join(root, "designs.json")))
    runs = {}
    for name in sorted(os.listdir(root)):
        path = os.path.join(root, name, "episodes.csv")
        if os.path.exists(path) and "-d" in name:
            arm, rest = name.split("-d", 1)
            k, seed = rest.split("-seed")
            runs[(arm, int(k), int(seed))] = curve(path)
    if not runs:
        raise SystemExit(f"latent_exploration_report: no runs under {root}")
    best_all = max(max(c) for c in runs.values() if c)
    if target is None:
        target = best_all / 2
    print(f"{meta['env']}, {len(meta['designs'])} new designs; target: a 10-episode mean return of {target:.1f}\n")
    print("| arm | design | seed | episodes | episodes to target | best 10-episode mean | last |")
    print("|---|---|---|---|---|---|---|")
    reach = {}
    for (arm, k, seed), c in sorted(runs.items()):
        first = next((i + 1 for i, v in enumerate(c) if v >= target), None)
        reach[(arm, k, seed)] = first if first is not None else len(c) + 1
        shown = str(first) if first is not None else f"not reached (> {len(c)})"
        print(f"| {arm} | {k} | {seed} | {len(c)} | {shown} | {max(c):.1f} | {c[-1]:.1f} |")
    pairs = sorted({(k, s) for (_, k, s) in runs if ("latent", k, s) in runs and ("sac", k, s) in runs})
    d_reach = [reach[("latent", k, s)] - reach[("sac", k, s)] for k, s in pairs]
    d_best = [max(runs[("latent", k, s)]) - max(runs[("sac", k, s)]) for k, s in pairs]
    print("\n| latent minus SAC, paired by design and seed | pairs | episodes to target | p | best 10-episode mean | p |")
    print("|---|---|---|---|---|---|")
    print(f"| all | {len(pairs)} | {mean_sd(d_reach)} | {sign_flip_p(d_reach)} | {mean_sd(d_best)} | {sign_flip_p(d_best)} |")


if __name__ == "__main__":
    main()
