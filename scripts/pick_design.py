"""The body a run recommends, or its control: prints a design of RUN/designs.csv, comma-separated.

usage: python3 scripts/pick_design.py RUN_DIR exploit|explore|best

exploit: the exploitation design (the method's own choice) with the highest best evaluation
return; explore: the exploration (random) design with the highest; best: any design's highest
(for a random-designs run, whose every later design is random, `exploit` and `best` agree). Used
by scripts/campaign.sh's retrain lines (issue 28 section 2: the body apart from the controller).
Prints also the design's index and return on stderr.
"""
import csv
import sys

if len(sys.argv) != 3 or sys.argv[2] not in ("exploit", "explore", "best"):
    sys.exit(__doc__)
path, which = sys.argv[1], sys.argv[2]
with open(f"{path}/designs.csv") as f:
    rows = [r for r in csv.DictReader(f) if r.get("prototype") != "rejected" and r["best_eval_return"]]
if which != "best":
    rows = [r for r in rows if r["kind"] == which]
if not rows:
    sys.exit(f"pick_design: {path}/designs.csv has no {which} design with an evaluation")
best = max(rows, key=lambda r: float(r["best_eval_return"]))
print(",".join(best["design"].split(";")))
print(f"pick_design: {path} {which}: design {best['index']}, best evaluation return {best['best_eval_return']}", file=sys.stderr)
