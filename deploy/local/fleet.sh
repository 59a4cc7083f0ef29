#!/usr/bin/env bash
# A coadapt fleet by hand: the learner, the design optimiser and N actors as separate background
# processes on this machine (iceoryx2 shared memory by default, or gRPC), one log per process,
# Ctrl-C stops them all. `coadapt run` does the same in Rust; this script shows the pieces.
# The multi-host launchers (deploy/multi-host/*.sh) run subsets of it with --roles.
set -euo pipefail

usage() {
  cat <<'EOF'
Usage: deploy/local/fleet.sh --config FILE [options]

Launches a coadapt fleet on this machine as separate processes:
  coadapt learner   (writes the run directory; the fleet's exit status is the learner's)
  coadapt optimizer (the design optimiser)
  coadapt actor x N (simulated robots; ids FIRST_ID .. FIRST_ID+N-1)
Each process logs stdout and stderr to <log-dir>/<role>-<i>.log (default <out>/logs).
When the learner exits, the others get --grace seconds to finish, then are stopped.
Ctrl-C (SIGINT) or SIGTERM stops every process: SIGINT first (coadapt finishes the current
episode and saves), SIGTERM after --grace seconds, SIGKILL 5 s later; a second Ctrl-C
skips the wait. The learner's JSON summary line is printed on stdout at the end.

Options:
  --config FILE       run config (TOML, e.g. configs/half-cheetah-tiny.toml); env COADAPT_CONFIG
  --transport T       shm (default; iceoryx2, one machine) or grpc
  --actors N          number of actors (default 2)
  --first-id K        id of the first actor (default 0); give each actor host its own range
  --out DIR           run directory (default runs/<config name>-<transport>-<date>)
  --log-dir DIR       where the logs go (default <out>/logs)
  --fleet NAME        fleet name shared by all processes (default coadapt-<pid of this script>);
                      env COADAPT_FLEET
  --seed S            override the config's seed (learner)
  --listen ADDR       gRPC: learner listen address (default 0.0.0.0:50051); env COADAPT_LISTEN
  --connect URL       gRPC: where actors and optimiser connect (default http://<host of --listen,
                      127.0.0.1 for 0.0.0.0>:<port>); env COADAPT_CONNECT
  --roles LIST        comma-separated subset of learner,optimizer,actors (default all three)
  --bin PATH          coadapt binary (default $COADAPT_BIN, else <repo>/target/release/coadapt,
                      else coadapt on PATH)
  --grace SECS        seconds to wait for a clean exit before SIGTERM (default 30)
  --ready-timeout S   gRPC: seconds to wait for the learner's port before starting the others
                      (default 60)
  --tls-dir DIR       gRPC over TLS with `coadapt tls new --out DIR`'s files: the learner serves
                      DIR/server.pem (key DIR/server-key.pem), the others check it with
                      DIR/ca.pem; env COADAPT_TLS_DIR
  --tokens-file FILE  the learner accepts only these tokens (`coadapt token new --tokens-file`);
                      env COADAPT_TOKENS_FILE
  --actor-token FILE  the actors' token file; env COADAPT_ACTOR_TOKEN_FILE
  --optimizer-token FILE  the optimiser's token file; env COADAPT_OPTIMIZER_TOKEN_FILE
  --insecure          let the learner listen in plaintext on a non-loopback address (a network
                      you trust; without TLS it is refused)
  -h, --help          this help

Exit status: the learner's (without a learner: 0 if every actor and optimiser exited 0, else 1);
130 if interrupted before the learner exited on its own; 2 on a usage error.

Examples:
  deploy/local/fleet.sh --config configs/half-cheetah-tiny.toml --actors 4
  deploy/local/fleet.sh --config configs/half-cheetah-tiny.toml --transport grpc --listen 127.0.0.1:50051
  deploy/local/fleet.sh --config configs/half-cheetah-tiny.toml --transport grpc --tls-dir tls \
    --tokens-file tokens --actor-token actor.token --optimizer-token optimizer.token
Tokens are read from files by coadapt itself: never on a command line, never in a log.
EOF
}

log() { printf '[fleet %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }
die() { printf 'fleet.sh: error: %s\n' "$*" >&2; exit 2; }

SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
REPO_ROOT=$(cd -- "$SCRIPT_DIR/../.." && pwd)

config=${COADAPT_CONFIG:-}
transport=${COADAPT_TRANSPORT:-shm}
actors=2
first_id=0
out=""
log_dir=""
fleet=${COADAPT_FLEET:-}
seed=""
listen=${COADAPT_LISTEN:-0.0.0.0:50051}
connect=${COADAPT_CONNECT:-}
roles="learner,optimizer,actors"
bin=${COADAPT_BIN:-}
grace=30
ready_timeout=60
tls_dir=${COADAPT_TLS_DIR:-}
tokens_file=${COADAPT_TOKENS_FILE:-}
actor_token=${COADAPT_ACTOR_TOKEN_FILE:-}
optimizer_token=${COADAPT_OPTIMIZER_TOKEN_FILE:-}
insecure=0

need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value (see --help)"; }
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) usage; exit 0 ;;
    --config) need_arg "$@"; config=$2; shift 2 ;;
    --transport) need_arg "$@"; transport=$2; shift 2 ;;
    --actors) need_arg "$@"; actors=$2; shift 2 ;;
    --first-id) need_arg "$@"; first_id=$2; shift 2 ;;
    --out) need_arg "$@"; out=$2; shift 2 ;;
    --log-dir) need_arg "$@"; log_dir=$2; shift 2 ;;
    --fleet) need_arg "$@"; fleet=$2; shift 2 ;;
    --seed) need_arg "$@"; seed=$2; shift 2 ;;
    --listen) need_arg "$@"; listen=$2; shift 2 ;;
    --connect) need_arg "$@"; connect=$2; shift 2 ;;
    --roles) need_arg "$@"; roles=$2; shift 2 ;;
    --bin) need_arg "$@"; bin=$2; shift 2 ;;
    --grace) need_arg "$@"; grace=$2; shift 2 ;;
    --ready-timeout) need_arg "$@"; ready_timeout=$2; shift 2 ;;
    --tls-dir) need_arg "$@"; tls_dir=$2; shift 2 ;;
    --tokens-file) need_arg "$@"; tokens_file=$2; shift 2 ;;
    --actor-token) need_arg "$@"; actor_token=$2; shift 2 ;;
    --optimizer-token) need_arg "$@"; optimizer_token=$2; shift 2 ;;
    --insecure) insecure=1; shift ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done

# --- check the arguments ------------------------------------------------------------------------
((BASH_VERSINFO[0] > 5 || (BASH_VERSINFO[0] == 5 && BASH_VERSINFO[1] >= 1))) ||
  die "needs bash >= 5.1 (wait -n -p); this is $BASH_VERSION"
is_uint() { [[ $1 =~ ^[0-9]+$ ]]; }
is_uint "$actors" || die "--actors must be a whole number, got '$actors'"
is_uint "$first_id" || die "--first-id must be a whole number, got '$first_id'"
is_uint "$grace" || die "--grace must be whole seconds, got '$grace'"
is_uint "$ready_timeout" || die "--ready-timeout must be whole seconds, got '$ready_timeout'"
[[ -z $seed ]] || is_uint "$seed" || die "--seed must be a whole number, got '$seed'"
for f in "$tls_dir" "$tokens_file" "$actor_token" "$optimizer_token"; do
  [[ -z $f || -r $f ]] || die "'$f' is not readable"
done
if [[ -n $tls_dir ]]; then
  for f in ca.pem server.pem server-key.pem; do
    [[ -r $tls_dir/$f ]] || die "--tls-dir: no readable $tls_dir/$f (coadapt tls new --out $tls_dir makes them)"
  done
fi
case $transport in
  shm | grpc) ;;
  *) die "--transport must be shm or grpc, got '$transport' (in-process is 'coadapt run --transport in-process')" ;;
esac

want_learner=0 want_optimizer=0 want_actors=0
IFS=, read -r -a role_list <<<"$roles"
for r in "${role_list[@]}"; do
  case $r in
    learner) want_learner=1 ;;
    optimizer | optimiser) want_optimizer=1 ;;
    actors | actor) want_actors=1 ;;
    *) die "--roles: unknown role '$r' (learner, optimizer, actors)" ;;
  esac
done
((want_learner + want_optimizer + want_actors > 0)) || die "--roles names no role"
((want_actors == 0 || actors > 0)) || die "--actors 0 with the actors role: nothing to run"

[[ -n $config ]] || die "--config FILE is required (e.g. --config configs/half-cheetah-tiny.toml)"
[[ -f $config && -r $config ]] || die "config '$config' is not a readable file"
config=$(cd -- "$(dirname -- "$config")" && pwd)/$(basename -- "$config")

if [[ -z $bin ]]; then
  if [[ -x $REPO_ROOT/target/release/coadapt ]]; then
    bin=$REPO_ROOT/target/release/coadapt
  elif command -v coadapt >/dev/null 2>&1; then
    bin=$(command -v coadapt)
  else
    die "no coadapt binary: build it (cargo build --release -p coadapt), or pass --bin PATH / set COADAPT_BIN"
  fi
fi
[[ -x $bin ]] || die "coadapt binary '$bin' is not executable (cargo build --release -p coadapt?)"
for sub in learner optimizer actor; do
  case $sub in
    learner) ((want_learner)) || continue ;;
    optimizer) ((want_optimizer)) || continue ;;
    actor) ((want_actors)) || continue ;;
  esac
  "$bin" "$sub" --help >/dev/null 2>&1 ||
    die "'$bin $sub --help' failed: this coadapt binary has no '$sub' subcommand (the process roles arrived with issue 5; rebuild)"
done

[[ -n $fleet ]] || fleet="coadapt-$$"
[[ $fleet =~ ^[A-Za-z0-9][A-Za-z0-9_.-]*$ ]] || die "--fleet '$fleet': use letters, digits, '-', '_' and '.'"

if [[ $transport == grpc && -z $connect ]]; then
  port=${listen##*:}
  is_uint "$port" || die "--listen '$listen' has no port"
  host=${listen%:*}
  case $host in "" | 0.0.0.0 | "[::]") host=127.0.0.1 ;; esac
  connect="http://$host:$port"
fi

if [[ -z $out ]]; then
  name=$(basename -- "$config" .toml)
  out="runs/$name-$transport-$(date +%Y%m%d-%H%M%S)"
fi
if ((want_learner)) && [[ -e $out/designs.csv ]]; then
  log "note: $out already holds a run (designs.csv); the learner decides whether to resume or refuse"
fi
[[ -n $log_dir ]] || log_dir="$out/logs"
mkdir -p -- "$log_dir"

# --- the processes -------------------------------------------------------------------------------
declare -A live=() # pid -> "role-i"
learner_pid=""
learner_status=""
stopping=0
learner_done=0
failed_others=0

# Job control: every background process gets its own process group (a terminal's Ctrl-C reaches
# only this script, which forwards it once: coadapt aborts on a second SIGINT) and keeps SIGINT's
# default disposition (without -m, bash starts background processes with SIGINT ignored).
set -m

# start NAME ARGS...: runs the coadapt binary in the background, output to <log-dir>/NAME.log.
start() {
  local name=$1
  shift
  local logf="$log_dir/$name.log"
  printf '# %s\n# %s\n' "$(date -Is)" "$bin $*" >"$logf"
  "$bin" "$@" >>"$logf" 2>&1 </dev/null &
  local pid=$!
  live[$pid]=$name
  log "started $name (pid $pid): $bin $* > $logf"
  REPLY=$pid
}

signal_all() { # signal_all SIG: to every live process group
  local sig=$1 pid
  for pid in "${!live[@]}"; do
    kill "-$sig" -- "-$pid" 2>/dev/null || kill "-$sig" "$pid" 2>/dev/null || true
  done
}

# Wait up to $1 seconds for every live process to exit; reap them and record statuses.
reap_for() {
  local deadline=$((SECONDS + $1)) pid
  while ((${#live[@]} > 0 && SECONDS < deadline)); do
    for pid in "${!live[@]}"; do
      if ! kill -0 "$pid" 2>/dev/null; then
        local st=0
        wait "$pid" 2>/dev/null || st=$?
        note_exit "$pid" "$st"
      fi
    done
    ((${#live[@]} == 0)) || sleep 0.5
  done
}

note_exit() { # note_exit PID STATUS
  local pid=$1 st=$2 name=${live[$1]:-?}
  unset "live[$pid]"
  log "$name (pid $pid) exited with status $st"
  if [[ $pid == "$learner_pid" ]]; then
    learner_status=$st
  elif ((st != 0 && stopping == 0 && learner_done == 0)); then
    failed_others=1
    log "  see $log_dir/$name.log"
  fi
}

stop_all() { # stop every process: SIGINT, then SIGTERM, then SIGKILL
  ((${#live[@]} > 0)) || return 0
  log "stopping ${#live[@]} process(es) with SIGINT (grace ${grace}s)"
  signal_all INT
  reap_for "$grace"
  ((${#live[@]} > 0)) || return 0
  log "still running after ${grace}s: ${live[*]}; SIGTERM"
  signal_all TERM
  reap_for 5
  ((${#live[@]} > 0)) || return 0
  log "still running: ${live[*]}; SIGKILL"
  signal_all KILL
  reap_for 5
}

# shellcheck disable=SC2317 # invoked by the trap
on_signal() {
  if ((stopping)); then
    log "second interrupt: SIGKILL to everything"
    grace=0
    signal_all KILL
    return
  fi
  stopping=1
  log "interrupted: stopping the fleet"
  stop_all
}
trap on_signal INT TERM
# Whatever happens (set -e, a bug), leave no process behind.
# shellcheck disable=SC2317 # invoked by the trap
kill_leftovers() {
  local pid
  for pid in "${!live[@]}"; do kill -KILL -- "-$pid" 2>/dev/null || true; done
}
trap kill_leftovers EXIT

common=(--config "$config" --transport "$transport" --fleet "$fleet")
log "fleet '$fleet': transport $transport, config $config, roles $roles, logs in $log_dir"

# TLS and tokens: paths only (coadapt reads the files).
client_tls=()
[[ -n $tls_dir ]] && client_tls=(--tls-ca "$tls_dir/ca.pem")
if ((want_learner)); then
  largs=(learner "${common[@]}" --out "$out")
  [[ $transport == grpc ]] && largs+=(--listen "$listen")
  [[ -n $tls_dir ]] && largs+=(--tls-cert "$tls_dir/server.pem" --tls-key "$tls_dir/server-key.pem")
  [[ -n $tokens_file ]] && largs+=(--tokens-file "$tokens_file")
  ((insecure)) && largs+=(--insecure)
  [[ -n $seed ]] && largs+=(--seed "$seed")
  start learner-0 "${largs[@]}"
  learner_pid=$REPLY
  if [[ $transport == grpc ]]; then
    # Wait until the learner accepts connections, so the others' first attempt succeeds.
    port=${listen##*:}
    host=${listen%:*}
    case $host in "" | 0.0.0.0 | "[::]") host=127.0.0.1 ;; esac
    host=${host#[}
    host=${host%]}
    deadline=$((SECONDS + ready_timeout))
    until (exec 3<>"/dev/tcp/$host/$port") 2>/dev/null; do
      kill -0 "$learner_pid" 2>/dev/null || break
      ((SECONDS < deadline)) || { log "learner not listening on port $port after ${ready_timeout}s; starting the others anyway"; break; }
      sleep 0.5
    done
  fi
fi

# One connection argument for the clients.
client=()
[[ $transport == grpc ]] && client=(--connect "$connect")

if ((want_optimizer && !stopping)); then
  # Its state beside the run (as `coadapt run` keeps it), so that a restarted optimiser, or
  # one of a resumed run, answers as the one before it did: the same designs.
  oargs=(optimizer "${common[@]}" "${client[@]}" "${client_tls[@]}" --state-dir "$out/optimizer")
  [[ -n $optimizer_token ]] && oargs+=(--token-file "$optimizer_token")
  start optimizer-0 "${oargs[@]}"
fi
if ((want_actors)); then
  for ((i = first_id; i < first_id + actors && !stopping; i++)); do
    aargs=(actor "${common[@]}" "${client[@]}" "${client_tls[@]}" --id "$i")
    [[ -n $actor_token ]] && aargs+=(--token-file "$actor_token")
    start "actor-$i" "${aargs[@]}"
  done
fi

# --- supervise -----------------------------------------------------------------------------------
while ((${#live[@]} > 0 && !stopping)); do
  done_pid="" st=0
  wait -n -p done_pid "${!live[@]}" || st=$?
  if [[ -z ${done_pid:-} ]]; then
    continue # a trapped signal interrupted the wait; the handler ran
  fi
  note_exit "$done_pid" "$st"
  if [[ $done_pid == "$learner_pid" ]]; then
    learner_done=1
    if ((${#live[@]} > 0)); then
      log "learner done; waiting up to ${grace}s for the others to finish"
      reap_for "$grace"
      stop_all
    fi
    break
  fi
done

trap - INT TERM
if [[ -n $learner_pid && -f $log_dir/learner-0.log ]]; then
  summary=$(grep -E '^\{".*\}$' "$log_dir/learner-0.log" | tail -n 1 || true)
  [[ -z $summary ]] || printf '%s\n' "$summary"
fi
if [[ -n $learner_pid ]]; then
  if [[ -z $learner_status ]]; then
    exit 130
  fi
  if ((stopping && learner_status == 0)); then
    log "the learner stopped cleanly after the interrupt; run directory: $out"
    exit 130
  fi
  ((learner_status == 0)) && log "run directory: $out"
  exit "$learner_status"
fi
if ((stopping)); then exit 130; fi
exit "$failed_others"
