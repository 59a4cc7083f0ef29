#!/usr/bin/env bash
# An actor host of a multi-machine fleet over gRPC: N actors on this host connecting to the
# learner at LEARNER_URL (started with learner-host.sh or the coadapt-learner systemd unit).
set -euo pipefail

usage() {
  cat <<'EOF_USAGE'
Usage: deploy/multi-host/actor-host.sh LEARNER_URL N [options] [-- fleet.sh options]

Runs N actors (ids FIRST_ID .. FIRST_ID+N-1) on this host; they connect to the learner at
LEARNER_URL (e.g. http://10.0.0.1:50051), run episodes until the learner finishes, and reconnect
with backoff if it goes away. Exit status: 0 when every actor exited 0.

Arguments and options (environment variables in brackets):
  LEARNER_URL        the learner's gRPC address [COADAPT_CONNECT]
  N                  number of actors on this host (default 1)
  --first-id K       id of the first actor [COADAPT_FIRST_ID] (default 0); ids must be unique
                     over the whole fleet: give host 1 --first-id 0, host 2 --first-id 100, ...
  --config FILE      run config, the same as the learner's [COADAPT_CONFIG]
                     (default <repo>/configs/half-cheetah-tiny.toml)
  --fleet NAME       fleet name, the same on every host [COADAPT_FLEET] (default coadapt)
  --log-dir DIR      where the logs go [COADAPT_LOG_DIR] (default coadapt-actor-logs/)
  --bin PATH         coadapt binary [COADAPT_BIN] (default <repo>/target/release/coadapt)
  -h, --help         this help
Anything after -- goes to deploy/local/fleet.sh.
EOF_USAGE
}

SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
REPO_ROOT=$(cd -- "$SCRIPT_DIR/../.." && pwd)
die() { printf 'actor-host.sh: error: %s\n' "$*" >&2; exit 2; }

url=${COADAPT_CONNECT:-}
n=1
first_id=${COADAPT_FIRST_ID:-0}
config=${COADAPT_CONFIG:-$REPO_ROOT/configs/half-cheetah-tiny.toml}
fleet=${COADAPT_FLEET:-coadapt}
log_dir=${COADAPT_LOG_DIR:-coadapt-actor-logs}
bin=${COADAPT_BIN:-}
extra=()
positional=()
need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value (see --help)"; }
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) usage; exit 0 ;;
    --first-id) need_arg "$@"; first_id=$2; shift 2 ;;
    --config) need_arg "$@"; config=$2; shift 2 ;;
    --fleet) need_arg "$@"; fleet=$2; shift 2 ;;
    --log-dir) need_arg "$@"; log_dir=$2; shift 2 ;;
    --bin) need_arg "$@"; bin=$2; shift 2 ;;
    --) shift; extra=("$@"); break ;;
    -*) die "unknown option '$1' (see --help)" ;;
    *) positional+=("$1"); shift ;;
  esac
done
((${#positional[@]} <= 2)) || die "too many arguments: ${positional[*]} (see --help)"
((${#positional[@]} < 1)) || url=${positional[0]}
((${#positional[@]} < 2)) || n=${positional[1]}
[[ -n $url ]] || die "LEARNER_URL is required, e.g. http://10.0.0.1:50051 (see --help)"
[[ $url =~ ^https?://[^/]+:[0-9]+/?$ ]] || die "LEARNER_URL '$url' must look like http://HOST:PORT"
[[ $n =~ ^[0-9]+$ && $n -gt 0 ]] || die "N must be a positive whole number, got '$n'"

args=(--transport grpc --roles actors --connect "$url" --actors "$n" --first-id "$first_id"
  --config "$config" --fleet "$fleet" --log-dir "$log_dir")
[[ -z $bin ]] || args+=(--bin "$bin")
exec "$REPO_ROOT/deploy/local/fleet.sh" "${args[@]}" "${extra[@]}"
