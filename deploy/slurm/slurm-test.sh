#!/usr/bin/env bash
# deploy/slurm/coadapt.sbatch on a real Slurm (Debian's slurmctld, slurmd and munge, installed
# by deploy/slurm/local-cluster.sh when missing): a controller and three compute nodes in
# network namespaces. A co-adaptation is submitted with a two-minute time limit, so that the
# time-limit signal stops and requeues it at least once; in the first allocation its learner is
# SIGKILLed a few episodes in (the job must start it again from the newest snapshot); in a later allocation, once the resumed
# run is under way, one actor node crashes while its actor holds the episode the run waits for
# (caught by stopping the actor and seeing the run stall; then its network down, SIGKILL to its
# slurmd, job steps and actors: the episode must go to the other actor) and
# reboots (its slurmd started again) once the controller has marked it down or 30 s later. The run must complete, and its
# designs.csv and episodes.csv must equal those of the same config run once, undisturbed, in
# one process (lock-step is deterministic): nothing lost, nothing counted twice.
#
# A requeued job waits about two minutes before Slurm lets it start again; the test releases
# it after 10 s, once no node is still completing the last allocation (`scontrol update
# JobId=... StartTime=now`, as an operator may), to save the wait.
#
#   deploy/slurm/slurm-test.sh [--designs N|auto] [--keep] [COADAPT_BIN]
# --designs auto (the default) sizes the run to about 100 s of this machine's work (timed
# on a short run first), so that the two-minute limit requeues it whatever the build's speed.
# Exit: 0 pass; 1 fail; 2 usage; 77 skipped (why is printed).
set -euo pipefail

SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
REPO_ROOT=$(cd -- "$SCRIPT_DIR/../.." && pwd)
say() { printf '[slurm-test %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }
fail() { say "FAIL: $*"; exit 1; }
usage_err() { printf 'slurm-test.sh: %s\n' "$*" >&2; exit 2; }

bin=${COADAPT_BIN:-}
designs=auto
keep=0
timeout=900
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    --designs) [[ $# -ge 2 && $2 =~ ^([1-9][0-9]*|auto)$ ]] || usage_err "--designs needs a count or auto"; designs=$2; shift 2 ;;
    --keep) keep=1; shift ;;
    --timeout) [[ $# -ge 2 && $2 =~ ^[0-9]+$ ]] || usage_err "--timeout needs seconds"; timeout=$2; shift 2 ;;
    -*) usage_err "unknown option '$1'" ;;
    *) bin=$1; shift ;;
  esac
done
[[ -n $bin ]] || bin=$REPO_ROOT/target/release/coadapt
[[ -x $bin ]] || usage_err "no coadapt binary at '$bin'"
bin=$(cd -- "$(dirname -- "$bin")" && pwd)/$(basename -- "$bin")

work=$(mktemp -d "${TMPDIR:-/tmp}/coadapt-slurm.XXXXXX")
chmod 755 "$work"
cluster=$work/cluster
passed=0
cleanup() {
  local st=$?
  trap - EXIT INT TERM
  "$SCRIPT_DIR/local-cluster.sh" down "$cluster" 2>/dev/null || true
  if ((passed && !keep)); then rm -rf -- "$work"; else say "work directory kept: $work"; fi
  exit "$st"
}
trap cleanup EXIT
trap 'say "interrupted"; exit 130' INT TERM

st=0
"$SCRIPT_DIR/local-cluster.sh" up "$cluster" --nodes 3 || st=$?
((st == 0)) || { ((st == 77)) && { passed=1; exit 77; }; fail "the cluster did not come up"; }
sl() { "$SCRIPT_DIR/local-cluster.sh" exec "$cluster" "$@"; }

# The tiny co-adaptation, longer (designs) and with a short lease, so that a crashed node's
# episode goes to the other actor in seconds.
config=$work/config.toml
with_designs() { # with_designs N FILE
python3 - "$REPO_ROOT/configs/half-cheetah-tiny.toml" "$2" "$1" <<'PY'
import re, sys
text = open(sys.argv[1]).read()
text, n = re.subn(r"(?m)^designs = \d+$", f"designs = {sys.argv[3]}", text)
assert n == 1, "half-cheetah-tiny.toml has no single designs line"
assert "[flow]" not in text
text += "\n[flow]\nassignment-lease-secs = 5\n"
open(sys.argv[2], "w").write(text)
PY
}
if [[ $designs == auto ]]; then
  # Time 12 designs in one process; size the run to about 100 s of that pace (at least 100).
  with_designs 12 "$work/pace.toml"
  t0=$(date +%s.%N)
  "$bin" run --config "$work/pace.toml" --transport in-process --out "$work/pace" >/dev/null 2>"$work/pace.err" ||
    fail "the pace run failed (see $work/pace.err)"
  designs=$(python3 -c 'import sys; s = float(sys.argv[2]) - float(sys.argv[1]); print(max(100, min(3000, round(100 * 12 / s))))' "$t0" "$(date +%s.%N)")
  say "pace: 12 designs in $(python3 -c 'import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 1))' "$t0" "$(date +%s.%N)") s; the run gets $designs designs"
fi
with_designs "$designs" "$config"
run_dir=$work/run
out=$work/job.out
job=$(COADAPT_BIN=$bin COADAPT_CONFIG=$config COADAPT_RUN_DIR=$run_dir \
  sl sbatch --parsable --time=2 --signal=B:USR1@60 --output="$out" "$REPO_ROOT/deploy/slurm/coadapt.sbatch") ||
  fail "sbatch failed"
job=${job%%;*}
say "submitted job $job: $designs designs, time limit 2 min, signal 60 s before it"
# Meanwhile the same config once, undisturbed, in one process (lock-step gives the same rows).
"$bin" run --config "$config" --transport in-process --out "$work/undisturbed" >"$work/undisturbed.out" 2>"$work/undisturbed.err" &
undisturbed=$!

job_field() { sl scontrol show job "$job" -o 2>/dev/null | tr ' ' '\n' | sed -n "s/^$1=//p"; }
episodes() { if [[ -f $run_dir/episodes.csv ]]; then echo $(($(wc -l <"$run_dir/episodes.csv") - 1)); else echo 0; fi; }
# n3_holds_an_episode: stop n3's actor (SIGSTOP) and see whether the run stalls: in lock-step the
# learner then waits for the episode that actor holds. If rows keep coming, it held none: it is
# let go again (SIGCONT) and the caller tries later.
n3_holds_an_episode() {
  local ns pids=() pid e0
  ns=$(sed -n 's/^ns_prefix=//p' "$cluster/env")-n3
  for pid in $(ip netns pids "$ns" 2>/dev/null); do
    tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null | grep -q ' actor --config' && pids+=("$pid")
  done
  ((${#pids[@]})) || return 1
  kill -STOP "${pids[@]}" 2>/dev/null || return 1
  e0=$(episodes)
  sleep 2
  (($(episodes) == e0)) && return 0
  kill -CONT "${pids[@]}" 2>/dev/null
  return 1
}
# learner_pid: the learner's pid on the head node n1 (the first allocation's, or any).
learner_pid() {
  local ns pid
  ns=$(sed -n 's/^ns_prefix=//p' "$cluster/env")-n1
  for pid in $(ip netns pids "$ns" 2>/dev/null); do
    if tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null | grep -q ' learner --config'; then echo "$pid"; return 0; fi
  done
  return 1
}
crashed=0 restarted_node=0 released=0 crash_at="" pending_since="" held=0 learner_killed=0
deadline=$((SECONDS + timeout))
while :; do
  state=$(job_field JobState)
  restarts=$(job_field Restarts)
  case $state in COMPLETED | FAILED | CANCELLED | TIMEOUT | NODE_FAIL | OUT_OF_MEMORY) break ;; esac
  # Released once the last allocation is cleaned up on every node (released sooner, Slurm
  # starts it before the old batch step has gone and kills it: "Job credential revoked").
  if [[ $state == PENDING && $(job_field Reason) == BeginTime ]]; then
    [[ -n $pending_since ]] || pending_since=$SECONDS
    if ((SECONDS - pending_since >= 10)) && ! sl sinfo -h -o %t | grep -q comp; then
      sl scontrol update JobId="$job" StartTime=now && released=$((released + 1))
      say "job $job requeued ($restarts restart(s)): released after $((SECONDS - pending_since)) s instead of Slurm's 2 min"
      pending_since=""
    fi
  fi
  # In the first allocation, a few episodes in, the learner is SIGKILLed (as the out-of-memory
  # killer does): coadapt.sbatch must start it again from the run's newest snapshot.
  if ((!learner_killed)) && [[ $state == RUNNING && ${restarts:-0} -eq 0 ]] && (($(episodes) >= 8)); then
    if lpid=$(learner_pid) && kill -KILL "$lpid" 2>/dev/null; then
      learner_killed=1
      say "the learner (pid $lpid) SIGKILLed at episode $(episodes)"
    fi
  fi
  # Crash an actor node once the run has resumed in a later allocation and gone on a little.
  if ((!crashed)) && [[ $state == RUNNING && ${restarts:-0} -ge 1 ]] && [[ -f $run_dir/slurm/job-$job-$restarts/learner.log ]]; then
    [[ -n $crash_at ]] || { crash_at=$(($(episodes) + 6)); crash_by=$((SECONDS + 30)); }
    # While n3's actor holds the episode the run waits for, so that the episode is lost with the
    # node and must go to the other actor; if that moment is not caught within 30 s, anyway.
    go=0
    if (($(episodes) >= crash_at)); then
      if n3_holds_an_episode; then
        go=1 held=1
      elif ((SECONDS >= crash_by)); then
        go=1
      fi
    fi
    if ((go)); then
      "$SCRIPT_DIR/local-cluster.sh" kill-node "$cluster" n3
      crashed=1
      crashed_at=$(episodes)
      crashed_secs=$SECONDS
      say "node n3 crashed at episode $crashed_at ($( ((held)) && echo "holding the episode the run waited for" || echo "the moment it held one was not caught in 30 s"))"
    fi
  fi
  # The crashed node reboots: once the controller has marked it down, or after 30 s (a node
  # whose job was requeued meanwhile may wait in "completing" for its dead slurmd for minutes).
  if ((crashed && !restarted_node)); then
    n3_state=$(sl sinfo -h -N -n n3 -o %t)
    if [[ $n3_state == down* ]] || ((SECONDS - crashed_secs >= 30)); then
      "$SCRIPT_DIR/local-cluster.sh" start-node "$cluster" n3
      restarted_node=1
      say "node n3 ($n3_state) rebooted: its slurmd started again"
    fi
  fi
  ((SECONDS < deadline)) || fail "job $job not finished after ${timeout}s (state $state; see $out)"
  sleep 1
done
say "job $job ended: $state after $restarts requeue(s)"
cat "$out" >&2 || true

[[ $state == COMPLETED ]] || fail "job $job ended $state (see $out and $run_dir/slurm)"
((restarts >= 1)) || fail "the time limit never requeued the job (the run ended within one allocation: raise --designs)"
((crashed)) || fail "the run ended before node n3 could be crashed (raise --designs)"
grep -q "requeueing job $job" "$out" || fail "the job output does not say it requeued itself"
if grep -q "scontrol requeue failed" "$out"; then fail "the job output tells the operator to resubmit a job Slurm requeued"; fi
((learner_killed)) || fail "the run ended before its learner could be SIGKILLed (raise --designs)"
grep -q "restarting it from the run's newest snapshot" "$out" || fail "the job output does not say it restarted the killed learner"
last=$run_dir/slurm/job-$job-$restarts/learner.out
grep -q '"interrupted":false' "$last" || fail "the last allocation's learner did not finish the run"
after=$(($(episodes) - crashed_at))
((after > 0)) || fail "no episode after node n3 crashed"
reissued=$(cat "$run_dir"/slurm/job-*/learner.out | grep -o '"episodes_reissued":[0-9]*' | awk -F: '{n += $2} END {print n + 0}')
if [[ $held == 1 ]]; then
  ((reissued >= 1)) || fail "node n3 crashed holding the episode the run waited for, yet no episode was reissued"
fi
say "after the crash: $after episodes on the nodes left; $reissued episode(s) reissued over all allocations (the one n3 held when it died goes to another actor after the 5 s lease)"
for tok in "$run_dir/slurm/credentials/"*.token; do
  if grep -rqF -- "$(<"$tok")" "$out" "$run_dir/slurm"/job-* 2>/dev/null; then fail "a token ($tok) appears in a log"; fi
done
allocs=("$run_dir"/slurm/job-*)
say "no token in any log; allocations: ${allocs[*]##*/}"

wait "$undisturbed" || fail "the undisturbed in-process run failed (see $work/undisturbed.err)"
python3 "$REPO_ROOT/deploy/compare_runs.py" "$run_dir" "$work/undisturbed" "$designs" || fail "the rows differ from the undisturbed run's"
say "every row equals the undisturbed run's: nothing lost or counted twice across a SIGKILLed learner, $restarts requeue(s) and a crashed node"
# A job whose run is already complete (as when the time limit comes just as the last design
# ends, and the requeued allocation finds nothing left): its learner ends at once, before it
# listens; that is the run's end, not a failure.
again=$(COADAPT_BIN=$bin COADAPT_RUN_DIR=$run_dir COADAPT_NO_REQUEUE=1 \
  sl sbatch --parsable --time=2 --output="$work/again.out" "$REPO_ROOT/deploy/slurm/coadapt.sbatch") || fail "sbatch (again) failed"
again=${again%%;*}
for _ in $(seq 120); do
  st=$(sl scontrol show job "$again" -o 2>/dev/null | tr ' ' '\n' | sed -n 's/^JobState=//p')
  case $st in COMPLETED | FAILED | CANCELLED | TIMEOUT | NODE_FAIL) break ;; esac
  sleep 1
done
[[ $st == COMPLETED ]] || fail "a job submitted on a complete run ended ${st:-unknown} (see $work/again.out)"
grep -q "the run completed" "$work/again.out" || fail "a job submitted on a complete run did not say the run completed (see $work/again.out)"
say "a job submitted on the complete run ends at once, COMPLETED: the run completed"
passed=1
say "PASS: coadapt.sbatch on Slurm: restarted its SIGKILLed learner, requeued by the time limit, resumed, survived a crashed actor node"
