"""Tables for one long run, design by design: the reference-protocol run of issue 28
(docs/campaign/results/hc-reference-bf16-seed1-partial), which grows across sessions.

usage: python3 scripts/reference_report.py RUN_DIR [--initial 5] [--tables designs,summary]

- `designs`: one row per design of RUN_DIR/designs.csv: its kind, the design (2 decimals), the
  episodes trained on it, its best evaluation return, the objective the optimiser predicted for
  it (chosen designs only) and how many of its coordinates sit within 2 % of the box's width of
  a bound;
- `summary`: one row: designs and episodes so far, the initial designs' best returns (mean ±
  sample sd, n), the chosen designs' and the exploitation designs' mean best return, each
  exploitation design minus the exploration design after it (mean ± sample sd, wins/pairs, sign
  test p) and the best design so far.

Without --tables both print with headings; with it, only the named ones and no headings (as
docs/EXPERIMENTS.md includes them, scripts/doc_tables.py). Pure Python, the system python3.
"""
import csv
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from campaign_report import BOUNDS, mean_sd, near_bound, p_value, read_run, sign_test  # noqa: E402
from campaign_runs import flag_value  # noqa: E402

TABLES = ["designs", "summary"]


def main():
    valued = {"--initial", "--tables"}
    args = [a for i, a in enumerate(sys.argv[1:], 1) if not a.startswith("--") and sys.argv[i - 1] not in valued]
    if len(args) != 1:
        sys.exit("usage: python3 scripts/reference_report.py RUN_DIR [--initial 5] [--tables designs,summary]")
    run = args[0]
    if not os.path.exists(os.path.join(run, "designs.csv")):
        sys.exit(f"reference_report: {run} has no designs.csv")
    try:
        n_init = int(flag_value("--initial", "5", "reference_report"))
    except ValueError:
        sys.exit("reference_report: --initial needs a whole number")
    only = flag_value("--tables", None, "reference_report")
    only = None if only is None else only.split(",")
    bad = [t for t in (only or []) if t not in TABLES]
    if bad:
        sys.exit(f"reference_report: --tables: unknown table {', '.join(bad)} (known: {', '.join(TABLES)})")

    env, rows = read_run(run)
    with open(os.path.join(run, "designs.csv")) as f:
        extra = {int(r["index"]): r for r in csv.DictReader(f) if r.get("prototype") != "rejected"}
    low, high = BOUNDS.get(env, (None, None))

    def near(r):
        return "-" if low is None else f"{near_bound(r['design'], low, high, 2e-2)}/{len(r['design'])}"

    first = True
    for table in TABLES:
        if only is not None and table not in only:
            continue
        if not first:
            print()
        first = False
        if table == "designs":
            if only is None:
                print(f"### {run}: design by design\n")
            print("| design | kind | design vector | episodes | best evaluation return | predicted objective | coordinates near a bound |")
            print("|---|---|---|---|---|---|---|")
            for r in rows:
                e = extra[r["index"]]
                vec = " ".join(f"{x:.2f}" for x in r["design"])
                pred = f"{float(e['predicted_objective']):.1f}" if e["predicted_objective"] else "-"
                print(f"| {r['index']} | {r['kind']} | {vec} | {e['episodes']} | {r['best']:.1f} | {pred} | {near(r)} |")
        else:
            if only is None:
                print(f"### {run}: so far\n")
            episodes = sum(int(extra[r["index"]]["episodes"]) for r in rows)
            initial = [r["best"] for r in rows if r["index"] < n_init]
            chosen = [r for r in rows if r["index"] >= n_init]
            exploit = [r for r in chosen if r["kind"] == "exploit"]
            by_index = {r["index"]: r for r in rows}
            diffs = [r["best"] - by_index[r["index"] + 1]["best"] for r in exploit
                     if by_index.get(r["index"] + 1, {}).get("kind") == "explore"]
            avg = lambda rs: f"{statistics.mean(x['best'] for x in rs):.1f}" if rs else "-"
            if diffs:
                wins = sum(d > 0 for d in diffs)
                pairs = f"{mean_sd(diffs, sign='+')} ({wins}/{len(diffs)}, p = {p_value(sign_test(diffs))})"
            else:
                pairs = "-"
            best = max(rows, key=lambda r: r["best"])
            print("| designs | episodes | initial designs | chosen designs | exploitation designs | exploit - next explore | best design |")
            print("|---|---|---|---|---|---|---|")
            print(f"| {len(rows)} | {episodes} | {mean_sd(initial)} (n = {len(initial)}) | {avg(chosen)} (n = {len(chosen)}) "
                  f"| {avg(exploit)} (n = {len(exploit)}) | {pairs} | {best['best']:.1f} (design {best['index']}, {best['kind']}) |")


if __name__ == "__main__":
    main()
