#!/usr/bin/env bash
# What network faults cost a fleet (issue 33, BENCHMARKS.md "The fleet under network faults"):
# the multi-host test (learner + optimiser in one namespace, one actor in each of two others,
# gRPC with TLS and tokens across a bridge) on the tiny config lengthened to 60 designs (122
# episodes), under each fault in turn, ROUNDS times back to back; every run must also write the
# undisturbed in-process run's rows (--compare). One JSON line per run into OUT.
#
#   deploy/netns/faults-bench.sh [ROUNDS] [OUT]      (as root; default 3 rounds, target/faults.jsonl)
#   python3 deploy/netns/faults_table.py OUT         (the table: median and spread per fault)
set -euo pipefail
cd "$(dirname "$0")/../.."
rounds=${1:-3}
out=${2:-target/faults.jsonl}
bin=${COADAPT_BIN:-target/release/coadapt}
faults=(
  ""
  "--latency 100 --jitter 20"
  "--loss 2"
  "--partition 60"
  "--partition 60 --lease 10"
  "--latency 100 --jitter 20 --loss 2 --partition 60 --lease 10"
)
for ((r = 1; r <= rounds; r++)); do
  for f in "${faults[@]}"; do
    # shellcheck disable=SC2086 # the fault flags are words
    bash deploy/netns/multi-host-test.sh --designs 60 --compare --report "$out" $f "$bin" 2>"$out.log" >/dev/null ||
      { echo "faults-bench: FAILED with '$f' (see $out.log)" >&2; exit 1; }
    echo "faults-bench: round $r, '${f:-no fault}': $(tail -n 1 "$out")" >&2
  done
done
