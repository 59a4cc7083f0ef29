#!/usr/bin/env bash
# A real Slurm cluster on one machine, for trying deploy/slurm/coadapt.sbatch and for its test
# (deploy/slurm/slurm-test.sh): Debian's slurmctld, slurmd and munge (installed here when
# missing), the controller and N compute nodes each in a network namespace of its own on a
# private 10.x subnet (one bridge in a "switch" namespace; nothing is added to the host's own
# network), each node with a /dev/shm of its own. Files (the run directory, the job's output)
# are shared, as on a cluster's shared filesystem. Munge's socket is shared too: one munged
# serves every "host", as one key does on a real cluster.
#
#   deploy/slurm/local-cluster.sh up DIR [--nodes N] [--subnet 10.B.C]
#   deploy/slurm/local-cluster.sh exec DIR CMD...     (a Slurm command from the controller host)
#   deploy/slurm/local-cluster.sh kill-node DIR NODE  (a crash: NODE's network down, SIGKILL to
#                                                      everything on it)
#   deploy/slurm/local-cluster.sh start-node DIR NODE (its network up, its slurmd again: rebooted)
#   deploy/slurm/local-cluster.sh down DIR
#
# DIR holds slurm.conf, the controller's state, logs and env (what `up` made, for the other
# commands). Needs Linux, root, iproute2, util-linux; apt-get to install Slurm and munge.
# Exit: 0 done; 1 failed; 2 usage; 77 this machine cannot (the reason is printed).
set -euo pipefail

say() { printf '[slurm-cluster %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }
fail() { say "FAIL: $*"; exit 1; }
skip() { say "SKIP: $*"; exit 77; }
usage() { sed -n '2,19p' "$0" | sed 's/^# \{0,1\}//'; }
usage_err() { printf 'local-cluster.sh: %s (see --help)\n' "$*" >&2; exit 2; }

[[ $# -ge 1 ]] || { usage; exit 2; }
case $1 in -h | --help) usage; exit 0 ;; esac
cmd=$1
shift
[[ $# -ge 1 ]] || usage_err "$cmd needs the cluster directory"
dir=$1
shift

# in_ns NS HOST CMD...: CMD in network namespace NS with its own host name and /dev/shm (as on a
# separate machine; slurmctld and slurmd check that they run on the host slurm.conf names).
in_ns() {
  local ns=$1 host=$2
  shift 2
  # nsenter, not `ip netns exec`: that mounts a fresh /sys without the cgroup hierarchies slurmd
  # needs.
  # shellcheck disable=SC2016 # expanded by the inner bash
  nsenter --net="/run/netns/$ns" unshare --mount --uts --propagation private -- \
    bash -c 'hostname "$0" && mount -t tmpfs -o size=256m,mode=1777 coadapt-shm /dev/shm && exec "$@"' "$host" "$@"
}

load_env() {
  [[ -f $dir/env ]] || usage_err "no cluster in '$dir' (run 'up' first)"
  # shellcheck source=/dev/null
  source "$dir/env"
}

# wait_node NODE STATE SECS: until sinfo shows NODE in a state matching STATE.
wait_node() {
  local deadline=$((SECONDS + $3)) st
  while :; do
    st=$(nsenter --net="/run/netns/$ns_ctl" sinfo -h -N -n "$1" -o %t 2>/dev/null | head -n 1 || true)
    [[ $st =~ $2 ]] && return 0
    ((SECONDS < deadline)) || { say "node $1 is '$st', not $2, after $3 s"; return 1; }
    sleep 0.5
  done
}

start_slurmd() {
  local node=$1
  mkdir -p "$dir/spool/$node"
  in_ns "$ns_prefix-$node" "$node" slurmd -f "$dir/slurm.conf" -N "$node" >>"$dir/log/slurmd-$node.out" 2>&1 ||
    fail "slurmd -N $node did not start (see $dir/log/slurmd-$node.log)"
}

case $cmd in
up)
  nodes=3
  subnet=10.214.0
  while [[ $# -gt 0 ]]; do
    case $1 in
      --nodes) [[ $# -ge 2 && $2 =~ ^[1-9]$ ]] || usage_err "--nodes needs 1-9"; nodes=$2; shift 2 ;;
      --subnet) [[ $# -ge 2 && $2 =~ ^10\.[0-9]+\.[0-9]+$ ]] || usage_err "--subnet needs 10.B.C"; subnet=$2; shift 2 ;;
      *) usage_err "unknown argument '$1'" ;;
    esac
  done
  [[ $(uname -s) == Linux ]] || skip "network namespaces need Linux"
  [[ $EUID -eq 0 ]] || skip "needs root (namespaces, and slurmd runs jobs as their users)"
  command -v ip >/dev/null 2>&1 || skip "'ip' not found: install iproute2"
  command -v unshare >/dev/null 2>&1 || skip "'unshare' not found: install util-linux"
  if ! command -v slurmctld >/dev/null 2>&1 || ! command -v slurmd >/dev/null 2>&1 ||
    ! command -v munged >/dev/null 2>&1 || ! command -v sbatch >/dev/null 2>&1; then
    command -v apt-get >/dev/null 2>&1 || skip "Slurm is not installed and there is no apt-get to install it"
    say "installing Slurm and munge (apt-get install slurmctld slurmd slurm-client munge)"
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -q slurmctld slurmd slurm-client munge >"$dir.apt.log" 2>&1 ||
      { apt-get update -q >>"$dir.apt.log" 2>&1 && apt-get install -y -q slurmctld slurmd slurm-client munge >>"$dir.apt.log" 2>&1; } ||
      skip "apt-get could not install Slurm and munge (see $dir.apt.log)"
  fi
  mkdir -p "$dir"/{state,spool,log}
  dir=$(cd "$dir" && pwd)
  chmod 755 "$dir"
  # munge: one key for the whole cluster, made once (readable by munge only), one daemon.
  if [[ ! -s /etc/munge/munge.key ]]; then
    mkdir -p /etc/munge
    dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none
  fi
  chown munge:munge /etc/munge/munge.key
  chmod 400 /etc/munge/munge.key
  mkdir -p /run/munge /var/log/munge /var/lib/munge
  chown munge:munge /run/munge /var/log/munge /var/lib/munge
  if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
    runuser -u munge -- munged ||
      skip "munged would not start (see /var/log/munge/munged.log)"
  fi
  munge -n | unmunge >/dev/null 2>&1 || fail "munge does not work (munge -n | unmunge)"

  tag=sl$$
  ns_prefix=coadapt-$tag
  ns_sw=$ns_prefix-sw
  ns_ctl=$ns_prefix-ctl
  {
    printf 'ns_prefix=%q\nns_sw=%q\nns_ctl=%q\nsubnet=%q\nnodes=%q\n' "$ns_prefix" "$ns_sw" "$ns_ctl" "$subnet" "$nodes"
    printf 'SLURM_CONF=%q\nexport SLURM_CONF\n' "$dir/slurm.conf"
  } >"$dir/env"
  export SLURM_CONF=$dir/slurm.conf
  add_ns() {
    local err
    err=$(ip netns add "$1" 2>&1) || skip "'ip netns add' is not allowed here: $err"
    ip -n "$1" link set lo up
  }
  add_ns "$ns_sw"
  ip -n "$ns_sw" link add br0 type bridge || skip "cannot create a bridge in a namespace"
  ip -n "$ns_sw" link set br0 up
  attach() { # attach NS INDEX
    local ns=$1 idx=$2 a="${tag}n$2" b="${tag}s$2"
    add_ns "$ns"
    ip link add "$a" netns "$ns" type veth peer name "$b" netns "$ns_sw" || fail "cannot create a veth pair for $ns"
    ip -n "$ns" link set "$a" name eth0
    ip -n "$ns" addr add "$subnet.$idx/24" dev eth0
    ip -n "$ns" link set eth0 up
    ip -n "$ns_sw" link set "$b" master br0
    ip -n "$ns_sw" link set "$b" up
  }
  attach "$ns_ctl" 100
  node_lines=""
  for ((i = 1; i <= nodes; i++)); do
    attach "$ns_prefix-n$i" "$i"
    node_lines+="NodeName=n$i NodeHostname=n$i NodeAddr=$subnet.$i CPUs=$(nproc) State=UNKNOWN"$'\n'
  done
  # Short timeouts so that a dead node is noticed in seconds, not the default five minutes.
  cat >"$dir/slurm.conf" <<EOF
ClusterName=coadapt-local
SlurmctldHost=ctl($subnet.100)
SlurmUser=root
AuthType=auth/munge
CredType=cred/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool/%n
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd-%n.log
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd-%n.pid
SlurmctldTimeout=10
SlurmdTimeout=10
MessageTimeout=5
KillWait=10
MinJobAge=3600
ReturnToService=2
JobRequeue=1
MpiDefault=none
$node_lines
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP OverSubscribe=YES
EOF
  in_ns "$ns_ctl" ctl slurmctld -f "$dir/slurm.conf" >>"$dir/log/slurmctld.out" 2>&1 ||
    fail "slurmctld did not start (see $dir/log/slurmctld.log)"
  for ((i = 1; i <= nodes; i++)); do start_slurmd "n$i"; done
  for ((i = 1; i <= nodes; i++)); do wait_node "n$i" '^idle' 60 || fail "node n$i did not come up (see $dir/log/slurmd-n$i.log)"; done
  say "up: slurmctld on $subnet.100, nodes n1-n$nodes on $subnet.1-$nodes (SLURM_CONF=$dir/slurm.conf)"
  ;;
exec)
  load_env
  [[ $# -ge 1 ]] || usage_err "exec needs a command"
  exec nsenter --net="/run/netns/$ns_ctl" "$@"
  ;;
kill-node)
  load_env
  [[ $# -eq 1 ]] || usage_err "kill-node needs a node name"
  ns=$ns_prefix-$1
  pids=$(ip netns pids "$ns" 2>/dev/null || true)
  [[ -n $pids ]] || fail "nothing runs on node $1"
  # Its network goes first, as when a machine loses power: its peers get no FIN or RST for its
  # connections and learn of the loss only from their timeouts and leases.
  ip -n "$ns" link set eth0 down
  # shellcheck disable=SC2086
  kill -KILL $pids 2>/dev/null || true
  say "node $1 crashed: network down, SIGKILL to $(wc -w <<<"$pids") processes (slurmd, its steps and their tasks)"
  ;;
start-node)
  load_env
  [[ $# -eq 1 ]] || usage_err "start-node needs a node name"
  ip -n "$ns_prefix-$1" link set eth0 up
  start_slurmd "$1"
  say "node $1: network up, slurmd started again"
  ;;
down)
  [[ -f $dir/env ]] || exit 0
  load_env
  for ns in $(ip netns list 2>/dev/null | awk '{print $1}' | grep -- "^$ns_prefix-" || true); do
    for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$pid" 2>/dev/null || true; done
  done
  sleep 0.5
  for ns in $(ip netns list 2>/dev/null | awk '{print $1}' | grep -- "^$ns_prefix-" || true); do
    ip netns del "$ns" 2>/dev/null || say "warning: could not delete namespace $ns"
  done
  rm -f "$dir/env"
  say "down: namespaces $ns_prefix-* removed"
  ;;
*) usage_err "unknown command '$cmd'" ;;
esac
