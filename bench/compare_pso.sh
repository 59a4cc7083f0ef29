#!/usr/bin/env bash
# `coadapt bench pso` and the PyTorch PSO-over-Q peer in one run, then the ratio (BENCHMARKS.md).
#   usage: bench/compare_pso.sh [--large]   (--large adds 256 start states: about 4 more minutes)
set -euo pipefail
cd "$(dirname "$0")/.."
bash bench/peers/setup.sh >/dev/null
cargo build --release -q
states=32
[ "${1:-}" = "--large" ] && states=32,256
mkdir -p runs
out=runs/bench-pso-$(date +%Y%m%d-%H%M%S).jsonl
{
  ./target/release/coadapt bench pso --states "$states"
  for s in ${states//,/ }; do .venv-peers/bin/python bench/peers/pso_q.py --states "$s"; done
} | tee "$out"
python3 bench/ratios.py "$out"
