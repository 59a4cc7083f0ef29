#!/usr/bin/env bash
# The learner's time per FEAR episode where both network pairs train (the reference protocol from
# its fourth design on: 1,000 individual and 250 population updates after every episode), two
# builds against each other: a slice of the reference protocol (configs/half-cheetah-reference.toml,
# bf16 products) with the population updates from the first design, EPISODES episodes of one
# design, `coadapt run` in process with two rayon threads, the builds interleaved in each of ROUNDS
# rounds so that a drift in the machine's speed hits both alike. Both must write the same rows
# (checked). One JSON line per run: the slice's wall seconds and seconds per trained episode.
#   usage: BEFORE=coadapt-binary [AFTER=coadapt-binary] [CONFIG=toml] [THREADS=n] bench/compare_fear_slice.sh [ROUNDS, default 3] [EPISODES, default 30]
# AFTER defaults to this checkout's release build. CONFIG (a HalfCheetah config; default the
# reference protocol) and THREADS (default 2) set the slice: the campaign's lanes run
# CONFIG=configs/half-cheetah-reduced.toml THREADS=1. Run on an idle machine: each side uses
# THREADS cores.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
episodes=${2:-30}
before=${BEFORE:?BEFORE=an older coadapt binary to compare with}
after=${AFTER:-}
if [ -z "$after" ]; then
  cargo build --release -q -p coadapt
  after=./target/release/coadapt
fi
work=$(mktemp -d runs/bench-fear-slice-XXXXXX 2>/dev/null || { mkdir -p runs && mktemp -d runs/bench-fear-slice-XXXXXX; })
config=${CONFIG:-configs/half-cheetah-reference.toml}
threads=${THREADS:-2}
python3 scripts/config_with.py "$config" schedule.designs=1 \
  "schedule.initial-designs=[[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]]" "schedule.initial-episodes=$episodes" \
  learner.population-updates-from-design=0 landscape-grid=0 > "$work/slice.toml"
# (3: the learner's default, learner/src/fear.rs)
warm=$(python3 -c 'import sys, tomllib; print(tomllib.load(open(sys.argv[1], "rb")).get("learner", {}).get("warmup-episodes", 3))' "$work/slice.toml")
echo "slices in $work" >&2
for r in $(seq 1 "$rounds"); do
  for side in before after; do
    bin=$before
    [ "$side" = after ] && bin=$after
    out=$work/$side-$r
    t0=$(date +%s.%N)
    RAYON_NUM_THREADS=$threads "$bin" run --config "$work/slice.toml" --out "$out" --transport in-process > /dev/null 2> "$out.log"
    t1=$(date +%s.%N)
    python3 - "$side" "$r" "$t0" "$t1" "$episodes" "$warm" "$bin" "$config" "$threads" <<'PY'
import json, sys
side, r, t0, t1, n, warm, bin, config, threads = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6]), sys.argv[7], sys.argv[8], int(sys.argv[9])
s = t1 - t0
what = "reference protocol, bf16" if config.endswith("half-cheetah-reference.toml") else config
print(json.dumps({"bench": "fear_slice", "impl": f"coadapt-{side}", "binary": bin, "round": r,
                  "config": f"{what}, 1 design x {n} episodes, population updates from design 0, {threads} thread{'s' if threads > 1 else ''}",
                  "value": round(s, 3), "unit": "s", "per_trained_episode_s": round(s / (n - warm), 4)}))
PY
  done
  for f in episodes designs; do
    if ! python3 - "$work/before-$r/$f.csv" "$work/after-$r/$f.csv" <<'PY'
import csv, sys
def rows(p):
    out = list(csv.DictReader(open(p)))
    for row in out:
        row.pop("seconds", None)
    return out
sys.exit(0 if rows(sys.argv[1]) == rows(sys.argv[2]) else 1)
PY
    then
      echo "compare_fear_slice: round $r: the two builds wrote different $f.csv rows" >&2
      exit 1
    fi
  done
done
echo "compare_fear_slice: every round's rows equal between the builds" >&2
