#!/usr/bin/env bash
# Archives what a run still going has written so far, for a run that spans sessions (the
# reference protocol): config.toml, designs.csv, episodes.csv and the optimiser's
# calibration.csv go to docs/campaign/results/NAME-partial/ with partial.json (designs finished,
# episodes, the newest snapshot's label), never summary.json: reports that count finished runs
# skip it, and the campaign does not mistake it for a finished run.
#   usage: scripts/archive_partial.sh RUN_DIR
set -euo pipefail
cd "$(dirname "$0")/.."
run=${1:?usage: scripts/archive_partial.sh RUN_DIR}
[ -f "$run/designs.csv" ] || { echo "archive_partial: $run has no designs.csv" >&2; exit 2; }
dst=docs/campaign/results/$(basename "$run")-partial
mkdir -p "$dst"
cp "$run"/{config.toml,designs.csv,episodes.csv} "$dst/"
if [ -f "$run/optimizer/calibration.csv" ]; then cp "$run/optimizer/calibration.csv" "$dst/"; fi
python3 - "$run" > "$dst/partial.json" <<'PY'
import csv, json, os, sys
run = sys.argv[1]
designs = sum(1 for _ in csv.DictReader(open(os.path.join(run, "designs.csv"))))
episodes = sum(1 for _ in csv.DictReader(open(os.path.join(run, "episodes.csv"))))
label = None
snaps = sorted(d for d in os.listdir(os.path.join(run, "snapshots")) if d.startswith("snap-")) if os.path.isdir(os.path.join(run, "snapshots")) else []
if snaps:
    try:
        label = json.load(open(os.path.join(run, "snapshots", snaps[-1], "MANIFEST.json"))).get("label")
    except (OSError, ValueError):
        pass
print(json.dumps({"designs_written": designs, "episodes": episodes, "newest_snapshot": label}))
PY
echo "archive_partial: $dst ($(cat "$dst/partial.json"))"
