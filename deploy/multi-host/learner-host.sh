#!/usr/bin/env bash
# The learner host of a multi-machine fleet over gRPC: the learner (serving on --listen) and the
# design optimiser on this host; actors on other hosts connect with actor-host.sh.
set -euo pipefail

usage() {
  cat <<'EOF_USAGE'
Usage: deploy/multi-host/learner-host.sh [--config FILE] [options] [-- fleet.sh options]

Runs the learner (gRPC server on --listen, default 0.0.0.0:50051) and the design optimiser on
this host, logs in <out>/logs, and waits for the run to finish (exit status: the learner's).
Then, on every actor host:
  deploy/multi-host/actor-host.sh http://THIS_HOST:50051 N --first-id K

Options (environment variables in brackets; the same as /etc/coadapt/coadapt.env):
  --config FILE    run config [COADAPT_CONFIG] (default <repo>/configs/half-cheetah-tiny.toml)
  --listen ADDR    gRPC listen address [COADAPT_LISTEN] (default 0.0.0.0:50051)
  --out DIR        run directory [COADAPT_RUN_DIR] (default runs/<config>-grpc-<date>)
  --fleet NAME     fleet name, the same on every host [COADAPT_FLEET] (default coadapt)
  --bin PATH       coadapt binary [COADAPT_BIN] (default <repo>/target/release/coadapt)
  --seed S         override the config's seed [COADAPT_SEED]
  -h, --help       this help
Anything after -- goes to deploy/local/fleet.sh (e.g. -- --grace 60).
The port must be reachable from the actor hosts (firewall: allow TCP 50051 from them).
EOF_USAGE
}

SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
REPO_ROOT=$(cd -- "$SCRIPT_DIR/../.." && pwd)
die() { printf 'learner-host.sh: error: %s\n' "$*" >&2; exit 2; }

config=${COADAPT_CONFIG:-$REPO_ROOT/configs/half-cheetah-tiny.toml}
listen=${COADAPT_LISTEN:-0.0.0.0:50051}
out=${COADAPT_RUN_DIR:-}
fleet=${COADAPT_FLEET:-coadapt}
bin=${COADAPT_BIN:-}
seed=${COADAPT_SEED:-}
extra=()
need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value (see --help)"; }
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) usage; exit 0 ;;
    --config) need_arg "$@"; config=$2; shift 2 ;;
    --listen) need_arg "$@"; listen=$2; shift 2 ;;
    --out) need_arg "$@"; out=$2; shift 2 ;;
    --fleet) need_arg "$@"; fleet=$2; shift 2 ;;
    --bin) need_arg "$@"; bin=$2; shift 2 ;;
    --seed) need_arg "$@"; seed=$2; shift 2 ;;
    --) shift; extra=("$@"); break ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done

port=${listen##*:}
[[ $port =~ ^[0-9]+$ ]] || die "--listen '$listen' has no port"
# The optimiser on this host connects to the learner here: 127.0.0.1 when it listens on all
# addresses, else the address it listens on.
host=${listen%:*}
case $host in "" | 0.0.0.0 | "[::]") host=127.0.0.1 ;; esac
args=(--transport grpc --roles "learner,optimizer" --config "$config" --listen "$listen"
  --connect "http://$host:$port" --fleet "$fleet")
[[ -z $out ]] || args+=(--out "$out")
[[ -z $bin ]] || args+=(--bin "$bin")
[[ -z $seed ]] || args+=(--seed "$seed")

printf 'learner-host: actors connect with: deploy/multi-host/actor-host.sh http://<this host>:%s N --first-id K\n' "$port" >&2
exec "$REPO_ROOT/deploy/local/fleet.sh" "${args[@]}" "${extra[@]}"
