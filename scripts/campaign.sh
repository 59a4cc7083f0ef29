#!/usr/bin/env bash
# Runs a queue of co-adaptation experiments (issue 10's campaign), N at a time, each
# single-threaded (RAYON_NUM_THREADS=1; THREADS=2 for a lone lane on two cores, such as the
# reference protocol: the same rows, tested by learner/tests/two_cores.rs), in-process (the same
# results as a fleet of processes, tested byte for byte; fewer processes competing for two cores).
#
#   usage: [BIN=coadapt-binary] [THREADS=1] scripts/campaign.sh [-j N] [--until TIME] QUEUE_FILE
#   --until TIME (what `date -d` reads: 05:30, 'now + 2 hours'): a line starts (or resumes) only
#          if it will end by then, by `scripts/campaign_status.py QUEUE --seconds NAME SEED
#          --threads THREADS` and a quarter more; one without an estimate does not start. A skipped
#          line stays for the next start of the queue; the lanes go on down the queue for lines
#          that fit (a retrain). For a session whose machine may not be kept: a run stopped at the
#          session's end resumes only where its snapshots survive. Several queues in turn per
#          lane: scripts/lanes.sh.
#   stop:  scripts/campaign.sh --stop QUEUE_FILE (or Ctrl-C in its terminal): the runs snapshot
#          and stop; the queue started again resumes them. While a queue runs, its pid is in
#          runs/campaign/QUEUE.pid, and a second start of the same queue is refused (two
#          campaigns would write the same run directories).
#   stop at a snapshot: scripts/campaign.sh --stop-at-snapshot QUEUE_FILE [DEADLINE]: waits
#          until every run the queue has going has written a snapshot since the call (a retrain
#          line: finished one of its seeds), then stops the queue as --stop does; at DEADLINE
#          (what `date -d` reads: 07:05, 'now + 20 min') it stops it whatever. A run started
#          since the call and less than CAMPAIGN_YOUNG seconds (10) ago has nothing to lose.
#          For a session's end with a binary older than 50b2f2a, which on a stop with an
#          episode out takes no snapshot: the run then goes back to its newest one and does
#          again what followed.
#
# QUEUE_FILE: one experiment per line, `NAME CONFIG SEED [coadapt run flags...]`; `#` starts a
# comment. NAME becomes runs/campaign/NAME-seedSEED. A line whose run directory already holds a
# finished run (summary.json) is skipped, so the same queue can be started again after a stop:
# an unfinished directory that holds a snapshot goes on from it (`coadapt run --resume`, the
# same rows as a run never stopped); one without a snapshot is moved aside to
# NAME-seedSEED.partial-<time> and the run starts over.
# CONFIG `retrain:SRC:exploit|explore|best` retrains a finished run's chosen body from scratch
# (retrain_one, in scripts/campaign_lines.sh).
# CONFIG `fork:SRC:K[+overrides]` forks runs/campaign/SRC-seedSEED at the start of design K
# (scripts/fork_run.sh, with the overrides, e.g. `fork:fear-random:5+optimizer.exploit="sim-pso"`)
# and continues the fork: the prefix two methods share is not run twice. The copy is taken by a
# watcher started when the queue starts (it waits for the source's snapshot at design K and
# uses no core while it waits); the line itself takes a lane only when its turn comes. Put a
# fork line after its source and far enough behind it that the source has reached design K.
# A source archived in docs/campaign/results whose run directory is gone (its snapshots were on
# another machine) has its first K designs run again by the fork's lane, checked row for row
# against the archive (a binary that does not reproduce them is refused), then forked; so is the
# whole of a run named by a line's `--init-population runs/campaign/NAME-seedS`. CONFIG may carry overrides, `CONFIG+key.path=value+...` (TOML values, e.g.
# `configs/half-cheetah-reduced.toml+learner.population-only=true+optimizer.q="pessimistic"`),
# applied by scripts/config_with.py. `random-only:CONFIG` is CONFIG with `alternate = false`
# (every later design uniform random, the thesis's random-designs baseline; pass --exploit random).
# A line being run by another campaign (queues share lines) is skipped: RUN.lock holds the
# lane's pid while a lane has the line.
# Each run's stdout (the JSON summary line) goes to RUN/summary.json, stderr to RUN.log.
# A finished run's small files (summary.json, config.toml, designs.csv, episodes.csv, and the
# optimiser's calibration.csv, a fork's forked-from.txt and the conservative term's
# conservative.csv (from TensorBoard, scripts/tb_scalars.py) where there are some) are also
# copied to docs/campaign/results/NAME-seedSEED/ to be committed: runs/ does not survive a new
# checkout, and a line whose results are archived there is skipped too.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=2
threads=${THREADS:-1}
stop=""
until_s=""
while [ $# -gt 0 ]; do
  case $1 in
    -j) [[ ${2:-} =~ ^[1-9][0-9]*$ ]] || { echo "campaign: -j takes a number of lanes, not '${2:-}'" >&2; exit 2; }
        jobs=$2; shift 2 ;;
    --until)
      until_s=$(date -d "${2:-}" +%s 2> /dev/null) || { echo "campaign: --until takes a time date -d reads (say 07:05), not '${2:-}'" >&2; exit 2; }
      [ "$until_s" -gt "$(date +%s)" ] || { echo "campaign: --until '${2:-}' is $(date -d "@$until_s" '+%F %H:%M'), already past (say 'tomorrow 01:00')" >&2; exit 2; }
      shift 2 ;;
    --stop) stop=yes; shift; break ;;
    --stop-at-snapshot) stop=at-snapshot; shift; break ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    *) break ;;
  esac
done
queue=${1:?usage: scripts/campaign.sh [-j N] [--until TIME] QUEUE_FILE, or --stop QUEUE_FILE, or --stop-at-snapshot QUEUE_FILE [DEADLINE]}
[ -f "$queue" ] || { echo "campaign: no queue file $queue" >&2; exit 2; }
pidfile=runs/campaign/$(basename "$queue" .queue).pid
# The live campaign of this queue, if any: the pid in its file, still a campaign.sh.
live_pid() {
  local p
  p=$(cat "$pidfile" 2>/dev/null || true)
  [[ $p =~ ^[1-9][0-9]*$ ]] && grep -qa campaign.sh "/proc/$p/cmdline" 2>/dev/null && echo "$p"
  return 0
}
# Whether pid $1 is pid $2 or runs below it.
below() {
  local p=$1
  while [[ $p =~ ^[1-9][0-9]*$ ]] && [ "$p" != 1 ]; do
    [ "$p" = "$2" ] && return 0
    # The parent's pid: the second field after the command name, which may hold spaces.
    p=$(sed -E 's/.*\) [A-Za-z] ([0-9]+) .*/\1/' "/proc/$p/stat" 2> /dev/null) || return 1
  done
  return 1
}
# The run directories queue pid $1's lanes hold (their lock directories name the lane's pid).
held_runs() {
  local lock
  for lock in runs/campaign/*.lock; do
    [ -d "$lock" ] && below "$(cat "$lock/pid" 2> /dev/null)" "$1" && echo "${lock%.lock}"
  done
  return 0
}
# Whether run directory $1 has written a snapshot (a retrain line: finished a seed) since
# epoch second $2, or has nothing to lose: its lane took it after $2 and less than
# CAMPAIGN_YOUNG seconds (10) ago (a line that started between two polls, as the one before it
# ended: stopping it now loses seconds, waiting for its first snapshot may cost the deadline).
saved_since() {
  local f lock=$1.lock
  if [ -d "$lock" ]; then
    local t
    t=$(stat -c %Y "$lock" 2> /dev/null) || t=0
    [ "$t" -ge "$2" ] && [ $(($(date +%s) - t)) -lt "${CAMPAIGN_YOUNG:-10}" ] && return 0
  fi
  for f in "$1"/snapshots/snap-* "$1"/train-seed*/summary.json; do
    [ -e "$f" ] && [ "$(stat -c %Y "$f")" -ge "$2" ] && return 0
  done
  return 1
}
if [ "$stop" = at-snapshot ]; then
  p=$(live_pid)
  [ -n "$p" ] || { echo "campaign: no campaign of $queue is running (no live pid in $pidfile)" >&2; exit 1; }
  deadline=""
  if [ -n "${2:-}" ]; then
    deadline=$(date -d "$2" +%s 2> /dev/null) || { echo "campaign: the deadline '$2' is not a time date -d reads (say 07:05)" >&2; exit 2; }
  fi
  since=$(date +%s)
  echo "campaign: waiting for a snapshot of each run of $queue's campaign (pid $p)${deadline:+, at most until $(date -d "@$deadline" +%H:%M:%S)}"
  while :; do
    [ -n "$(live_pid)" ] || { echo "campaign: $queue's campaign ended by itself"; exit 0; }
    waiting=()
    for d in $(held_runs "$p"); do saved_since "$d" "$since" || waiting+=("$(basename "$d")"); done
    if [ "${#waiting[@]}" = 0 ]; then
      echo "campaign: every run of $queue has snapshotted since $(date -d "@$since" +%H:%M:%S) or has just started"
      # A retrain line archives itself in the moments after its second seed: let it.
      sleep "${CAMPAIGN_GRACE:-3}"
      break
    fi
    if [ -n "$deadline" ] && [ "$(date +%s)" -ge "$deadline" ]; then echo "campaign: deadline; no new snapshot yet of ${waiting[*]}"; break; fi
    sleep "${CAMPAIGN_POLL:-5}"
  done
  stop=yes
fi
if [ -n "$stop" ]; then
  p=$(live_pid)
  [ -n "$p" ] || { echo "campaign: no campaign of $queue is running (no live pid in $pidfile)" >&2; exit 1; }
  kill -TERM "$p"
  echo "campaign: asked $queue's campaign (pid $p) to stop; its runs snapshot and exit"
  exit 0
fi
# `nice -n 19 scripts/campaign.sh` is meant to yield the cores to a build or CI. Under the
# kernel's autogroup scheduling (on here: /proc/sys/kernel/sched_autogroup_enabled) a process's
# nice weighs only within its session's group, and `setsid` makes the lane a group of its own,
# so the lane took two thirds of the machine from a CI run of nice 0 (seen 2026-11-28). When
# this script leads its session, its nice goes to the group too; a lane started from a
# terminal's session leaves that session's group alone.
if [ "$(ps -o sid= -p $$ | tr -d ' ')" = "$$" ] && [ -w /proc/self/autogroup ]; then
  echo "$(ps -o ni= -p $$ | tr -d ' ')" > /proc/self/autogroup 2> /dev/null || true
fi
# runs/ lives beside the work tree (../runs, linked as runs): a session's checkout is laid anew
# each time, and a machine that is kept then keeps the runs and their snapshots too.
if [ ! -e runs ] && [ ! -L runs ]; then
  mkdir -p ../runs && ln -s "$(cd ../runs && pwd)" runs
fi
root=runs/campaign
mkdir -p "$root/configs"
if [ -n "$(live_pid)" ]; then
  echo "campaign: $queue is already running (pid $(live_pid)); stop it first: scripts/campaign.sh --stop $queue" >&2
  exit 2
fi
echo $$ > "$pidfile"
main_pid=$$
stopflag=${pidfile%.pid}.stopping
# Only this shell removes the files (the lanes are subshells of it).
trap '[ "$BASHPID" = "$main_pid" ] && rm -f "$pidfile" "$stopflag" "$stopflag.signalled"' EXIT
# A private copy: rebuilding the workspace during the campaign does not touch running runs.
# BIN=path runs that binary instead of building the checkout: a queue whose runs must be made by
# an older build (say, before a change to a robot) names it in its header. Its copy is named after
# it, so that two queues running at once with different binaries do not swap each other's.
bin=$root/coadapt
if [ -n "${BIN:-}" ]; then
  [ -x "$BIN" ] || { echo "campaign: BIN=$BIN is not an executable" >&2; exit 2; }
  bin=$root/bin-$(basename "$BIN")
  cp "$BIN" "$bin.new.$$" && mv "$bin.new.$$" "$bin"
else
  cargo build --release -q -p coadapt
  cp target/release/coadapt "$bin.new.$$" && mv "$bin.new.$$" "$bin"
fi

# Whether process PID has a handler for SIGINT (bit 2 of SigCgt). Until a run has put its handler
# in place, SIGINT has its default action there (this script traps SIGINT, so its background jobs
# do not ignore it): the run would die at once, without a snapshot, and count as failed.
catches_int() {
  local mask
  mask=$(awk '/^SigCgt:/ { print $2 }' "/proc/$1/status" 2> /dev/null) || return 1
  [ -n "$mask" ] && (( 16#$mask & 2 ))
}

# Runs a binary ("$@", its output where the caller sends it) for a lane so that a stop reaches
# it wherever the stop lands. Stopped before it starts, it does not start (and says so as a
# stopped run does: "interrupted": true). Started after the queue signalled its processes (the
# stop landed between the lane's last look at the flag and the start, as at a fork's hand-off),
# or still without its handler when the stop came, it is not in the stop's list of processes
# signalled: the lane sends it SIGINT itself once it has a handler, once only (a second SIGINT
# aborts a run).
lane_exec() {
  if [ -e "$stopflag" ]; then echo '{"interrupted": true, "started": false}'; return 0; fi
  "$@" &
  local pid=$! sent=""
  while [ -e "/proc/$pid" ] && [ "$(sed -E 's/.*\) ([A-Za-z]).*/\1/' "/proc/$pid/stat" 2> /dev/null)" != Z ]; do
    if [ -z "$sent" ] && [ -e "$stopflag.signalled" ]; then
      if grep -qx "$pid" "$stopflag.signalled"; then
        sent=yes
      elif catches_int "$pid"; then
        kill -INT "$pid" 2> /dev/null || true
        sent=yes
      fi
    fi
    sleep 1
  done
  wait "$pid"
}

archive_run() {
  local dir=$1 archive=$2 t0=$3
  # A run stopped by a signal (Ctrl-C, a session's end) exits 0 with "interrupted": true: it
  # is not finished, so it is neither archived nor marked done; its snapshots resume it.
  if grep -Eq '"interrupted": *true' "$dir.summary.tmp"; then
    mv "$dir.summary.tmp" "$dir.interrupted.json"
    echo "campaign: stopped $dir before its end after $((SECONDS - t0)) s (not archived; the queue started again resumes it)" >&2
    return 0
  fi
  mv "$dir.summary.tmp" "$dir/summary.json"
  mkdir -p "$archive"
  cp "$dir"/{summary.json,config.toml,designs.csv,episodes.csv} "$archive/"
  if [ -f "$dir/forked-from.txt" ]; then cp "$dir/forked-from.txt" "$archive/"; fi
  if [ -f "$dir/optimizer/calibration.csv" ]; then cp "$dir/optimizer/calibration.csv" "$archive/"; fi
  # The conservative term's gap and weight, logged only to TensorBoard (EXPERIMENTS 5.13).
  if python3 scripts/tb_scalars.py "$dir" train/conservative_ > "$archive/conservative.csv.tmp" 2> /dev/null \
      && [ "$(wc -l < "$archive/conservative.csv.tmp")" -gt 1 ]; then
    mv "$archive/conservative.csv.tmp" "$archive/conservative.csv"
  else
    rm -f "$archive/conservative.csv.tmp"
  fi
  echo "campaign: done  $dir in $((SECONDS - t0)) s: $(cat "$dir/summary.json")"
}

# The lanes' locks and the line kinds that start from another run (retrain, the prefix of an
# archived fork source, an --init-population source): retrain_one, take_lock,
# regenerate_prefix, ensure_init_population.
source scripts/campaign_lines.sh

# The pid files of this queue's fork watchers (other queues running beside it have their own).
fork_pidfiles() {
  local name config seed rest
  while read -r name config seed rest; do
    case $name in ''|'#'*) continue ;; esac
    case $config in fork:*) echo "$root/$name-seed$seed.fork.pid" ;; esac
  done < "$queue"
}

# Starts the watchers that take the copies for the queue's fork lines.
start_fork_watchers() {
  local name config seed rest
  while read -r name config seed rest; do
    case $name in ''|'#'*) continue ;; esac
    case $config in fork:*) ;; *) continue ;; esac
    local dir=$root/$name-seed$seed
    if [ -e "$dir" ] || [ -s "docs/campaign/results/$name-seed$seed/summary.json" ]; then continue; fi
    local spec=${config#fork:} overrides=()
    local src=${spec%%:*} rest_k=${spec#*:}
    local k=${rest_k%%+*}
    if [[ $rest_k == *+* ]]; then IFS=+ read -r -a overrides <<< "${rest_k#*+}"; fi
    # A source that finished here and is archived, but kept only its newest snapshots (not the
    # one at design K): set aside, so that the line runs its first K designs again as for a
    # source whose directory is gone (run_one), instead of a watcher failing at once.
    local srcdir=$root/$src-seed$seed
    if [ -s "$srcdir/summary.json" ] && [ -s "docs/campaign/results/$src-seed$seed/summary.json" ] \
      && ! scripts/fork_run.sh --has "$srcdir" "$k"; then
      local aside
      aside=$srcdir.finished-$(date -u +%Y%m%dT%H%M%S)
      mv "$srcdir" "$aside"
      echo "campaign: $srcdir kept no snapshot at the start of design $k: set aside as $aside; its first $k designs run again for $name-seed$seed"
    fi
    rm -f "$dir.fork.log"
    # In a subshell that returns at once: the watcher is then no child of this shell, and
    # `wait -n` below, which counts the lanes, never mistakes its end for a finished run.
    ( scripts/fork_run.sh "$root/$src-seed$seed" "$k" "$dir" "${overrides[@]}" > "$dir.fork.log" 2>&1 < /dev/null &
      echo $! > "$dir.fork.pid" )
    echo "campaign: watching $root/$src-seed$seed for design $k, to fork $dir"
  done < "$queue"
}

# Whether line NAME SEED ($1 $2) ends before --until, by its estimate and a quarter more (paces
# vary with what shares the machine: hc-fear's three seeds ran at 137 to 366 episodes an
# hour); says why not.
fits_until() {
  local need left
  need=$(python3 scripts/campaign_status.py "$queue" --seconds "$1" "$2" --threads "$threads" 2> /dev/null) || need=""
  left=$((until_s - $(date +%s)))
  if [[ ! $need =~ ^[0-9]+$ ]]; then
    echo "campaign: $1-seed$2 skipped: nothing to size it by before --until (no pace, or its source is not finished); the queue started again runs it"
    return 1
  fi
  need=$((need + need / 4))
  if [ "$need" -gt "$left" ]; then
    echo "campaign: $1-seed$2 skipped: it needs about $((need / 60)) min, $((left / 60)) min are left before --until; the queue started again runs it"
    return 1
  fi
  echo "campaign: $1-seed$2 fits before --until: about $((need / 60)) min of $((left / 60))"
}

run_one() {
  local name=$1 config=$2 seed=$3; shift 3
  local dir=$root/$name-seed$seed
  local archive=docs/campaign/results/$name-seed$seed
  if [ -s "$dir/summary.json" ] || [ -s "$archive/summary.json" ]; then echo "campaign: $name-seed$seed done already, skipped"; return 0; fi
  # Queues share lines (seed3.queue's are design-bench's and design-choice's): one run
  # directory, one writer. The lock holds this lane's pid; a lock whose lane is gone is taken
  # over unless a live process still names the directory (a run orphaned by a killed campaign).
  local lock=$dir.lock
  if ! take_lock "$lock" "(run|resume|out) $dir( |\$)"; then
    echo "campaign: $name-seed$seed is being run by another campaign (pid $(cat "$lock/pid" 2> /dev/null || echo ?)), skipped"
    return 0
  fi
  # The lane is a subshell that ends with this line: its exit frees the lock.
  # shellcheck disable=SC2064 # the path now: $lock is local and gone when the trap runs
  trap "rm -rf $(printf %q "$lock")" EXIT
  if [ -n "$until_s" ] && ! fits_until "$name" "$seed"; then return 0; fi
  local resume=""
  case $config in
    retrain:*) retrain_one "$name" "$config" "$seed" "$@"; return 0 ;;
  esac
  case $config in
    fork:*)
      local spec=${config#fork:}
      local src=${spec%%:*} rest_k=${spec#*:}
      if [ ! -d "$dir" ] && [ ! -d "$root/$src-seed$seed" ] && [ -s "docs/campaign/results/$src-seed$seed/summary.json" ]; then
        regenerate_prefix "$src" "$seed" "${rest_k%%+*}" || return 1
      fi
      # The watcher started below copies the fork into $dir; wait for it (or its failure, or
      # the queue's stop: a lane is a subshell, so it learns of that from the flag file).
      until [ -d "$dir" ]; do
        if [ -e "$stopflag" ]; then echo "campaign: stopped waiting for the fork $dir" >&2; return 0; fi
        # (No pid file counts as a dead watcher: `kill -0 0` would ask about our own group.)
        local wpid
        wpid=$(cat "$dir.fork.pid" 2>/dev/null || true)
        if { [[ ! $wpid =~ ^[1-9][0-9]*$ ]] || ! kill -0 "$wpid" 2>/dev/null; } && [ ! -d "$dir" ]; then
          echo "campaign: FAILED $dir: the fork was not made (see $dir.fork.log)" >&2
          return 1
        fi
        sleep 10
      done
      resume=yes ;;
  esac
  if [ -z "$resume" ] && [ -e "$dir" ]; then
    if compgen -G "$dir/snapshots/snap-*" > /dev/null; then resume=yes; else mv "$dir" "$dir.partial-$(date +%s)"; fi
  fi
  if [ -n "$resume" ]; then
    echo "campaign: resume $dir ($(date -u +%H:%M:%S))"
    local t0=$SECONDS
    if RAYON_NUM_THREADS=$threads lane_exec "$bin" run --resume "$dir" --transport in-process > "$dir.summary.tmp" 2>> "$dir.log"; then
      archive_run "$dir" "$archive" "$t0"
    else
      echo "campaign: FAILED $dir after $((SECONDS - t0)) s (see $dir.log)" >&2
    fi
    return 0
  fi
  if ! ensure_init_population "$@"; then
    if [ -e "$stopflag" ]; then return 0; fi
    echo "campaign: FAILED $dir: its --init-population source cannot be had" >&2
    return 1
  fi
  case $config in
    random-only:*) config="${config#random-only:}+schedule.alternate=false" ;;
  esac
  if [[ $config == *+* ]]; then
    local base=${config%%+*} c=$root/configs/$name-seed$seed.toml
    local IFS=+
    # shellcheck disable=SC2086 # split the overrides on +
    python3 scripts/config_with.py "$base" ${config#*+} > "$c" || { echo "campaign: bad config $config" >&2; return 1; }
    unset IFS
    config=$c
  fi
  echo "campaign: start $dir ($(date -u +%H:%M:%S))"
  local t0=$SECONDS
  if RAYON_NUM_THREADS=$threads lane_exec "$bin" run --config "$config" --seed "$seed" --out "$dir" --transport in-process "$@" \
      > "$dir.summary.tmp" 2> "$dir.log"; then
    archive_run "$dir" "$archive" "$t0"
  else
    echo "campaign: FAILED $dir after $((SECONDS - t0)) s (see $dir.log)" >&2
  fi
}

# Ctrl-C or a TERM to this script stops the queue, not only the run in hand: every run below it
# gets SIGINT (it snapshots and exits; the lanes' subshells see their run end), a run that starts
# or hears it late gets it from its lane (lane_exec), and no further line starts. Signal this script's
# pid alone: `pkill -f campaign.sh` would also hit the lanes' subshells, which share its command
# line and die of a TERM, leaving their runs going.
descendants() { local c; for c in $(pgrep -P "$1"); do echo "$c"; descendants "$c"; done; }
stopping=0
# The processes signalled are listed (written whole, then renamed into place) before any is
# signalled: a lane whose run is not in the list knows the stop has not reached it (lane_exec).
# Only processes with a handler are signalled: a run without one yet would die of it.
stop_descendants() {
  local p caught=()
  for p in $(descendants $$); do catches_int "$p" && caught+=("$p"); done
  printf '%s\n' "${caught[@]}" > "$stopflag.signalled.tmp"
  mv "$stopflag.signalled.tmp" "$stopflag.signalled"
  for p in "${caught[@]}"; do kill -INT "$p" 2> /dev/null || true; done
}
rm -f "$stopflag" "$stopflag.signalled"
trap 'stopping=1; touch "$stopflag"; stop_descendants' INT TERM
start_fork_watchers
running=0
while read -r name config seed rest; do
  case $name in ''|'#'*) continue ;; esac
  [ "$stopping" = 0 ] || break
  # shellcheck disable=SC2086 # the flags are words
  run_one "$name" "$config" "$seed" $rest &
  running=$((running + 1))
  if [ "$running" -ge "$jobs" ]; then wait -n || true; running=$((running - 1)); fi
done < "$queue"
while [ "$(jobs -pr | wc -l)" -gt 0 ]; do wait || true; done
# Ends the watcher of pid file $1 and waits (up to 10 s) until it has gone: the queue's end
# leaves nothing of it running (a SIGTERM is delivered when the process next runs, which on a
# busy machine was after this script had exited).
end_watcher() {
  local pid
  pid=$(cat "$1" 2> /dev/null) || return 0
  [[ $pid =~ ^[1-9][0-9]*$ ]] || return 0
  kill "$pid" 2> /dev/null || return 0
  for _ in $(seq 50); do
    # Gone, or a zombie (dead, not yet reaped by init): not running.
    local state
    state=$(sed -E 's/.*\) ([A-Za-z]).*/\1/' "/proc/$pid/stat" 2> /dev/null) || return 0
    [ "$state" = Z ] && return 0
    sleep 0.2
  done
  echo "campaign: the fork watcher $pid did not end within 10 s of SIGTERM" >&2
}
if [ "$stopping" = 1 ]; then
  for f in $(fork_pidfiles); do
    if [ -s "$f" ]; then end_watcher "$f"; fi
  done
  echo "campaign: stopped; start the queue again to resume"
  exit 130
fi
# Watchers whose fork never came (a source that failed) would wait for ever.
for f in $(fork_pidfiles); do
  if [ -s "$f" ] && [ ! -d "${f%.fork.pid}" ]; then end_watcher "$f"; fi
done
echo "campaign: queue $queue finished"
