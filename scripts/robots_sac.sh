#!/usr/bin/env bash
# Does SAC learn each robot on its original design? (issue 10: before co-adapting Walker, Hopper
# and Daisy.) `coadapt train` with the reference SAC settings, STEPS steps (1000 per episode),
# two robots at a time, single-threaded.
#   usage: scripts/robots_sac.sh [STEPS, default 100000] [SEED, default 1] [ROBOTS..., default walker hopper daisy]
# Writes runs/robots-sac/ROBOT-seedSEED/ and prints the mean return of the last 10 episodes
# every 10 episodes for each.
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-100000}
seed=${2:-1}
shift $(($# < 2 ? $# : 2))
if [ $# -gt 0 ]; then robots=("$@"); else robots=(walker hopper daisy); fi
root=runs/robots-sac
mkdir -p "$root"
cargo build --release -q -p coadapt
bin=$root/coadapt
cp target/release/coadapt "$bin.new" && mv "$bin.new" "$bin"
running=0
for r in "${robots[@]}"; do
  dir=$root/$r-seed$seed
  if [ ! -s "$dir/summary.json" ]; then
    rm -rf "$dir"
    ( RAYON_NUM_THREADS=1 "$bin" train --env "$r" --algo sac --steps "$steps" --seed "$seed" --quiet --out "$dir" > "$dir.summary" 2> "$dir.log" \
        && mv "$dir.summary" "$dir/summary.json" ) &
    running=$((running + 1))
    if [ "$running" -ge 2 ]; then wait -n || true; running=$((running - 1)); fi
  fi
done
wait
python3 - "$root" "$seed" "${robots[@]}" <<'PY'
import csv, sys
root, seed, robots = sys.argv[1], sys.argv[2], sys.argv[3:]
for r in robots:
    try:
        rows = list(csv.DictReader(open(f"{root}/{r}-seed{seed}/episodes.csv")))
    except FileNotFoundError:
        print(f"{r}: no episodes.csv"); continue
    marks = [rows[i] for i in range(9, len(rows), 10)]
    print(f"{r} seed {seed}: mean of last 10 every 10 episodes:", ", ".join(f"{float(m['mean_return_last_10']):.0f}" for m in marks),
          f"(last: {float(rows[-1]['mean_return_last_10']):.1f} after {len(rows)} episodes)")
PY
