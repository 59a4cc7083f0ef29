#!/usr/bin/env bash
# `coadapt bench conv` (the image embedding's convolutions, one thread) against PyTorch CPU on
# the same shapes (bench/peers/conv_bench.py), in one run (BENCHMARKS.md). First the numeric
# checks: ours dumps every layer's shape, inputs and outputs (forward, parameter and input
# gradients), the peer recomputes them with torch.nn.functional in float64 and float32 and
# compares (fails beyond 1e-4 relative); the same with ours' bf16 products against float64 and
# PyTorch's bf16 autocast (ours no further from float64 than twice autocast). Then ROUNDS rounds
# of ours f32 / ours bf16 / PyTorch f32 with one thread (the matched figure) / PyTorch under bf16
# autocast with one thread / PyTorch f32 with its default threads (context), the peer reading
# the shapes from ours' dump; each round's ratios via bench/ratios.py, then per figure the
# median and range of the rounds' ratios.
#   usage: bench/compare_conv.sh [rounds, default 3] [repetitions, default 100] [batches, default 32,1]
# PAUSE_PIDS="pid ..." stops those processes (SIGSTOP) for the duration and always resumes
# them (SIGCONT) on exit, so a long experiment can share the machine without sharing the timing.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
reps=${2:-100}
batch=${3:-32,1}
VENV_PEERS=${VENV_PEERS:-.venv-peers} bash bench/peers/setup.sh >/dev/null
cargo build --release -q -p coadapt
bin=${CARGO_TARGET_DIR:-target}/release/coadapt
py=${VENV_PEERS:-.venv-peers}/bin/python
mkdir -p runs
stamp=$(date +%Y%m%d-%H%M%S)
out=runs/bench-conv-$stamp.jsonl
dump=runs/bench-conv-$stamp-dump.json
if [ -n "${PAUSE_PIDS:-}" ]; then
  trap 'kill -CONT $PAUSE_PIDS 2>/dev/null || true' EXIT
  kill -STOP $PAUSE_PIDS
fi
"$bin" bench conv --dump "$dump" --dump-only
"$py" bench/peers/conv_bench.py --check "$dump" | tee "$out.check"
"$bin" bench conv --dump "$dump.bf16" --dump-only --precision bf16
"$py" bench/peers/conv_bench.py --check "$dump.bf16" | tee -a "$out.check"
for r in $(seq 1 "$rounds"); do
  round=runs/bench-conv-$stamp-round$r.jsonl
  {
    "$bin" bench conv --repetitions "$reps" --batch "$batch"
    "$bin" bench conv --repetitions "$reps" --batch "$batch" --precision bf16
    "$py" bench/peers/conv_bench.py --shapes "$dump" --repetitions "$reps" --batch "$batch" --threads 1
    "$py" bench/peers/conv_bench.py --shapes "$dump" --repetitions "$reps" --batch "$batch" --threads 1 --autocast
    "$py" bench/peers/conv_bench.py --shapes "$dump" --repetitions "$reps" --batch "$batch" --threads 0
  } | tee "$round" | tee -a "$out"
  python3 bench/ratios.py "$round" | sed "s/^{/{\"round\": $r, /" | tee -a "$out.ratios"
done
python3 - "$out" "$out.ratios" <<'PY'
import json, sys, statistics
figs = [json.loads(l) for l in open(sys.argv[1]) if l.startswith("{")]
ratios = [json.loads(l) for l in open(sys.argv[2]) if l.startswith("{")]
by = {}
for r in ratios:
    by.setdefault((r["bench"], r["config"]), []).append(r)
for (bench, config), rs in by.items():
    v = sorted(r["value"] for r in rs)
    ours = sorted(r["coadapt"] for r in rs)
    peer = sorted(r["peer"] for r in rs)
    print(json.dumps({"bench": bench, "config": config, "rounds": len(v), "median": statistics.median(v),
                      "min": v[0], "max": v[-1], "unit": "x faster", "coadapt_ms": [ours[0], ours[-1]],
                      "peer_ms": [peer[0], peer[-1]]}))
PY
