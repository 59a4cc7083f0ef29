"""Plots one run's learning curve (episode return and the mean of the last 10) for the docs.

usage: .venv-peers/bin/python scripts/plot_run.py RUN_DIR OUT.png [TITLE]
RUN_DIR holds episodes.csv as written by `coadapt train`. (Needs matplotlib.)
"""
import csv
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main(run_dir, png, title):
    with open(os.path.join(run_dir, "episodes.csv")) as f:
        rows = list(csv.DictReader(f))
    ep = [int(r["episode"]) for r in rows]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.plot(ep, [float(r["return"]) for r in rows], color="C0", alpha=0.35, lw=1, label="episode return")
    ax.plot(ep, [float(r["mean_return_last_10"]) for r in rows], color="C0", lw=2, label="mean of last 10")
    ax.set_xlabel("episode (1000 steps each)" if rows and rows[0]["length"] == "1000" else "episode")
    ax.set_ylabel("return")
    ax.set_title(title)
    wall = float(rows[-1]["wall_s"]) if rows else 0
    ax.text(0.01, 0.97, f"{len(rows)} episodes, {int(rows[-1]['step']) if rows else 0} steps, {wall / 60:.1f} min wall",
            transform=ax.transAxes, va="top", fontsize=8)
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png, dpi=110)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else sys.argv[1])
