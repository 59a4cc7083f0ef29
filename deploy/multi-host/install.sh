#!/usr/bin/env bash
# Installs the coadapt systemd units on this host: the binary, the role wrapper, the units, the
# config and /etc/coadapt/coadapt.env, a dedicated `coadapt` system user; then enables the units
# of the chosen roles. Run as root. --root DIR stages everything under DIR instead (no user, no
# systemctl): used to check the units with `systemd-analyze verify --root=DIR`.
set -euo pipefail

usage() {
  cat <<'EOF_USAGE'
Usage: sudo deploy/multi-host/install.sh --role learner|actors|all [options]

  --role R          learner: coadapt-learner + coadapt-optimizer on this host
                    actors:  coadapt-actor@ID for ID in FIRST_ID .. FIRST_ID+N-1
                    all:     both (one-host fleet over gRPC)
  --bin PATH        coadapt binary to install as /usr/local/bin/coadapt
                    (default <repo>/target/release/coadapt)
  --config FILE     run config to install as /etc/coadapt/run.toml
                    (default <repo>/configs/half-cheetah-tiny.toml)
  --connect URL     the learner's URL, written to coadapt.env (actors, optimiser)
  --listen ADDR     the learner's listen address, written to coadapt.env (default 0.0.0.0:50051)
  --actors N        actors on this host (default 2)
  --first-id K      id of the first actor (default 0); unique ranges per host
  --force           overwrite an existing /etc/coadapt/coadapt.env and run.toml
  --no-start        install and enable, but do not start now
  --root DIR        stage under DIR: no user creation, no systemctl
  -h, --help        this help
Afterwards: journalctl -fu coadapt-learner; systemctl status 'coadapt-*'.
EOF_USAGE
}

SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
REPO_ROOT=$(cd -- "$SCRIPT_DIR/../.." && pwd)
die() { printf 'install.sh: error: %s\n' "$*" >&2; exit 2; }
say() { printf 'install.sh: %s\n' "$*" >&2; }

role="" bin=$REPO_ROOT/target/release/coadapt config=$REPO_ROOT/configs/half-cheetah-tiny.toml
connect="" listen=0.0.0.0:50051 actors=2 first_id=0 force=0 start=1 root=""
need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value (see --help)"; }
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) usage; exit 0 ;;
    --role) need_arg "$@"; role=$2; shift 2 ;;
    --bin) need_arg "$@"; bin=$2; shift 2 ;;
    --config) need_arg "$@"; config=$2; shift 2 ;;
    --connect) need_arg "$@"; connect=$2; shift 2 ;;
    --listen) need_arg "$@"; listen=$2; shift 2 ;;
    --actors) need_arg "$@"; actors=$2; shift 2 ;;
    --first-id) need_arg "$@"; first_id=$2; shift 2 ;;
    --force) force=1; shift ;;
    --no-start) start=0; shift ;;
    --root) need_arg "$@"; root=$2; shift 2 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done
case $role in learner | actors | all) ;; *) die "--role learner|actors|all is required" ;; esac
[[ $actors =~ ^[0-9]+$ && $first_id =~ ^[0-9]+$ ]] || die "--actors and --first-id must be whole numbers"
[[ -x $bin ]] || die "no coadapt binary at '$bin' (cargo build --release -p coadapt, or --bin PATH)"
[[ -r $config ]] || die "config '$config' is not readable"
if [[ -z $root ]]; then
  [[ $EUID -eq 0 ]] || die "run as root (or stage with --root DIR)"
  if [[ $role == actors && -z $connect ]]; then
    die "--connect http://LEARNER_HOST:50051 is required for --role actors"
  fi
else
  mkdir -p -- "$root"
  root=$(cd -- "$root" && pwd)
fi
[[ -n $connect ]] || connect="http://127.0.0.1:${listen##*:}"

units_dir=$root/etc/systemd/system
install -d -m 0755 "$root/usr/local/bin" "$root/usr/local/lib/coadapt" "$units_dir" \
  "$root/etc/coadapt" "$root/usr/local/share/doc/coadapt"
# Where the TLS files and role tokens go (copied in by the operator: see deploy/README.md).
install -d -m 0750 "$root/etc/coadapt/tls" "$root/etc/coadapt/tokens.d"
install -m 0755 "$bin" "$root/usr/local/bin/coadapt"
install -m 0755 "$SCRIPT_DIR/systemd/coadapt-role.sh" "$root/usr/local/lib/coadapt/coadapt-role"
for u in coadapt-learner.service coadapt-optimizer.service coadapt-actor@.service; do
  install -m 0644 "$SCRIPT_DIR/systemd/$u" "$units_dir/$u"
done
install -m 0644 "$REPO_ROOT/deploy/README.md" "$root/usr/local/share/doc/coadapt/deploy-README.md"
if [[ ! -e $root/etc/coadapt/run.toml || $force -eq 1 ]]; then
  install -m 0644 "$config" "$root/etc/coadapt/run.toml"
else
  say "keeping the existing $root/etc/coadapt/run.toml (--force replaces it)"
fi
env_file=$root/etc/coadapt/coadapt.env
if [[ ! -e $env_file || $force -eq 1 ]]; then
  sed -e "s|^COADAPT_CONNECT=.*|COADAPT_CONNECT=$connect|" \
    -e "s|^COADAPT_LISTEN=.*|COADAPT_LISTEN=$listen|" \
    "$SCRIPT_DIR/systemd/coadapt.env.example" >"$env_file"
  chmod 0644 "$env_file"
else
  say "keeping the existing $env_file (--force replaces it)"
fi

units=()
[[ $role == actors ]] || units+=(coadapt-learner.service coadapt-optimizer.service)
if [[ $role != learner ]]; then
  for ((i = first_id; i < first_id + actors; i++)); do units+=("coadapt-actor@$i.service"); done
fi

if [[ -n $root ]]; then
  say "staged under $root (units: ${units[*]}); nothing enabled"
  exit 0
fi

if ! id -u coadapt >/dev/null 2>&1; then
  useradd --system --user-group --home-dir /var/lib/coadapt --no-create-home \
    --shell /usr/sbin/nologin --comment "coadapt fleet" coadapt
  say "created system user coadapt"
fi
# The units run as coadapt: it reads the TLS files and tokens, nobody else does.
chgrp coadapt /etc/coadapt/tls /etc/coadapt/tokens.d
command -v systemctl >/dev/null 2>&1 || die "systemctl not found: is this a systemd host?"
systemctl daemon-reload
if ((start)); then
  systemctl enable --now "${units[@]}"
else
  systemctl enable "${units[@]}"
fi
say "enabled: ${units[*]}"
say "logs: journalctl -fu coadapt-learner (or coadapt-actor@$first_id); settings: $env_file"
