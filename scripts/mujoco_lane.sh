#!/usr/bin/env bash
# The MuJoCo cheetah's lane of the design benchmark (issue 28 section 2): makes the Python
# bridge's virtualenv if it is missing (bridges/python/setup_venv.sh, into runs/venv-bridge),
# starts the bridge on 127.0.0.1:50061 (the address in configs/mujoco-half-cheetah-reduced.toml),
# waits until it answers, runs docs/campaign/mujoco-bench.queue with scripts/campaign.sh (which
# resumes where it stopped and archives each run as it ends), and stops the bridge at the end or
# on Ctrl-C / SIGTERM, once the runs using it have stopped (at most 2 minutes).
#   usage: [BIN=path/to/coadapt] [UNTIL=TIME] scripts/mujoco_lane.sh [QUEUE, default docs/campaign/mujoco-bench.queue]
#   UNTIL: passed to campaign.sh as --until (start only the lines that end by then).
set -euo pipefail
cd "$(dirname "$0")/.."
queue=${1:-docs/campaign/mujoco-bench.queue}
venv=runs/venv-bridge
port=50061
if [ ! -x "$venv/bin/coadapt-gym-serve" ]; then
  echo "mujoco_lane: making the bridge's virtualenv in $venv"
  bash bridges/python/setup_venv.sh "$venv"
fi
if python3 -c 'import socket,sys; s=socket.socket(); s.settimeout(1); sys.exit(s.connect_ex(("127.0.0.1", int(sys.argv[1]))) != 0)' "$port"; then
  echo "mujoco_lane: something already listens on 127.0.0.1:$port; stop it first (or it is a bridge of a lane still running)" >&2
  exit 2
fi
mkdir -p runs
"$venv/bin/coadapt-gym-serve" --factory coadapt_bridge.mujoco_half_cheetah:make --port "$port" > runs/mujoco-bridge.log 2>&1 &
bridge=$!
# The bridge goes last: a run stopping (SIGTERM: its stop snapshot) still steps the robot, and
# without the bridge its actor fails before the learner has written the snapshot.
stop_bridge() {
  for _ in $(seq 1 240); do
    pgrep -f -- "(--out|--resume) runs/campaign/mujoco-bench|--env dm-env-rpc://127.0.0.1:$port" > /dev/null || break
    sleep 0.5
  done
  kill "$bridge" 2> /dev/null || true
}
trap stop_bridge EXIT
trap 'exit 130' INT TERM
for _ in $(seq 1 120); do
  if python3 -c 'import socket,sys; s=socket.socket(); s.settimeout(1); sys.exit(s.connect_ex(("127.0.0.1", int(sys.argv[1]))) != 0)' "$port"; then
    break
  fi
  kill -0 "$bridge" 2>/dev/null || { echo "mujoco_lane: the bridge ended at start (runs/mujoco-bridge.log):" >&2; tail -5 runs/mujoco-bridge.log >&2; exit 1; }
  sleep 0.5
done
echo "mujoco_lane: bridge pid $bridge on 127.0.0.1:$port (log runs/mujoco-bridge.log)"
scripts/campaign.sh -j 1 ${UNTIL:+--until "$UNTIL"} "$queue"
