#!/usr/bin/env bash
# The multi-host test on one machine: three network namespaces stand in for three hosts on a
# private 10.x subnet (one bridge in a fourth, "switch" namespace: nothing is added to the host's
# own network). The learner and the design optimiser run in the first (learner-host.sh), one
# actor in each of the two others (actor-host.sh), talking gRPC across the bridge; each "host"
# also gets its own /dev/shm, so nothing can pass through shared memory. A tiny co-adaptation
# runs to the end, then the run directory is checked. Every namespace is removed on exit.
#
# Faults (issue 33): --latency MS [--jitter MS] delays every byte between the actor hosts and the
# learner both ways (deploy/netns/delay_proxy.py: this machine's kernel has no netem, so a proxy
# in the learner's namespace stands in for `tc netem delay`); --loss PCT drops that share of the
# packets leaving every host (nftables' random numgen, a real loss that TCP must retransmit);
# --partition SECS cuts the second actor host off entirely (nftables drops all its traffic) once
# the run has --partition-after episodes, then heals it. --compare runs the same config in one
# process afterwards and checks that the rows are the undisturbed run's (lock-step is
# deterministic); --report FILE appends one JSON line of what the faults cost (BENCHMARKS.md).
#
# Needs: Linux, root (or CAP_NET_ADMIN + CAP_SYS_ADMIN), iproute2 (`ip`, `ss`), util-linux
# (`unshare`), bash >= 5.1.
# Exit: 0 pass; 1 fail; 2 usage; 77 skipped (no namespaces here: the reason is printed).
set -euo pipefail

usage() {
  cat <<'EOF'
Usage: deploy/netns/multi-host-test.sh [options] [COADAPT_BIN]

  COADAPT_BIN        the coadapt binary (default: $COADAPT_BIN, else target/release/coadapt)
  --config FILE      run config (default: configs/pendulum-tiny.toml if present, else
                     configs/half-cheetah-tiny.toml)
  --timeout SECS     give up on the run after SECS (default 900)
  --subnet A.B.C     the /24 inside the namespaces (default 10.213.0; private to them)
  --keep             keep the run directory (under $TMPDIR) after a pass
  --plumbing-only    check only the namespaces and the bridge with a stand-in server
                     (python3 -m http.server and a python3 client); no coadapt needed
  --designs N        the config's schedule.designs set to N (a longer run under faults)
  --latency MS       delay every byte between actor hosts and the learner by MS, both ways
  --jitter MS        the delay's standard deviation (default: a fifth of the latency)
  --loss PCT         drop PCT % of the packets leaving every host (needs nftables)
  --partition SECS   cut the second actor host off for SECS once the run has
                     --partition-after N episodes (default 4) (needs nftables)
  --lease SECS       flow.assignment-lease-secs (default the config's: 60 s): how long a
                     silent actor's episode waits before it goes to another actor
  --compare          then run the same config in one process and require the same rows
  --report FILE      append one JSON line: the faults, the learner's waiting time, throughput
  -h, --help         this help
Exit status: 0 pass, 1 fail, 2 usage error, 77 skipped (why is printed).
EOF
}

SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
REPO_ROOT=$(cd -- "$SCRIPT_DIR/../.." && pwd)
say() { printf '[netns-test %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }
fail() { say "FAIL: $*"; exit 1; }
skip() {
  say "SKIP: $*"
  passed=1 # nothing ran: nothing to keep
  exit 77
}
usage_err() { printf 'multi-host-test.sh: %s (see --help)\n' "$*" >&2; exit 2; }

passed=0
bin=${COADAPT_BIN:-}
config=""
timeout=900
subnet=10.213.0
keep=0
plumbing_only=0
designs=""
latency=0
jitter=""
loss=0
partition=0
partition_after=4
compare=0
report=""
lease=""
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) usage; exit 0 ;;
    --config) [[ $# -ge 2 ]] || usage_err "--config needs a file"; config=$2; shift 2 ;;
    --timeout) [[ $# -ge 2 && $2 =~ ^[0-9]+$ ]] || usage_err "--timeout needs seconds"; timeout=$2; shift 2 ;;
    --subnet) [[ $# -ge 2 && $2 =~ ^10\.[0-9]+\.[0-9]+$ ]] || usage_err "--subnet needs 10.B.C"; subnet=$2; shift 2 ;;
    --keep) keep=1; shift ;;
    --plumbing-only) plumbing_only=1; shift ;;
    --designs) [[ $# -ge 2 && $2 =~ ^[1-9][0-9]*$ ]] || usage_err "--designs needs a count"; designs=$2; shift 2 ;;
    --latency) [[ $# -ge 2 && $2 =~ ^[0-9]+$ ]] || usage_err "--latency needs milliseconds"; latency=$2; shift 2 ;;
    --jitter) [[ $# -ge 2 && $2 =~ ^[0-9]+$ ]] || usage_err "--jitter needs milliseconds"; jitter=$2; shift 2 ;;
    --loss) [[ $# -ge 2 && $2 =~ ^[0-9]+(\.[0-9]{1,2})?$ ]] || usage_err "--loss needs a percentage like 2 or 0.5"; loss=$2; shift 2 ;;
    --partition) [[ $# -ge 2 && $2 =~ ^[0-9]+$ ]] || usage_err "--partition needs seconds"; partition=$2; shift 2 ;;
    --partition-after) [[ $# -ge 2 && $2 =~ ^[0-9]+$ ]] || usage_err "--partition-after needs episodes"; partition_after=$2; shift 2 ;;
    --lease) [[ $# -ge 2 && $2 =~ ^[1-9][0-9]*$ ]] || usage_err "--lease needs seconds"; lease=$2; shift 2 ;;
    --compare) compare=1; shift ;;
    --report) [[ $# -ge 2 ]] || usage_err "--report needs a file"; report=$2; shift 2 ;;
    -*) usage_err "unknown option '$1'" ;;
    *) bin=$1; shift ;;
  esac
done

# --- can this machine do it? ---------------------------------------------------------------------
[[ $(uname -s) == Linux ]] || skip "network namespaces need Linux (this is $(uname -s))"
((BASH_VERSINFO[0] > 5 || (BASH_VERSINFO[0] == 5 && BASH_VERSINFO[1] >= 1))) || skip "needs bash >= 5.1"
command -v ip >/dev/null 2>&1 || skip "'ip' not found: install iproute2 (Debian: apt-get install -y iproute2)"
command -v ss >/dev/null 2>&1 || skip "'ss' not found: install iproute2"
command -v unshare >/dev/null 2>&1 || skip "'unshare' not found: install util-linux"
[[ $EUID -eq 0 ]] || skip "needs root (or CAP_NET_ADMIN and CAP_SYS_ADMIN) for 'ip netns add'; run with sudo"
command -v python3 >/dev/null 2>&1 || skip "python3 not found (the stand-in server and the run-directory checks use it)"
[[ -n $jitter ]] || jitter=$((latency / 5))
loss_per_10k=$(python3 -c 'import sys; print(round(float(sys.argv[1]) * 100))' "$loss")
if ((loss_per_10k > 0 || partition > 0)) && ! command -v nft >/dev/null 2>&1; then
  # The project installs what its tests need (Debian's nftables: the userspace side of the
  # kernel's nf_tables, which this kernel has).
  if command -v apt-get >/dev/null 2>&1; then
    say "installing nftables (apt-get install nftables) for --loss/--partition"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q nftables >/dev/null 2>&1 ||
      { apt-get update -q >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q nftables >/dev/null 2>&1; } || true
  fi
  command -v nft >/dev/null 2>&1 || skip "--loss and --partition need nftables ('nft'), which could not be installed"
fi

if ((!plumbing_only)); then
  [[ -n $bin ]] || bin=$REPO_ROOT/target/release/coadapt
  [[ -x $bin ]] || usage_err "no coadapt binary at '$bin' (cargo build --release -p coadapt)"
  bin=$(cd -- "$(dirname -- "$bin")" && pwd)/$(basename -- "$bin")
  for sub in learner optimizer actor; do
    "$bin" "$sub" --help >/dev/null 2>&1 ||
      skip "'$bin $sub --help' failed: this coadapt has no '$sub' subcommand yet (process roles, issue 5)"
  done
  if [[ -z $config ]]; then
    config=$REPO_ROOT/configs/pendulum-tiny.toml
    [[ -f $config ]] || config=$REPO_ROOT/configs/half-cheetah-tiny.toml
  fi
  [[ -r $config ]] || usage_err "config '$config' is not readable"
fi

if [[ -n $designs$lease ]] && ((!plumbing_only)); then
  changed=$(mktemp "${TMPDIR:-/tmp}/coadapt-netns-config.XXXXXX.toml")
  python3 - "$config" "$changed" "$designs" "$lease" <<'PY' || usage_err "cannot set schedule.designs or the lease in '$config'"
import re, sys
text = open(sys.argv[1]).read()
if sys.argv[3]:
    text, n = re.subn(r"(?m)^designs = \d+$", f"designs = {sys.argv[3]}", text)
    if n != 1:
        sys.exit(f"{sys.argv[1]} has no single `designs = N` line")
if sys.argv[4]:
    if re.search(r"(?m)^\[flow\]", text):
        sys.exit(f"{sys.argv[1]} has a [flow] table already")
    text += f"\n[flow]\nassignment-lease-secs = {sys.argv[4]}\n"
open(sys.argv[2], "w").write(text)
PY
  config=$changed
fi

tag="cx$$"                # namespaces and links are named after this process: runs can overlap
ns_sw="coadapt-$tag-sw"   # the switch: holds the bridge
ns_l="coadapt-$tag-learner"
ns_a1="coadapt-$tag-actors1"
ns_a2="coadapt-$tag-actors2"
learner_ip=$subnet.1
work=$(mktemp -d "${TMPDIR:-/tmp}/coadapt-netns.XXXXXX")
created_ns=()
bg_pids=()

cleanup() {
  local st=$? pid ns
  trap - EXIT INT TERM
  set +m # no job-status lines for the launchers we stop
  for pid in "${bg_pids[@]}"; do # our launchers (each stops its own children on SIGINT/TERM)
    kill -TERM "$pid" 2>/dev/null || true
  done
  for pid in "${bg_pids[@]}"; do
    for _ in $(seq 20); do kill -0 "$pid" 2>/dev/null || break; sleep 0.5; done
    kill -KILL "$pid" 2>/dev/null || true
  done
  for ns in "${created_ns[@]}"; do # whatever still runs inside our namespaces was started by us
    for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$pid" 2>/dev/null || true; done
  done
  for ns in "${created_ns[@]}"; do
    ip netns del "$ns" 2>/dev/null || say "warning: could not delete namespace $ns"
  done
  # The veth pairs die with their namespaces; check that nothing of ours is left.
  if ip netns list 2>/dev/null | grep -q -- "coadapt-$tag-"; then
    say "warning: namespaces left: $(ip netns list | grep -- "coadapt-$tag-" | tr '\n' ' ')"
  fi
  if ((passed && !keep)); then
    rm -rf -- "$work"
  else
    say "work directory kept: $work"
  fi
  exit "$st"
}
trap cleanup EXIT
# Background processes keep SIGINT's default disposition (without -m bash ignores it in them,
# and fleet.sh could not trap it), each in its own process group.
set -m
trap 'say "interrupted"; exit 130' INT TERM

# --- the namespaces ------------------------------------------------------------------------------
add_ns() {
  local err
  if ! err=$(ip netns add "$1" 2>&1); then
    skip "'ip netns add' is not allowed here: $err (a container without CAP_SYS_ADMIN/CAP_NET_ADMIN, or no /run/netns)"
  fi
  created_ns+=("$1")
  ip -n "$1" link set lo up
}
add_ns "$ns_sw"
if ! err=$(ip -n "$ns_sw" link add br0 type bridge 2>&1); then
  skip "cannot create a bridge in a namespace: $err (kernel without bridge support?)"
fi
ip -n "$ns_sw" link set br0 up

# attach NS INDEX: a veth pair from NS (as eth0, $subnet.INDEX/24) into the bridge.
attach() {
  local ns=$1 idx=$2 a="${tag}n$2" b="${tag}s$2"
  add_ns "$ns"
  ip link add "$a" netns "$ns" type veth peer name "$b" netns "$ns_sw" ||
    fail "cannot create the veth pair for $ns"
  ip -n "$ns" link set "$a" name eth0
  ip -n "$ns" addr add "$subnet.$idx/24" dev eth0
  ip -n "$ns" link set eth0 up
  ip -n "$ns_sw" link set "$b" master br0
  ip -n "$ns_sw" link set "$b" up
}
attach "$ns_l" 1
attach "$ns_a1" 2
attach "$ns_a2" 3
say "namespaces: $ns_l ($learner_ip), $ns_a1 ($subnet.2), $ns_a2 ($subnet.3), bridged in $ns_sw"
if ((loss_per_10k > 0)); then
  for ns in "$ns_l" "$ns_a1" "$ns_a2"; do
    ip netns exec "$ns" nft add table inet coadapt_loss
    ip netns exec "$ns" nft add chain inet coadapt_loss out '{ type filter hook output priority 0 ; }'
    ip netns exec "$ns" nft add rule inet coadapt_loss out oifname eth0 numgen random mod 10000 '<' "$loss_per_10k" drop ||
      skip "nftables cannot drop packets here (numgen random)"
  done
  say "faults: $loss % of the packets leaving every host dropped"
fi

# in_host NS CMD...: CMD in namespace NS with a /dev/shm of its own (as on a separate machine).
in_host() {
  local ns=$1
  shift
  ip netns exec "$ns" unshare --mount --propagation private -- \
    bash -c 'mount -t tmpfs -o size=256m,mode=1777 coadapt-shm /dev/shm && exec "$@"' in_host "$@"
}

# wait_port NS IP PORT SECS: until a TCP connection to IP:PORT from NS succeeds.
wait_port() {
  local deadline=$((SECONDS + $4))
  until ip netns exec "$1" python3 -c 'import socket,sys; socket.create_connection((sys.argv[1], int(sys.argv[2])), 1).close()' "$2" "$3" 2>/dev/null; do
    ((SECONDS < deadline)) || return 1
    sleep 0.5
  done
}

# --- the plumbing, with a stand-in server ----------------------------------------------------------
mkdir -p "$work/www"
echo "hello from $ns_l" >"$work/www/probe.txt"
ip netns exec "$ns_l" python3 -m http.server --bind "$learner_ip" --directory "$work/www" 18080 \
  >"$work/stand-in-server.log" 2>&1 &
bg_pids+=("$!")
stand_in=$!
wait_port "$ns_a1" "$learner_ip" 18080 15 || fail "stand-in server on $learner_ip:18080 not reachable from $ns_a1 (see $work/stand-in-server.log)"
for ns in "$ns_a1" "$ns_a2"; do
  got=$(ip netns exec "$ns" python3 -c 'import sys,urllib.request; print(urllib.request.urlopen(sys.argv[1], timeout=5).read().decode().strip())' "http://$learner_ip:18080/probe.txt") ||
    fail "HTTP from $ns to $learner_ip failed"
  [[ $got == "hello from $ns_l" ]] || fail "HTTP from $ns got '$got'"
done
# The namespaces are isolated from the host: the host's loopback is not theirs.
if ip netns exec "$ns_a1" python3 -c 'import socket; socket.create_connection(("127.0.0.1", 18080), 1)' 2>/dev/null; then
  fail "$ns_a1 reaches 127.0.0.1:18080: the namespaces are not isolated"
fi
kill "$stand_in" 2>/dev/null || true
wait "$stand_in" 2>/dev/null || true
say "plumbing OK: HTTP from both actor namespaces to $learner_ip across the bridge; loopback isolated"
if ((plumbing_only)); then
  passed=1
  say "PASS (plumbing only)"
  exit 0
fi

# --- the real fleet -------------------------------------------------------------------------------
run_dir=$work/run
fleet=coadapt-netns-$$
say "coadapt: $bin; config: $config; run directory: $run_dir"
# Across hosts the learner serves TLS and accepts only the actors' and the optimiser's tokens:
# certificates for its address and one token per role, made by coadapt itself.
sec=$work/sec
"$bin" tls new --out "$sec/tls" --host "$learner_ip" 2>>"$work/credentials.log" || fail "coadapt tls new failed"
for role in actor optimizer; do
  "$bin" token new --role "$role" --out "$sec/$role.token" --tokens-file "$sec/tokens" 2>>"$work/credentials.log" ||
    fail "coadapt token new --role $role failed"
done
in_host "$ns_l" "$REPO_ROOT/deploy/multi-host/learner-host.sh" --bin "$bin" --config "$config" \
  --listen "$learner_ip:50051" --out "$run_dir" --fleet "$fleet" -- --grace 20 \
  --tls-dir "$sec/tls" --tokens-file "$sec/tokens" --optimizer-token "$sec/optimizer.token" \
  >"$work/learner-host.out" 2>"$work/learner-host.err" &
learner_host=$!
bg_pids+=("$learner_host")
wait_port "$ns_a1" "$learner_ip" 50051 60 ||
  fail "the learner is not listening on $learner_ip:50051 after 60 s (see $run_dir/logs/learner-0.log)"
say "learner listening on $learner_ip:50051"
learner_url="http://$learner_ip:50051"
if ((latency > 0)); then
  ip netns exec "$ns_l" python3 "$SCRIPT_DIR/delay_proxy.py" "$learner_ip:50052" "$learner_ip:50051" "$latency" "$jitter" \
    >"$work/delay-proxy.log" 2>&1 &
  bg_pids+=("$!")
  wait_port "$ns_a1" "$learner_ip" 50052 15 || fail "the delay proxy is not listening (see $work/delay-proxy.log)"
  learner_url="http://$learner_ip:50052"
  say "faults: actors reach the learner through a $latency ms (sd $jitter ms) delay each way"
fi
if ((partition > 0)); then
  # Cut the second actor host off once the run is under way, heal it after $partition s.
  (
    until [[ -f $run_dir/episodes.csv ]] && (($(wc -l <"$run_dir/episodes.csv") > partition_after)); do sleep 0.2; done
    ip netns exec "$ns_a2" nft add table inet coadapt_cut
    ip netns exec "$ns_a2" nft add chain inet coadapt_cut in '{ type filter hook input priority 0 ; policy drop ; }'
    ip netns exec "$ns_a2" nft add chain inet coadapt_cut out '{ type filter hook output priority 0 ; policy drop ; }'
    echo "cut $(date +%s.%N) $(($(wc -l <"$run_dir/episodes.csv") - 1))" >>"$work/partition.log"
    sleep "$partition"
    echo "healed $(date +%s.%N) $(($(wc -l <"$run_dir/episodes.csv") - 1))" >>"$work/partition.log"
    ip netns exec "$ns_a2" nft delete table inet coadapt_cut
  ) &
  bg_pids+=("$!")
fi
actor_hosts=()
actor_ns=("$ns_a1" "$ns_a2")
actor_failures=()
i=0
for ns in "$ns_a1" "$ns_a2"; do
  in_host "$ns" "$REPO_ROOT/deploy/multi-host/actor-host.sh" "$learner_url" 1 \
    --first-id $((i * 100)) --bin "$bin" --config "$config" --fleet "$fleet" \
    --log-dir "$work/$ns-logs" -- --grace 20 --tls-dir "$sec/tls" --actor-token "$sec/actor.token" \
    >"$work/$ns.out" 2>&1 &
  actor_hosts+=("$!")
  bg_pids+=("$!")
  i=$((i + 1))
done

# While the run goes on, see each actor namespace hold a TCP connection to the learner.
declare -A connected=()
deadline=$((SECONDS + timeout))
while kill -0 "$learner_host" 2>/dev/null; do
  for ns in "$ns_a1" "$ns_a2"; do
    if [[ -z ${connected[$ns]:-} ]] && ip netns exec "$ns" ss -tnH state established "dst $learner_ip" 2>/dev/null | grep -q ":${learner_url##*:}"; then
      connected[$ns]=1
      say "$ns has a gRPC connection to ${learner_url#http://}"
    fi
  done
  if ((SECONDS >= deadline)); then
    fail "the run did not finish within ${timeout}s (logs: $run_dir/logs, $work/*-logs)"
  fi
  sleep 1
done
learner_status=0
wait "$learner_host" || learner_status=$?
say "learner host exited with status $learner_status"
for ((k = 0; k < ${#actor_hosts[@]}; k++)); do
  pid=${actor_hosts[$k]}
  for _ in $(seq 60); do kill -0 "$pid" 2>/dev/null || break; sleep 1; done
  if kill -0 "$pid" 2>/dev/null; then
    say "warning: actor host $k still running 60 s after the learner finished; stopping it"
    # SIGINT to what runs in its namespace (fleet.sh and the actors: both stop cleanly on it);
    # the launcher's subshell would not pass it on.
    for p in $(ip netns pids "${actor_ns[$k]}" 2>/dev/null); do kill -INT "$p" 2>/dev/null || true; done
  fi
  st=0
  wait "$pid" || st=$?
  say "actor host $k exited with status $st"
  ((st == 0)) || actor_failures+=("actor host $k (${actor_ns[$k]}) exited with status $st (logs: $work/${actor_ns[$k]}-logs)")
done

# --- the checks -------------------------------------------------------------------------------------
((learner_status == 0)) || fail "the learner failed (status $learner_status): $(tail -n 20 "$run_dir/logs/learner-0.log" 2>/dev/null)"
((${#actor_failures[@]} == 0)) || fail "${actor_failures[*]}"
for ns in "$ns_a1" "$ns_a2"; do
  [[ -n ${connected[$ns]:-} ]] || fail "never saw a gRPC connection from $ns to the learner (logs: $work/$ns-logs)"
done
summary=$(cat "$work/learner-host.out")
say "summary: $summary"
python3 - "$config" "$run_dir" "$summary" <<'PY' || fail "the run directory is not what the config asks for"
import csv, json, sys, tomllib
config, run_dir, summary = sys.argv[1], sys.argv[2], sys.argv[3]
with open(config, "rb") as f:
    cfg = tomllib.load(f)
designs = cfg.get("schedule", {}).get("designs")
def rows(name):
    with open(f"{run_dir}/{name}", newline="") as f:
        return list(csv.DictReader(f))
d = rows("designs.csv")
e = rows("episodes.csv")
problems = []
if designs is not None and len(d) != designs:
    problems.append(f"designs.csv has {len(d)} rows, the config asks for {designs}")
if [r.get("index") for r in d] != [str(i) for i in range(len(d))]:
    problems.append(f"designs.csv indices are {[r.get('index') for r in d]}")
if not e:
    problems.append("episodes.csv has no rows")
if {r.get("design") for r in e} != {r.get("index") for r in d}:
    problems.append("episodes.csv does not cover every design of designs.csv")
if e and "actor" in e[0]:
    by_actor = {}
    for r in e:
        by_actor[r["actor"]] = by_actor.get(r["actor"], 0) + 1
    print(f"  episodes by actor: {by_actor}", file=sys.stderr)
    strangers = set(by_actor) - {"0", "100"}
    if strangers:
        problems.append(f"episodes.csv names actors {sorted(strangers)}, not ours (0, 100)")
    if len(by_actor) < 2:
        print("  note: one actor host ran every episode (allowed: lock-step hands them out one at a time)", file=sys.stderr)
try:
    s = json.loads(summary.strip().splitlines()[-1])
    if designs is not None and s.get("designs") != designs:
        problems.append(f"summary says designs={s.get('designs')}")
except (ValueError, IndexError) as err:
    problems.append(f"no JSON summary line on the learner's stdout ({err})")
for p in problems:
    print("  " + p, file=sys.stderr)
print(f"  designs.csv: {len(d)} rows; episodes.csv: {len(e)} rows", file=sys.stderr)
sys.exit(1 if problems else 0)
PY
for role in actor optimizer; do
  tok=$(<"$sec/$role.token")
  if grep -rqF -- "$tok" "$run_dir/logs" "$work"/*-logs "$work"/*.out "$work"/*.err 2>/dev/null; then
    fail "the $role token appears in a log"
  fi
done
say "the fleet spoke TLS with role tokens across hosts; no token in any log"
if ((partition > 0)); then
  [[ -s $work/partition.log ]] || fail "the partition never happened (the run ended before $partition_after episodes?)"
  say "partition: $(tr '\n' ' ' <"$work/partition.log")"
  if grep -q '^healed' "$work/partition.log"; then
    # Did the cut-off host come back? Episodes after the heal that its actor (id 100) ran.
    healed_at=$(awk '/^healed/ {print $3}' "$work/partition.log")
    back=$(python3 -c 'import csv,sys; r=list(csv.DictReader(open(sys.argv[1]))); print(sum(1 for x in r[int(sys.argv[2]):] if x.get("actor") == "100"))' \
      "$run_dir/episodes.csv" "$healed_at")
    say "partition: the cut-off actor host ran $back episodes after it was healed"
  else
    say "note: the run ended while the second actor host was still cut off"
  fi
fi
if ((compare)); then
  # Lock-step is deterministic: the same config in one process must write the same rows (but
  # the wall clock, which actor ran an episode, and its policy lag).
  "$bin" run --config "$config" --transport in-process --out "$work/undisturbed" >"$work/undisturbed.out" 2>"$work/undisturbed.err" ||
    fail "the undisturbed in-process run failed (see $work/undisturbed.err)"
  python3 "$REPO_ROOT/deploy/compare_runs.py" "$run_dir" "$work/undisturbed" || fail "the rows differ from the undisturbed run's"
  say "every row equals the undisturbed run's: no transition lost or counted twice"
fi
if [[ -n $report ]]; then
  python3 - "$summary" "$latency" "$jitter" "$loss" "$partition" "${lease:-60}" >>"$report" <<'PY'
import json, sys
s = json.loads(sys.argv[1].strip().splitlines()[-1])
secs = s["seconds"]
print(json.dumps({"bench": "fleet under faults", "config": f"latency {sys.argv[2]} ms sd {sys.argv[3]}, loss {sys.argv[4]} %, partition {sys.argv[5]} s, lease {sys.argv[6]} s",
                  "seconds": round(secs, 2), "learner_waiting_seconds": round(s["learner_waiting_seconds"], 2),
                  "transitions_per_second": round(s["replay_transitions"] / secs, 1), "transitions": s["replay_transitions"],
                  "episodes_reissued": s["episodes_reissued"], "impl": "coadapt"}))
PY
fi
passed=1
say "PASS: learner + optimiser in $ns_l, actors in $ns_a1 and $ns_a2, gRPC across the bridge; run directory checked"
