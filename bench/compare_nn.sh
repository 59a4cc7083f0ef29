#!/usr/bin/env bash
# `coadapt bench nn` and its PyTorch peers in one run, then the ratios (BENCHMARKS.md).
#   usage: bench/compare_nn.sh [seconds per figure, default 10]
# Installs the peer venv on first use (bench/peers/setup.sh). Run on an idle machine.
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-10}
bash bench/peers/setup.sh >/dev/null
cargo build --release -q
mkdir -p runs
out=runs/bench-nn-$(date +%Y%m%d-%H%M%S).jsonl
{
  ./target/release/coadapt bench nn --seconds "$secs" --large
  .venv-peers/bin/python bench/peers/sac_step.py --seconds "$secs"
  .venv-peers/bin/python bench/peers/forward.py --big
} | tee "$out"
python3 bench/ratios.py "$out"
