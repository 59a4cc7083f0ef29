#!/usr/bin/env bash
# The command line of one coadapt role built from /etc/coadapt/coadapt.env, for the systemd units
# (installed as /usr/local/lib/coadapt/coadapt-role). `exec`s coadapt, so systemd supervises and
# signals coadapt itself.
set -euo pipefail

usage() {
  cat <<'EOF_USAGE'
Usage: coadapt-role learner|optimizer|actor [ID]

Runs `$COADAPT_BIN <role> ...` with the settings of the environment (the units load them from
/etc/coadapt/coadapt.env):
  COADAPT_BIN        coadapt binary (default /usr/local/bin/coadapt)
  COADAPT_CONFIG     run config, required (e.g. /etc/coadapt/run.toml)
  COADAPT_TRANSPORT  grpc (default) or shm (learner, optimiser and actors on one host)
  COADAPT_LISTEN     learner: gRPC listen address (default 0.0.0.0:50051)
  COADAPT_CONNECT    optimiser and actors: the learner's URL (default http://127.0.0.1:50051)
  COADAPT_FLEET      fleet name, the same on every host (default coadapt)
  COADAPT_RUN_DIR    learner: run directory (default /var/lib/coadapt/run)
  COADAPT_SEED       learner: override the config's seed (optional)
  COADAPT_EXTRA_ARGS extra arguments for every role, split on spaces (optional)
  COADAPT_TLS_DIR    TLS files of `coadapt tls new` (default /etc/coadapt/tls): the learner
                     serves server.pem/server-key.pem when present, the others check it with
                     ca.pem when present
  COADAPT_TOKENS_FILE learner: the accepted tokens (default /etc/coadapt/tokens when present)
  COADAPT_TOKEN_DIR  optimiser and actors: their token, <dir>/<role>.token (default
                     /etc/coadapt/tokens.d when present); tokens are read by coadapt from the
                     file, never passed as arguments
  COADAPT_INSECURE   learner: 1 to serve plaintext on a non-loopback address (trusted networks)
ID is the actor id (the unit instance: coadapt-actor@3 runs actor 3).
EOF_USAGE
}

die() { printf 'coadapt-role: error: %s\n' "$*" >&2; exit 2; }
[[ $# -ge 1 ]] || { usage >&2; exit 2; }
case $1 in -h | --help) usage; exit 0 ;; esac

role=$1
bin=${COADAPT_BIN:-/usr/local/bin/coadapt}
transport=${COADAPT_TRANSPORT:-grpc}
[[ -n ${COADAPT_CONFIG:-} ]] || die "COADAPT_CONFIG is not set (in /etc/coadapt/coadapt.env)"
[[ -r $COADAPT_CONFIG ]] || die "COADAPT_CONFIG=$COADAPT_CONFIG is not readable by $(id -un)"
[[ -x $bin ]] || die "COADAPT_BIN=$bin is not an executable"
case $transport in grpc | shm) ;; *) die "COADAPT_TRANSPORT must be grpc or shm, got '$transport'" ;; esac

args=("$role" --config "$COADAPT_CONFIG" --transport "$transport" --fleet "${COADAPT_FLEET:-coadapt}")
case $role in
  learner)
    [[ $# -eq 1 ]] || die "learner takes no id"
    # --resume: a restarted learner continues the run from its newest snapshot (a fresh
    # directory starts a run), so systemd's Restart=on-failure resumes after any crash.
    args+=(--out "${COADAPT_RUN_DIR:-/var/lib/coadapt/run}" --resume)
    [[ $transport != grpc ]] || args+=(--listen "${COADAPT_LISTEN:-0.0.0.0:50051}")
    [[ -z ${COADAPT_SEED:-} ]] || args+=(--seed "$COADAPT_SEED")
    ;;
  optimizer)
    [[ $# -eq 1 ]] || die "optimizer takes no id"
    # Its state (generator, ES state, every reply) survives a restart here.
    args+=(--state-dir "${COADAPT_OPTIMIZER_STATE_DIR:-/var/lib/coadapt/optimizer}")
    [[ $transport != grpc ]] || args+=(--connect "${COADAPT_CONNECT:-http://127.0.0.1:50051}")
    ;;
  actor)
    [[ $# -eq 2 && $2 =~ ^[0-9]+$ ]] || die "actor needs a numeric id (coadapt-actor@ID.service), got '${2:-}'"
    [[ $transport != grpc ]] || args+=(--connect "${COADAPT_CONNECT:-http://127.0.0.1:50051}")
    args+=(--id "$2")
    ;;
  *) die "unknown role '$role' (learner, optimizer, actor)" ;;
esac
# TLS and tokens: file paths only.
tls_dir=${COADAPT_TLS_DIR:-/etc/coadapt/tls}
if [[ $transport == grpc ]]; then
  case $role in
    learner)
      if [[ -f $tls_dir/server.pem ]]; then
        args+=(--tls-cert "$tls_dir/server.pem" --tls-key "$tls_dir/server-key.pem")
      fi
      tokens=${COADAPT_TOKENS_FILE:-/etc/coadapt/tokens}
      [[ ! -f $tokens ]] || args+=(--tokens-file "$tokens")
      [[ ${COADAPT_INSECURE:-0} != 1 ]] || args+=(--insecure)
      ;;
    *)
      [[ ! -f $tls_dir/ca.pem ]] || args+=(--tls-ca "$tls_dir/ca.pem")
      token=${COADAPT_TOKEN_DIR:-/etc/coadapt/tokens.d}/$role.token
      [[ ! -f $token ]] || args+=(--token-file "$token")
      ;;
  esac
fi
if [[ -n ${COADAPT_EXTRA_ARGS:-} ]]; then
  read -r -a extra <<<"$COADAPT_EXTRA_ARGS"
  args+=("${extra[@]}")
fi
exec "$bin" "${args[@]}"
