#!/usr/bin/env bash
# `coadapt bench groups` (one GrouPS update) against the same update in NumPy
# (bench/peers/groups_update.py), in one run (BENCHMARKS.md). First the numeric check: ours
# dumps its inputs and one update's outputs, the peer recomputes that update from the same
# inputs and compares M, W, alpha, tau (fails beyond 1e-4 relative). Then ROUNDS rounds of
# ours / peer, the peer timing the very inputs ours dumped; each round's ratio via
# bench/ratios.py, then the median and range of the rounds' ratios.
#   usage: bench/compare_groups.sh [rounds, default 3] [repetitions, default 200]
# PAUSE_PIDS="pid ..." stops those processes (SIGSTOP) for the duration and always resumes
# them (SIGCONT) on exit, so a long experiment can share the machine without sharing the timing.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
reps=${2:-200}
bash bench/peers/setup.sh >/dev/null
cargo build --release -q -p coadapt
bin=${CARGO_TARGET_DIR:-target}/release/coadapt
py=.venv-peers/bin/python
mkdir -p runs
stamp=$(date +%Y%m%d-%H%M%S)
out=runs/bench-groups-$stamp.jsonl
dump=runs/bench-groups-$stamp-dump.json
if [ -n "${PAUSE_PIDS:-}" ]; then
  trap 'kill -CONT $PAUSE_PIDS 2>/dev/null || true' EXIT
  kill -STOP $PAUSE_PIDS
fi
"$bin" bench groups --repetitions 1 --warmup 0 --dump "$dump" >/dev/null
"$py" bench/peers/groups_update.py --check "$dump" | tee "$out.check"
for r in $(seq 1 "$rounds"); do
  round=runs/bench-groups-$stamp-round$r.jsonl
  {
    "$bin" bench groups --repetitions "$reps"
    "$py" bench/peers/groups_update.py --repetitions "$reps" --inputs "$dump"
  } | tee "$round" | tee -a "$out"
  python3 bench/ratios.py "$round" | sed "s/^{/{\"round\": $r, /" | tee -a "$out.ratios"
done
python3 - "$out" "$out.ratios" <<'PY'
import json, sys, statistics
figs = [json.loads(l) for l in open(sys.argv[1]) if l.startswith("{")]
for impl in ("coadapt", "numpy"):
    v = sorted(f["value"] for f in figs if f.get("impl") == impl)
    print(json.dumps({"impl": impl, "rounds": len(v), "median_ms_min": v[0], "median_ms_max": v[-1]}))
ratios = sorted(json.loads(l)["value"] for l in open(sys.argv[2]))
print(json.dumps({"bench": "groups_update_ratio", "rounds": len(ratios), "median": statistics.median(ratios),
                  "min": ratios[0], "max": ratios[-1], "unit": "x faster"}))
PY
