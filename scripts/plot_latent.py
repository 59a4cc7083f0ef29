"""Plots and tabulates `coadapt latent` runs against each other (thesis Fig. 4.5-4.8) for
docs/EXPERIMENTS.md.

usage: .venv-peers/bin/python scripts/plot_latent.py [--window W] OUT.png "TITLE" LABEL=DIR [LABEL=DIR ...]

OUT.png may be `-`: the tables only, no plot (then matplotlib is not needed, and the system
python3 runs it).

DIR may be `DIR1+DIR2+...` (or CSV files): their runs joined, unfinished runs left out.

Each DIR holds an episodes.csv of `coadapt latent` (runs x episodes). Two panels: the
deterministic actor's evaluation return after each episode (test time) and the training
episode's return with exploration (training time), mean over runs with +-1 standard
deviation shaded. Prints a markdown table: per method, the runs, and the mean (+- sd over
runs) of each run's average return over episodes 1-10, 11-20 and all, for both returns.
Every sd here is the sample standard deviation (n - 1; statistics.stdev) over the runs, the
convention of docs/EXPERIMENTS.md; the table's runs column is the n.
With --window W (the sparse reach stand-in, thesis Table 4.1): also each method's best success
rate (return > 0) over a sliding window of W episodes, per run, mean ± sd over runs, for the
training episodes and the evaluations, with the same test against the first method.
(The plot needs matplotlib: `.venv-peers/bin/pip install matplotlib`.)
"""
import csv
import os
import statistics as st
import sys


def load(spec):
    """Runs of DIR (its episodes.csv) or of a CSV file; `A+B` joins the runs of A and B in
    order (a campaign continued under another name with later seeds). Runs shorter than the
    longest (a run cut by a session's end) are left out, and said so."""
    all_runs = []
    for d in spec.split("+"):
        runs = {}
        path = d if d.endswith(".csv") else os.path.join(d, "episodes.csv")
        with open(path) as f:
            for row in csv.DictReader(f):
                r = runs.setdefault(int(row["run"]), [])
                r.append((float(row["train_return"]), float(row["eval_return"])))
        all_runs += [runs[k] for k in sorted(runs)]
    n = max(len(r) for r in all_runs)
    cut = [r for r in all_runs if len(r) < n]
    if cut:
        print(f"{spec}: {len(cut)} unfinished run(s) left out", file=sys.stderr)
    return [r for r in all_runs if len(r) == n]


def sd(v):
    """Sample standard deviation (n - 1); 0 for a single run (nothing to spread)."""
    return st.stdev(v) if len(v) > 1 else 0.0


def band(curves):
    n = min(len(c) for c in curves)
    mean = [st.mean(c[i] for c in curves) for i in range(n)]
    return mean, [sd([c[i] for c in curves]) for i in range(n)]


def run_means(runs, k, lo, hi):
    """Each run's mean of return k (1 evaluation, 0 training) over episodes lo+1..hi; empty
    when the runs are shorter than hi."""
    return [st.mean(x[k] for x in r[lo:hi]) for r in runs if len(r) >= hi]


def window(runs, k, lo, hi):
    per_run = run_means(runs, k, lo, hi)
    if not per_run:
        return "-"
    return f"{st.mean(per_run):.1f} ± {sd(per_run):.1f}"


def mann_whitney(a, b):
    """Exact two-sided Mann-Whitney p-value of a vs b (all splits enumerated; ties count half)."""
    from itertools import combinations

    def u(x, y):
        return sum(1.0 if xi > yi else 0.5 if xi == yi else 0.0 for xi in x for yi in y)

    pooled = a + b
    observed = abs(u(a, b) - len(a) * len(b) / 2)
    hits = total = 0
    for idx in combinations(range(len(pooled)), len(a)):
        x = [pooled[i] for i in idx]
        y = [pooled[i] for i in range(len(pooled)) if i not in idx]
        total += 1
        hits += abs(u(x, y) - len(a) * len(b) / 2) >= observed - 1e-12
    return hits / total


def main():
    args = sys.argv[1:]
    window_len = None
    if args and args[0] == "--window":
        window_len, args = int(args[1]), args[2:]
    out, title, pairs = args[0], args[1], args[2:]
    best = []
    plot = out != "-"
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    rows = []
    per_run = []
    for pair in pairs:
        label, d = pair.rsplit("=", 1)
        runs = load(d)
        n = min(len(r) for r in runs)
        for ax, k in zip(axes if plot else [], (1, 0)):
            mean, spread = band([[x[k] for x in r] for r in runs])
            xs = list(range(1, len(mean) + 1))
            (line,) = ax.plot(xs, mean, label=f"{label} ({len(runs)} runs)")
            ax.fill_between(xs, [m - s for m, s in zip(mean, spread)], [m + s for m, s in zip(mean, spread)], color=line.get_color(), alpha=0.2)
        rows.append((label, len(runs), n, [window(runs, k, lo, hi) for k in (1, 0) for lo, hi in ((0, 10), (10, 20), (0, n))]))
        # per window (1-10, 11-20, all): [evaluation, training] per-run means
        per_run.append([[run_means(runs, k, lo, hi) for k in (1, 0)] for lo, hi in ((0, 10), (10, 20), (0, n))])
        if window_len:
            rates = [[max(sum(x[k] > 0 for x in r[i : i + window_len]) / window_len for i in range(len(r) - window_len + 1)) for r in runs] for k in (0, 1)]
            best.append((label, rates))
    if plot:
        for ax, name in zip(axes, ("evaluation return (deterministic actor, test time)", "training return (with exploration)")):
            ax.set_xlabel("episode")
            ax.set_ylabel(name)
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=8)
        fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(out, dpi=110)
    print("| method | runs | episodes | eval 1-10 | eval 11-20 | eval all | train 1-10 | train 11-20 | train all |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, nr, n, cells in rows:
        print(f"| {label} | {nr} | {n} | " + " | ".join(cells) + " |")
    if len(rows) > 1:
        print()
        print(f"Exact two-sided Mann-Whitney p of each method's per-run means against {rows[0][0]} (episodes 1-10 / 11-20 / all):")
        for (label, *_), windows in zip(rows[1:], per_run[1:]):
            # a window the runs are too short for (fewer than 20 episodes) prints "-"
            def p(k):
                return " / ".join(f"{mann_whitney(b[k], w[k]):.3f}" if b[k] and w[k] else "-" for b, w in zip(per_run[0], windows))

            ev, tr = p(0), p(1)
            print(f"- {label}: evaluation p = {ev}, training p = {tr}")
    if best:
        print()
        print(f"| method | best training success rate over {window_len} episodes | best evaluation success rate | p (training) vs {best[0][0]} |")
        print("|---|---|---|---|")
        for label, (tr, ev) in best:
            p = "" if label == best[0][0] else f"{mann_whitney(best[0][1][0], tr):.3f}"
            print(f"| {label} | {100 * st.mean(tr):.1f}% ± {100 * sd(tr):.1f} | {100 * st.mean(ev):.1f}% ± {100 * sd(ev):.1f} | {p} |")


if __name__ == "__main__":
    main()
