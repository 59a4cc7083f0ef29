#!/usr/bin/env bash
# Forks a running (or finished) co-adaptation at the start of design K into a new run directory
# with some config keys changed, to be continued with `coadapt run --resume NEW`.
#
#   usage: scripts/fork_run.sh SRC_RUN K NEW_RUN [KEY.PATH=VALUE ...]
#          scripts/fork_run.sh --has SRC_RUN K   (exit 0 when SRC_RUN holds that snapshot now)
#   e.g.   scripts/fork_run.sh runs/campaign/walker-fear-seed1 5 runs/campaign/walker-sim-pso-seed1 \
#              'optimizer.exploit="sim-pso"'
#          RAYON_NUM_THREADS=1 coadapt run --resume runs/campaign/walker-sim-pso-seed1 --transport in-process
#
# Why: two methods that differ only in how they choose designs (FEAR and the simulation
# baseline, say) run the same seed identically until the first chosen design (the initial
# designs are fixed, the networks and streams seeded alike). Forking the first run at that
# design instead of running the shared prefix twice saves its episodes (100 of 260 on the
# reduced protocols), and `--resume` goes on to the rows a fresh run would write (the resume
# tests in cli/tests/resume/ check that, row for row).
#
# Waits (polling every 5 s) until SRC_RUN holds the snapshot taken at the end of design K-1
# (its learner state says design K is next and no design is in progress), then copies into NEW_RUN:
# that snapshot alone, the CSVs (the resume cuts them back to the snapshot), the checkpoints,
# and the optimiser's replies for designs before K (none when K is the first chosen design:
# then the optimiser starts fresh, as it does in a fresh run). The config is SRC_RUN's with the
# overrides applied (scripts/config_with.py). Copy it soon after design K-1 ends: the source
# keeps only its newest `snapshot.keep` snapshots.
#
# The fork is the run a fresh start with the changed config would make only if nothing before
# design K depended on the changed keys: fork at the first chosen design (K = the number of
# initial designs). Later, the optimiser's generator has been drawn by the old method (sim-PSO
# draws its rollout seeds from it), and the fork is a hybrid of the two methods.
set -euo pipefail
cd "$(dirname "$0")/.."
has=""
if [ "${1:-}" = --has ]; then has=1; shift; fi
src=${1:?usage: scripts/fork_run.sh SRC_RUN K NEW_RUN [KEY.PATH=VALUE ...]}
k=${2:?design index K}
[[ $k =~ ^[1-9][0-9]*$ ]] || { echo "fork_run: K must be a design index of at least 1, not $k" >&2; exit 2; }

find_snapshot() {
  python3 - "$src/snapshots" "$k" <<'PY'
import json, os, sys
root, k = sys.argv[1], int(sys.argv[2])
if not os.path.isdir(root):
    sys.exit(1)
for name in sorted(os.listdir(root)):
    if not name.startswith("snap-"):
        continue
    try:
        with open(os.path.join(root, name, "state.json")) as f:
            v = json.load(f)["values"]
        p = v["progress"]
    except (OSError, ValueError, KeyError):
        continue
    # At a design's end the learner has closed its episodes (nothing in progress) and names the
    # next design; the finished design's row is still "open" until the next one starts.
    if p.get("design") == k and p.get("in_design") is None:
        print(name)
        sys.exit(0)
sys.exit(1)
PY
}

if [ -n "$has" ]; then find_snapshot > /dev/null; exit; fi
dst=${3:?new run directory}
shift 3
[ -e "$dst" ] && { echo "fork_run: $dst exists already" >&2; exit 2; }

[ -d "$src" ] || echo "fork_run: $src does not exist yet; waiting for it (Ctrl-C to stop)" >&2
# Looks into the snapshots (a Python start) only when their directory listing or times have
# changed: a campaign queue keeps dozens of these watchers waiting for hours.
seen=""
while :; do
  now=$(ls -l --time-style=+%s.%N "$src/snapshots" 2>/dev/null || true)
  if [ -n "$now" ] && [ "$now" != "$seen" ]; then
    if snap=$(find_snapshot); then break; fi
    seen=$now
  fi
  if [ -s "$src/summary.json" ]; then
    snap=$(find_snapshot) && break
    echo "fork_run: $src has finished and kept no snapshot at the start of design $k" >&2
    exit 1
  fi
  sleep 5
done
tmp=$dst.forking
rm -rf "$tmp"
mkdir -p "$tmp/snapshots"
cp -a "$src/snapshots/$snap" "$tmp/snapshots/" || {
  rm -rf "$tmp"
  echo "fork_run: $src/snapshots/$snap went away while being copied (the source keeps its newest snapshot.keep); fork sooner or raise snapshot.keep" >&2
  exit 1
}
cp -a "$src/designs.csv" "$src/episodes.csv" "$tmp/"
[ -d "$src/checkpoints" ] && cp -a "$src/checkpoints" "$tmp/"
mkdir -p "$tmp/optimizer"
if [ -f "$src/optimizer/optimizer-state.jsonl" ]; then
  python3 - "$src/optimizer/optimizer-state.jsonl" "$k" > "$tmp/optimizer/optimizer-state.jsonl" <<'PY'
import json, sys
path, k = sys.argv[1], int(sys.argv[2])
for line in open(path):
    try:
        if json.loads(line)["key"]["index"] < k:
            print(line, end="")
    except (ValueError, KeyError):
        pass  # a torn last line: the optimiser would skip it too
PY
fi
python3 scripts/config_with.py "$src/config.toml" "$@" > "$tmp/config.toml"
printf '%s at the start of design %s (%s), with: %s\n' "$src" "$k" "$snap" "${*:-no changes}" > "$tmp/forked-from.txt"
mv "$tmp" "$dst"
echo "fork_run: $dst is $src at the start of design $k ($snap), with ${*:-no changes}; continue it with: coadapt run --resume $dst"
