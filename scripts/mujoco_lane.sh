#!/usr/bin/env bash
# The MuJoCo cheetah's lane of the design benchmark (issue 28 section 2) and of the simulator-gap
# transfer (issue 31): makes the Python bridge's virtualenv if it is missing
# (bridges/python/setup_venv.sh, into runs/venv-bridge), starts the bridge on 127.0.0.1:50071
# (the address in configs/mujoco-half-cheetah-reduced.toml), waits until it answers, runs the
# queue with scripts/campaign.sh (which resumes where it stopped and archives each run as it
# ends), and stops the bridge at the end or on Ctrl-C / SIGTERM (which stops the queue first),
# once no run of runs/campaign/mujoco-* is left using it. A bridge another lane started
# (runs/mujoco-bridge.pid) is used, not started twice, and left to that lane to stop:
# scripts/lanes.sh runs every mujoco-* queue through this script, so two lanes can share it.
#   usage: [BIN=path/to/coadapt] [UNTIL=TIME] [PORT=50071] scripts/mujoco_lane.sh [QUEUE, default docs/campaign/mujoco-bench.queue]
#   UNTIL: passed to campaign.sh as --until (start only the lines that end by then).
#   PORT: the bridge's port; the configs name 50071, so another suits only configs that say so
#   (the tests' fake bridge, beside a real lane). Archived configs naming the bridge's old
#   address, 127.0.0.1:50061 (the design service's default port), are run against this one
#   (MUJOCO_BRIDGE, scripts/campaign_lines.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
queue=${1:-docs/campaign/mujoco-bench.queue}
venv=runs/venv-bridge
port=${PORT:-50071}
export MUJOCO_BRIDGE=127.0.0.1:$port
pidfile=runs/mujoco-bridge.pid
answers() {
  python3 -c 'import socket,sys; s=socket.socket(); s.settimeout(1); sys.exit(s.connect_ex(("127.0.0.1", int(sys.argv[1]))) != 0)' "$port"
}
if [ ! -x "$venv/bin/coadapt-gym-serve" ]; then
  echo "mujoco_lane: making the bridge's virtualenv in $venv"
  bash bridges/python/setup_venv.sh "$venv"
fi
mkdir -p runs
bridge=""
# Two lanes reaching their mujoco-* queues at once: one starts the bridge, the other finds it.
exec 9> runs/mujoco-bridge.lock
flock 9
if answers; then
  other=$(cat "$pidfile" 2> /dev/null || true)
  if [[ $other =~ ^[1-9][0-9]*$ ]] && grep -qa coadapt-gym-serve "/proc/$other/cmdline" 2> /dev/null; then
    echo "mujoco_lane: using the bridge another lane started (pid $other on 127.0.0.1:$port)"
  else
    echo "mujoco_lane: something already listens on 127.0.0.1:$port and it is no bridge of a lane (runs/mujoco-bridge.pid); stop it first" >&2
    exit 2
  fi
else
  # Without the lock's descriptor: a lock lives as long as any process holds it open.
  "$venv/bin/coadapt-gym-serve" --factory coadapt_bridge.mujoco_half_cheetah:make --port "$port" > runs/mujoco-bridge.log 2>&1 9>&- &
  bridge=$!
  echo "$bridge" > "$pidfile"
fi
# The bridge goes last: a run stopping (SIGTERM: its stop snapshot) still steps the robot, and
# without the bridge its actor fails before the learner has written the snapshot. Runs of
# another lane that uses this bridge are waited for too, however long they take.
# Another lane of this script (using this bridge) counts while it lives: between its runs no
# run is alive, and the bridge must not go in that gap.
other_lanes() {
  local p ppid
  for p in $(pgrep -f -- 'scripts/mujoco_lane\.sh' || true); do
    # Of this checkout only (its runs/ and bridge), not of another tree on the machine.
    [ "$p" != $$ ] && [ "$(readlink "/proc/$p/cwd" 2> /dev/null)" = "$(pwd -P)" ] || continue
    # Gone already (a subshell of this script that ran pgrep), or one of this script's own.
    ppid=$(ps -o ppid= -p "$p" 2> /dev/null | tr -d ' ') || continue
    if [ -n "$ppid" ] && [ "$ppid" != $$ ]; then return 0; fi
  done
  return 1
}
stop_bridge() {
  [ -n "$bridge" ] || return 0
  # A signal while this waits (lanes.sh stopping every lane, a second Ctrl-C) must not end the
  # script before the bridge: the INT/TERM trap's `exit` would leave it running, orphaned, with
  # the port. The runs and lanes it waits for are being stopped by the same signal.
  trap '' INT TERM
  local said=""
  while pgrep -f -- "(--out|--resume) runs/campaign/mujoco-|--env dm-env-rpc://127.0.0.1:$port" > /dev/null || other_lanes; do
    [ -n "$said" ] || { echo "mujoco_lane: the bridge stops once the runs and lanes using it have ended"; said=1; }
    sleep 0.5
  done
  kill "$bridge" 2> /dev/null || true
  rm -f "$pidfile"
}
trap stop_bridge EXIT
camp=""
# The queue runs in the background so that a signal reaches this script at once (bash runs a
# trap only after its foreground command ends) and is passed on as campaign.sh --stop does.
trap '[ -z "$camp" ] || { kill -TERM "$camp" 2> /dev/null; wait "$camp" || true; }; exit 130' INT TERM
if [ -n "$bridge" ]; then
  for _ in $(seq 1 120); do
    answers && break
    kill -0 "$bridge" 2>/dev/null || { echo "mujoco_lane: the bridge ended at start (runs/mujoco-bridge.log):" >&2; tail -5 runs/mujoco-bridge.log >&2; exit 1; }
    sleep 0.5
  done
  echo "mujoco_lane: bridge pid $bridge on 127.0.0.1:$port (log runs/mujoco-bridge.log)"
fi
exec 9>&-
scripts/campaign.sh -j 1 ${UNTIL:+--until "$UNTIL"} "$queue" &
camp=$!
wait "$camp"
