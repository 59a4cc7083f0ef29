#!/usr/bin/env bash
# Runs a queue of co-adaptation experiments (issue 10's campaign), N at a time, each
# single-threaded (RAYON_NUM_THREADS=1), in-process (the same results as a fleet of processes,
# tested byte for byte; fewer processes competing for two cores).
#
#   usage: scripts/campaign.sh [-j N] QUEUE_FILE
#
# QUEUE_FILE: one experiment per line, `NAME CONFIG SEED [coadapt run flags...]`; `#` starts a
# comment. NAME becomes runs/campaign/NAME-seedSEED. A line whose run directory already holds a
# finished run (summary.json) is skipped, so the same queue can be started again after a stop:
# an unfinished directory is moved aside to NAME-seedSEED.partial-<time> and the run starts
# over. CONFIG may carry overrides, `CONFIG+key.path=value+...` (TOML values, e.g.
# `configs/half-cheetah-reduced.toml+learner.population-only=true+optimizer.q="pessimistic"`),
# applied by scripts/config_with.py. `random-only:CONFIG` is CONFIG with `alternate = false`
# (every later design uniform random, the thesis's random-designs baseline; pass --exploit random).
# Each run's stdout (the JSON summary line) goes to RUN/summary.json, stderr to RUN.log.
# A finished run's small files (summary.json, config.toml, designs.csv, episodes.csv) are also
# copied to docs/campaign/results/NAME-seedSEED/ to be committed: runs/ does not survive a new
# checkout, and a line whose results are archived there is skipped too.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=2
if [ "${1:-}" = "-j" ]; then jobs=$2; shift 2; fi
queue=${1:?usage: scripts/campaign.sh [-j N] QUEUE_FILE}
[ -f "$queue" ] || { echo "campaign: no queue file $queue" >&2; exit 2; }
root=runs/campaign
mkdir -p "$root/configs"
bin=$root/coadapt
cargo build --release -q -p coadapt
# A private copy: rebuilding the workspace during the campaign does not touch running runs.
cp target/release/coadapt "$bin.new" && mv "$bin.new" "$bin"

run_one() {
  local name=$1 config=$2 seed=$3; shift 3
  local dir=$root/$name-seed$seed
  local archive=docs/campaign/results/$name-seed$seed
  if [ -s "$dir/summary.json" ] || [ -s "$archive/summary.json" ]; then echo "campaign: $name-seed$seed done already, skipped"; return 0; fi
  if [ -e "$dir" ]; then mv "$dir" "$dir.partial-$(date +%s)"; fi
  case $config in
    random-only:*) config="${config#random-only:}+schedule.alternate=false" ;;
  esac
  if [[ $config == *+* ]]; then
    local base=${config%%+*} c=$root/configs/$name-seed$seed.toml
    local IFS=+
    # shellcheck disable=SC2086 # split the overrides on +
    python3 scripts/config_with.py "$base" ${config#*+} > "$c" || { echo "campaign: bad config $config" >&2; return 1; }
    unset IFS
    config=$c
  fi
  echo "campaign: start $dir ($(date -u +%H:%M:%S))"
  local t0=$SECONDS
  if RAYON_NUM_THREADS=1 "$bin" run --config "$config" --seed "$seed" --out "$dir" --transport in-process "$@" \
      > "$dir.summary.tmp" 2> "$dir.log"; then
    mv "$dir.summary.tmp" "$dir/summary.json"
    mkdir -p "$archive"
    cp "$dir"/{summary.json,config.toml,designs.csv,episodes.csv} "$archive/"
    echo "campaign: done  $dir in $((SECONDS - t0)) s: $(cat "$dir/summary.json")"
  else
    echo "campaign: FAILED $dir after $((SECONDS - t0)) s (see $dir.log)" >&2
  fi
}

running=0
while read -r name config seed rest; do
  case $name in ''|'#'*) continue ;; esac
  # shellcheck disable=SC2086 # the flags are words
  run_one "$name" "$config" "$seed" $rest &
  running=$((running + 1))
  if [ "$running" -ge "$jobs" ]; then wait -n || true; running=$((running - 1)); fi
done < "$queue"
wait
echo "campaign: queue $queue finished"
