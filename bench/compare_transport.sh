#!/usr/bin/env bash
# `coadapt bench transport` over gRPC, its Python grpcio peer, then ours over shared memory, in
# one run; then the ratios (BENCHMARKS.md).
#   usage: bench/compare_transport.sh [seconds per figure, default 5]
# Installs the peer's venv packages on first use (bench/peers/setup.sh transport: grpcio only,
# no torch). Every figure spawns its own actor processes; run on an idle machine.
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-5}
bash bench/peers/setup.sh transport >/dev/null
cargo build --release -q -p coadapt
mkdir -p runs
out=runs/bench-transport-$(date +%Y%m%d-%H%M%S).jsonl
{
  ./target/release/coadapt bench transport --transport grpc --seconds "$secs"
  .venv-peers/bin/python bench/peers/transport_grpc.py --seconds "$secs"
  ./target/release/coadapt bench transport --transport shm --seconds "$secs"
} | tee "$out"
python3 bench/ratios.py "$out"
