"""Plots a campaign's methods for docs/EXPERIMENTS.md: the best evaluation return of each design
against the design index, one thin line per seed and the mean over seeds in bold, one colour
per method; exploitation designs marked with a dot.

usage: .venv-peers/bin/python scripts/plot_campaign.py OUT.png RUNS_ROOT METHOD [METHOD ...]
       [--title "HalfCheetah, reduced protocol"]
RUNS_ROOT holds METHOD-seedN/designs.csv (scripts/campaign.sh). Needs matplotlib
(`.venv-peers/bin/pip install matplotlib`).
"""
import csv
import glob
import os
import re
import statistics
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main(out, root, methods):
    fig, ax = plt.subplots(figsize=(9, 5))
    for colour, method in zip(plt.rcParams["axes.prop_cycle"].by_key()["color"], methods):
        per_seed = []
        for path in sorted(glob.glob(os.path.join(root, f"{method}-seed*", "designs.csv"))):
            run = os.path.dirname(path)
            if not re.search(r"-seed\d+$", run) or not os.path.exists(os.path.join(run, "summary.json")):
                continue  # only finished runs
            # Rejected prototypes (schedule.confirm-designs) were never trained on; a design not
            # evaluated yet has an empty return.
            rows = [r for r in csv.DictReader(open(path)) if r.get("prototype") != "rejected"]
            best = [float(r["best_eval_return"]) if r["best_eval_return"] else float("nan") for r in rows]
            kinds = [r["kind"] for r in rows]
            per_seed.append(best)
            ax.plot(range(len(best)), best, color=colour, alpha=0.3, lw=1)
            xs = [i for i, k in enumerate(kinds) if k == "exploit"]
            ax.scatter(xs, [best[i] for i in xs], color=colour, alpha=0.35, s=12)
        if not per_seed:
            continue
        n = min(len(b) for b in per_seed)
        mean = [statistics.mean(b[i] for b in per_seed) for i in range(n)]
        ax.plot(range(n), mean, color=colour, lw=2.5, label=f"{method} (mean of {len(per_seed)} seeds)")
    ax.axvline(4.5, color="grey", ls=":", lw=1)
    ax.text(4.6, ax.get_ylim()[0], " chosen designs ->", color="grey", va="bottom")
    ax.set_xlabel("design index (0-4: the five fixed initial designs)")
    ax.set_ylabel("best evaluation return of the design")
    ax.set_title(f"{TITLE}: each design's best evaluation return (dots: exploitation designs)")
    ax.legend(loc="upper left", fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    args = sys.argv[1:]
    TITLE = "HalfCheetah, reduced protocol"
    if "--title" in args:
        i = args.index("--title")
        if i + 1 >= len(args):
            sys.exit("plot_campaign: --title needs a value")
        TITLE = args[i + 1]
        del args[i : i + 2]
    if len(args) < 3:
        sys.exit(__doc__)
    main(args[0], args[1], args[2:])
