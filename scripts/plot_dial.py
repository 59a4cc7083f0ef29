"""The screening dial as a curve (issue 28 section 3): quality of the chosen designs against the
simulation a method spends on choosing them, per robot, from the archived runs.

usage: .venv-peers/bin/python scripts/plot_dial.py OUT.png [RUNS_ROOT, default docs/campaign/results]
           [--robots walker-bench,hopper-bench]

x: simulated steps spent on design choice per run (design rollouts x the screen's steps, or x
1,000 for the simulation baseline's whole episodes: an upper bound where an episode ends early),
on a log axis with FEAR's 0 drawn at the left edge; y: the quality of the chosen designs (mean best
evaluation return of the exploitation designs), one dot per run (seed), the mean over seeds joined
by a line from FEAR through the screened settings to the simulation baseline; the random-designs
run of the same robot as a dashed line (its mean over seeds). The same numbers as
design_bench_report.py's `dial` table. Needs matplotlib (`.venv-peers/bin/pip install matplotlib`).
"""
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import design_bench_report as db  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

TITLES = dict((prefix, title) for title, prefix in db.ROBOTS)


def points(root, prefix):
    """[(steps, method, [quality per seed])] of the dial's methods, by steps; and the random
    designs' qualities."""
    runs = db.runs_of(root, prefix)
    out = []
    for m in db.ordered(runs):
        if not (m == "fear" or m.startswith("screened") or m.startswith("sim-")):
            continue
        steps = [f["rollouts"] * db.rollout_steps(os.path.join(root, f"{prefix}-{m}-seed{s}")) for s, (f, _) in runs[m].items()]
        out.append((statistics.mean(steps), m, [f["exploit"] for f, _ in runs[m].values()]))
    rand = [f["exploit"] for f, _ in runs.get("random", {}).values()]
    return sorted(out), rand


def main():
    args = [a for i, a in enumerate(sys.argv[1:], 1) if not a.startswith("--") and sys.argv[i - 1] != "--robots"]
    if not args:
        sys.exit(__doc__)
    out, root = args[0], args[1] if len(args) > 1 else "docs/campaign/results"
    robots = db.option("--robots", "walker-bench,hopper-bench").split(",")
    fig, axes = plt.subplots(1, len(robots), figsize=(5.5 * len(robots), 4.2), squeeze=False)
    for ax, prefix in zip(axes[0], robots):
        pts, rand = points(root, prefix)
        if not pts:
            ax.set_title(f"{TITLES.get(prefix, prefix)}: no runs")
            continue
        # FEAR spends 0 steps: drawn at a tenth of the smallest positive x.
        positive = [x for x, _, _ in pts if x > 0]
        floor = min(positive) / 10 if positive else 1.0
        xs = [x if x > 0 else floor for x, _, _ in pts]
        ax.plot(xs, [statistics.mean(q) for _, _, q in pts], "-", color="C0", lw=1.5)
        for x, (_, m, q) in zip(xs, pts):
            ax.plot([x] * len(q), q, "o", color="C0", alpha=0.5, ms=4)
            # Screened settings by their M x R alone (short labels do not run into the next
            # point's on the log axis); `screened` is the screen's default, 4 x 2.
            name = "4x2" if m == "screened" else m.removeprefix("screened-")
            ax.annotate(f"{name} (n={len(q)})", (x, statistics.mean(q)), textcoords="offset points", xytext=(4, 6), fontsize=8)
        if rand:
            ax.axhline(statistics.mean(rand), color="C1", ls="--", lw=1, label=f"random designs (mean, n={len(rand)})")
            ax.legend(loc="upper left", fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("simulated steps spent choosing designs per run (FEAR's 0 at the left;\nM x R: screened, M candidates x R short rollouts each)")
        ax.set_ylabel("quality of chosen designs (mean best eval return)")
        ax.set_title(TITLES.get(prefix, prefix))
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
