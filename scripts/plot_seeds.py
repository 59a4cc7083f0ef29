"""Plots the learning curves of a seed study (scripts/pendulum_seeds.sh) for docs/EXPERIMENTS.md.

usage: .venv-peers/bin/python scripts/plot_seeds.py OUT.png LABEL=runs/pendulum-seeds-sac [LABEL=DIR ...]
Each DIR holds seed*/episodes.csv; the plot shows the mean return of the last 10 episodes
against environment steps, one thin line per seed and the median across seeds in bold.
(Needs matplotlib: `.venv-peers/bin/pip install matplotlib`.)
"""
import csv
import glob
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def curves(d):
    out = []
    for path in sorted(glob.glob(os.path.join(d, "seed*", "episodes.csv"))):
        with open(path) as f:
            rows = list(csv.DictReader(f))
        out.append(([int(r["step"]) for r in rows], [float(r["mean_return_last_10"]) for r in rows]))
    return out


def main(png, specs):
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for i, spec in enumerate(specs):
        label, d = spec.split("=", 1)
        color = f"C{i}"
        cs = curves(d)
        for steps, vals in cs:
            ax.plot(steps, vals, color=color, alpha=0.3, lw=0.8)
        if cs:
            n = min(len(c[0]) for c in cs)
            med = [sorted(c[1][k] for c in cs)[len(cs) // 2] for k in range(n)]
            ax.plot(cs[0][0][:n], med, color=color, lw=2, label=f"{label} (median of {len(cs)} seeds)")
    ax.axhline(-200, color="k", ls="--", lw=0.8, label="-200")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("mean return, last 10 episodes")
    ax.set_title("Pendulum: coadapt learning curves")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png, dpi=110)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
