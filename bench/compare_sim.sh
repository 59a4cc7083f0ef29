#!/usr/bin/env bash
# `coadapt bench sim` for HalfCheetah against MuJoCo's HalfCheetah-v5 (gymnasium), ROUNDS times
# in one run, each round ours / peer / ours, then the ratio of every round and their spread
# (BENCHMARKS.md). Both on one core, uniform random actions drawn before the timed loop,
# resets included. A first pass times every robot of ours once.
#   usage: bench/compare_sim.sh [seconds, default 10] [rounds, default 3]
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-10}
rounds=${2:-3}
bash bench/peers/setup.sh >/dev/null
cargo build --release -q -p coadapt
mkdir -p runs
stamp=$(date +%Y%m%d-%H%M%S)
out=runs/bench-sim-$stamp.jsonl
./target/release/coadapt bench sim --seconds "$secs" | tee "$out"
for r in $(seq 1 "$rounds"); do
  round=runs/bench-sim-$stamp-round$r.jsonl
  {
    ./target/release/coadapt bench sim --seconds "$secs" --env half-cheetah
    .venv-peers/bin/python bench/peers/sim_mujoco.py --seconds "$secs" 2>/dev/null
    ./target/release/coadapt bench sim --seconds "$secs" --env half-cheetah
  } | tee "$round" | tee -a "$out"
  python3 bench/ratios.py "$round" | sed "s/^{/{\"round\": $r, /" | tee -a "$out.ratios"
done
python3 - "$out.ratios" <<'PY'
import json, sys, statistics
rows = [json.loads(l) for l in open(sys.argv[1])]
for bench in sorted({r["bench"] for r in rows}):
    v = sorted(r["value"] for r in rows if r["bench"] == bench)
    print(json.dumps({"bench": bench, "rounds": len(v), "median": statistics.median(v), "min": v[0], "max": v[-1], "unit": "x faster"}))
PY
