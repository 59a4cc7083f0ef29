#!/usr/bin/env bash
# Is a resume exact? Copies the run SRC_RUN (a run still going, or finished with snapshots) with
# only its newest snapshot, resumes the copy with BIN until it has written N more episode rows,
# stops it (SIGTERM), and compares those rows with SRC_RUN's (all columns but the wall clock).
#   usage: [BIN=coadapt-binary] scripts/resume_check.sh SRC_RUN [N=3] [WORK_DIR=/tmp/resume-check]
# Prints the first row that differs, or that the N rows agree.
set -euo pipefail
cd "$(dirname "$0")/.."
src=${1:?usage: scripts/resume_check.sh SRC_RUN [N] [WORK_DIR]}
n=${2:-3}
work=${3:-/tmp/resume-check}
bin=${BIN:-target/release/coadapt}
snap=$(ls "$src/snapshots" | grep '^snap-' | tail -1)
[ -n "$snap" ] || { echo "resume_check: $src has no snapshot" >&2; exit 2; }
rm -rf "$work"; mkdir -p "$work/snapshots"
cp -a "$src/snapshots/$snap" "$work/snapshots/"
for f in "$src"/*; do
  case $(basename "$f") in snapshots|checkpoints|plots) ;; *) cp -a "$f" "$work/" ;; esac
done
label=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['label'])" "$work/snapshots/$snap/MANIFEST.json" 2>/dev/null || echo "$snap")
echo "resume_check: resuming a copy of $src from $snap ($label)"
base=$(python3 - "$work/snapshots/$snap/state.json" <<'PY'
import json, sys
p = json.load(open(sys.argv[1]))["values"]["progress"]
print(p["global"])
PY
)
"$bin" run --resume "$work" --transport in-process > "$work.summary" 2> "$work.log" &
pid=$!
until [ "$(($(wc -l < "$work/episodes.csv") - 1))" -ge $((base + n)) ] || ! kill -0 $pid 2>/dev/null; do sleep 2; done
kill -TERM $pid 2>/dev/null || true
wait $pid || true
python3 - "$src/episodes.csv" "$work/episodes.csv" "$base" "$n" <<'PY'
import csv, sys
src, got, base, n = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
def rows(p):
    with open(p) as f:
        r = list(csv.DictReader(f))
    return [{k: v for k, v in x.items() if k != "seconds"} for x in r]
a, b = rows(src), rows(got)
for i in range(base, base + n):
    if i >= len(a) or i >= len(b):
        print(f"resume_check: row {i}: only {len(a)} source and {len(b)} resumed rows"); sys.exit(1)
    if a[i] != b[i]:
        print(f"resume_check: row {i} DIFFERS\n  source  {a[i]}\n  resumed {b[i]}"); sys.exit(1)
print(f"resume_check: rows {base}..{base + n - 1} agree with the source")
PY
