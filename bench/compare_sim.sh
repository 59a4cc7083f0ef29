#!/usr/bin/env bash
# `coadapt bench sim` for HalfCheetah and MuJoCo's HalfCheetah-v5 (gymnasium) in one run, then the
# ratio (BENCHMARKS.md). Both on one core, random actions, resets included.
#   usage: bench/compare_sim.sh [seconds, default 10]
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-10}
bash bench/peers/setup.sh >/dev/null
cargo build --release -q
mkdir -p runs
out=runs/bench-sim-$(date +%Y%m%d-%H%M%S).jsonl
{
  ./target/release/coadapt bench sim --seconds "$secs"
  .venv-peers/bin/python bench/peers/sim_mujoco.py --seconds "$secs" 2>/dev/null
  ./target/release/coadapt bench sim --seconds "$secs" --env half-cheetah
} | tee "$out"
python3 bench/ratios.py "$out"
