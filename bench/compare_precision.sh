#!/usr/bin/env bash
# Issue 34's figures in one run: SAC updates/s and PSO over Q, ours in f32 and in bf16 against
# PyTorch in f32 and under bf16 autocast, the four sides interleaved in each of ROUNDS rounds so
# that a drift in the machine's speed hits all alike; then the table (median and range over the
# rounds, and the ratios round by round) from bench/precision_report.py.
#   usage: [BEFORE=coadapt-binary] bench/compare_precision.sh [ROUNDS, default 3] [SECONDS per SAC figure, default 10]
# BEFORE: an older build whose f32 figures join each round as "impl": "coadapt-before" (the
# issue's "today's f32": the same machine, the same run).
# Installs the peer venv on first use (bench/peers/setup.sh; VENV_PEERS=dir to keep it
# elsewhere). Run on an idle machine: both sides use the two cores (rayon's pool, torch threads 2).
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
secs=${2:-10}
venv=${VENV_PEERS:-.venv-peers}
VENV_PEERS=$venv bash bench/peers/setup.sh >/dev/null
cargo build --release -q -p coadapt
mkdir -p runs
out=runs/bench-precision-$(date +%Y%m%d-%H%M%S).jsonl
bin=./target/release/coadapt
py=$venv/bin/python
echo "writing $out" >&2
for r in $(seq 1 "$rounds"); do
  echo "round $r of $rounds" >&2
  {
    "$bin" bench nn --only sac_update --seconds "$secs"
    "$bin" bench nn --only sac_update --seconds "$secs" --precision bf16
    if [ -n "${BEFORE:-}" ]; then
      "$BEFORE" bench nn --only sac_update --seconds "$secs" | sed 's/"impl":"coadapt"/"impl":"coadapt-before"/'
    fi
    "$py" bench/peers/sac_step.py --seconds "$secs"
    "$py" bench/peers/sac_step.py --seconds "$secs" --autocast
    "$bin" bench pso
    "$bin" bench pso --precision bf16
    if [ -n "${BEFORE:-}" ]; then
      "$BEFORE" bench pso | sed 's/"impl":"coadapt"/"impl":"coadapt-before"/'
    fi
    "$py" bench/peers/pso_q.py
    "$py" bench/peers/pso_q.py --autocast
  } | python3 -c "import json, sys
for line in sys.stdin:
    d = json.loads(line); d['round'] = $r; print(json.dumps(d), flush=True)" | tee -a "$out"
done
python3 bench/precision_report.py "$out"
