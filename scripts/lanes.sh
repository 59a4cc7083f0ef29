#!/usr/bin/env bash
# Keeps the machine's lanes busy across queues: each LANE argument is a list of queue files (one
# word each) run one after another by scripts/campaign.sh -j 1, every lane at once. A queue
# already running (started by hand, or by another lane) is waited for, not started twice. With
# --until TIME every queue starts only the lines that end by then (campaign.sh --until), and no
# queue starts after it: a session whose machine may not be kept ends with finished runs.
# Ctrl-C or SIGTERM stops the lanes: the queues running stop as `campaign.sh --stop` stops them
# (their runs snapshot), and no further queue starts.
#
#   usage: [BIN=coadapt-binary] [THREADS=1] scripts/lanes.sh [--until TIME] LANE [LANE ...]
#   e.g.   scripts/lanes.sh --until 05:20 "docs/campaign/hc-forks.queue docs/campaign/design-bench.queue" \
#              "docs/campaign/design-choice.queue docs/campaign/fidelity-ablations.queue"
# Each queue's output goes to runs/campaign-NAME.log (NAME: the queue file's name without
# .queue), this script's own lines to standard output. A mujoco-* queue runs through
# scripts/mujoco_lane.sh, which brings up the Python bridge its robot is served by.
set -euo pipefail
cd "$(dirname "$0")/.."
until_arg=()
case ${1:-} in
  -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
  --until)
    t=$(date -d "${2:-}" +%s 2> /dev/null) || { echo "lanes: --until takes a time date -d reads (say 07:05), not '${2:-}'" >&2; exit 2; }
    [ "$t" -gt "$(date +%s)" ] || { echo "lanes: --until '${2:-}' is $(date -d "@$t" '+%F %H:%M'), already past" >&2; exit 2; }
    until_arg=(--until "$(date -d "@$t" '+%F %H:%M:%S')")
    until_s=$t
    shift 2 ;;
esac
[ $# -gt 0 ] || { echo "usage: scripts/lanes.sh [--until TIME] LANE [LANE ...] (a LANE: queue files, space-separated)" >&2; exit 2; }
for lane in "$@"; do
  for q in $lane; do
    [ -f "$q" ] || { echo "lanes: no queue file $q" >&2; exit 2; }
  done
done
# As campaign.sh: a script that leads its session gives its nice to the session's scheduling
# group, or `nice scripts/lanes.sh` would not yield the cores to a build.
if [ "$(ps -o sid= -p $$ | tr -d ' ')" = "$$" ] && [ -w /proc/self/autogroup ]; then
  echo "$(ps -o ni= -p $$ | tr -d ' ')" > /proc/self/autogroup 2> /dev/null || true
fi
mkdir -p runs/campaign
stopflag=runs/campaign/lanes-$$.stopping
trap 'rm -f "$stopflag"' EXIT
pidfile_of() { echo "runs/campaign/$(basename "$1" .queue).pid"; }
live() {
  local p
  p=$(cat "$(pidfile_of "$1")" 2> /dev/null || true)
  [[ $p =~ ^[1-9][0-9]*$ ]] && grep -qa campaign.sh "/proc/$p/cmdline" 2> /dev/null
}
run_lane() {
  local i=$1 q; shift
  for q in "$@"; do
    while live "$q"; do
      [ -e "$stopflag" ] && return 0
      sleep 5
    done
    [ -e "$stopflag" ] && return 0
    if [ -n "${until_s:-}" ] && [ "$(date +%s)" -ge "$until_s" ]; then
      echo "lanes: lane $i: --until has passed; $q not started"
      return 0
    fi
    echo "lanes: lane $i: $q from $(date -u +%H:%M:%S)"
    local name
    name=$(basename "$q" .queue)
    local cmd=(scripts/campaign.sh -j 1 "${until_arg[@]}" "$q")
    # The MuJoCo cheetah's queues need the Python bridge: mujoco_lane.sh starts it (or uses the
    # one another lane started) around the same campaign.sh.
    if [[ $name == mujoco-* ]]; then cmd=(env UNTIL="${until_arg[1]:-}" scripts/mujoco_lane.sh "$q"); fi
    "${cmd[@]}" >> "runs/campaign-$name.log" 2>&1 < /dev/null || echo "lanes: lane $i: $q ended with an error (runs/campaign-$name.log)"
    echo "lanes: lane $i: $q ended at $(date -u +%H:%M:%S)"
  done
}
# The queues this script started stop as `campaign.sh --stop` stops them (a TERM to their
# campaign.sh, a child of its lane; a queue started by hand that a lane waits for is left alone).
stop_lanes() {
  touch "$stopflag"
  local p
  for p in "${pids[@]}"; do pkill -TERM -P "$p" 2> /dev/null || true; done
}
pids=()
# Before the lanes start: a signal from their first moment on stops them (the lanes, subshells,
# do not inherit the trap).
trap stop_lanes INT TERM
i=0
for lane in "$@"; do
  i=$((i + 1))
  # shellcheck disable=SC2086 # a lane is a list of queue files
  run_lane "$i" $lane &
  pids+=($!)
done
for p in "${pids[@]}"; do
  while kill -0 "$p" 2> /dev/null; do wait "$p" || true; done
done
echo "lanes: every lane ended at $(date -u +%H:%M:%S)"
