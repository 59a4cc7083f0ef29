# Sourced by scripts/campaign.sh (it uses the campaign's root, bin, threads and stopflag, and
# lane_exec): the lanes' locks, and the line kinds that start from another run: retraining a
# finished run's body, a fork of an archived source whose run directory is gone (its prefix run
# again), and a line starting from an archived run's population networks (the run again).
# shellcheck shell=bash

# The MuJoCo bridge of the campaign listened on 127.0.0.1:50061 until 2026-12-03: the port that
# `coadapt serve` and a run's design service take by default, so a user serving a MuJoCo run's
# designs beside its bridge got "address already in use". It listens on MUJOCO_BRIDGE now
# (127.0.0.1:50071 unless scripts/mujoco_lane.sh says otherwise). An archived config naming the
# old address is the same robot: what is run here from it talks to the bridge where it is now.
old_bridge=dm-env-rpc://127.0.0.1:50061
bridge_here() {
  if [ "$1" = "$old_bridge" ]; then echo "dm-env-rpc://${MUJOCO_BRIDGE:-127.0.0.1:50071}"; else echo "$1"; fi
}

# The env of CONFIG (empty if it names none).
env_of() {
  python3 -c 'import sys, tomllib; print(tomllib.load(open(sys.argv[1], "rb")).get("env", ""))' "$1"
}

# CONFIG copied to OUT, its env through bridge_here.
config_here() {
  local config=$1 out=$2 env
  env=$(env_of "$config") || return 1
  if [ "$(bridge_here "$env")" != "$env" ]; then
    python3 scripts/config_with.py "$config" "env=\"$(bridge_here "$env")\"" > "$out"
  else
    cp "$config" "$out"
  fi
}

# `NAME retrain:SRC:WHICH SEED [coadapt train flags]`: the body apart from the controller. Waits
# for SRC-seedSEED to finish, picks its best exploitation (WHICH = exploit), exploration
# (explore) or any (best) design (scripts/pick_design.py), and trains plain SAC on it from
# scratch with train seeds 1 and 2 (`coadapt train`, 30 episodes unless the flags say
# --steps), into NAME-seedSEED/train-seed{1,2}.
retrain_one() {
  local name=$1 config=$2 seed=$3; shift 3
  local spec=${config#retrain:}
  local src=${spec%%:*} which=${spec#*:}
  local dir=$root/$name-seed$seed archive=docs/campaign/results/$name-seed$seed
  local srcdir=docs/campaign/results/$src-seed$seed
  [ -s "$srcdir/summary.json" ] || srcdir=$root/$src-seed$seed
  until [ -s "$srcdir/summary.json" ]; do
    if [ -e "$stopflag" ]; then echo "campaign: stopped waiting for $srcdir" >&2; return 0; fi
    sleep 30
  done
  local design env
  design=$(python3 scripts/pick_design.py "$srcdir" "$which") || { echo "campaign: FAILED $dir: no design to retrain" >&2; return 1; }
  env=$(env_of "$srcdir/config.toml")
  env=$(bridge_here "$env")
  mkdir -p "$dir"
  echo "campaign: start $dir: SAC from scratch on $env, $which design of $srcdir ($design) ($(date -u +%H:%M:%S))"
  local t0=$SECONDS k steps=(--steps 30000) a
  for a in "$@"; do [ "$a" = --steps ] && steps=(); done
  for k in 1 2; do
    if [ -s "$dir/train-seed$k/summary.json" ]; then continue; fi
    rm -rf "$dir/train-seed$k"
    if RAYON_NUM_THREADS=$threads lane_exec "$bin" train --env "$env" --algo sac --design "$design" "${steps[@]}" --seed "$k" --quiet \
        --out "$dir/train-seed$k" "$@" > "$dir/train-seed$k.summary" 2>> "$dir.log"; then
      # Stopped by Ctrl-C (exit 0, "interrupted": true): not done; trained again from the start.
      if grep -Eq '"interrupted": *true' "$dir/train-seed$k.summary"; then
        echo "campaign: stopped $dir train seed $k before its end (not archived)" >&2
        return 0
      fi
      mv "$dir/train-seed$k.summary" "$dir/train-seed$k/summary.json"
    else
      echo "campaign: FAILED $dir train seed $k (see $dir.log)" >&2
      return 1
    fi
  done
  python3 - "$dir" "$srcdir" "$which" "$design" > "$dir/summary.json" <<'PY'
import csv, json, statistics, sys
d, src, which, design = sys.argv[1:5]
out = {"source": src, "which": which, "design": [float(x) for x in design.split(",")], "seeds": {}}
for k in (1, 2):
    r = [float(x["return"]) for x in csv.DictReader(open(f"{d}/train-seed{k}/episodes.csv"))]
    out["seeds"][str(k)] = {"episodes": len(r), "last10_mean_return": statistics.mean(r[-10:]), "best10_mean_return": max(statistics.mean(r[max(0, i - 9):i + 1]) for i in range(len(r)))}
print(json.dumps(out))
PY
  mkdir -p "$archive"
  cp "$dir/summary.json" "$archive/"
  for k in 1 2; do mkdir -p "$archive/train-seed$k"; cp "$dir/train-seed$k"/{summary.json,config.toml,episodes.csv} "$archive/train-seed$k/"; done
  echo "campaign: done  $dir in $((SECONDS - t0)) s: $(cat "$dir/summary.json")"
}

# Takes the lock directory LOCK for this lane (its pid inside), or returns 1 while another holds
# it: a lane still alive, or, given PATTERN, a live process whose command line matches it (a run
# orphaned by a campaign killed outright). A lock left by neither is taken over.
take_lock() {
  local lock=$1 pattern=${2:-} holder
  if ! mkdir "$lock" 2> /dev/null; then
    holder=$(cat "$lock/pid" 2> /dev/null || true)
    if [[ $holder =~ ^[1-9][0-9]*$ ]] && kill -0 "$holder" 2> /dev/null; then return 1; fi
    if [ -n "$pattern" ] && pgrep -f -- "$pattern" > /dev/null; then return 1; fi
    rm -rf "$lock"
    mkdir "$lock" 2> /dev/null || return 1
  fi
  echo "$BASHPID" > "$lock/pid"
}

# A run directory here that is the same run as archived SRC-seedSEED over its first K designs,
# with a snapshot to go on from, so that running SRC again need not start over: another line's
# run of the same config and seed (transfer-src-seedS is hc-fear-seedS, all 260 rows equal) whose
# archive holds the same rows over those designs, whose config runs K designs, which no lane
# holds, and whose newest snapshot is at or before design K. Prints its path. The rows of the
# run that results are checked against SRC's archive all the same (regenerate_prefix).
same_run() {
  local src=$1 seed=$2 k=$3 d
  for d in "$root"/*-seed"$seed"; do
    if [ ! -d "$d" ] || [ "$d" = "$root/$src-seed$seed" ] || [ -d "$d.lock" ]; then continue; fi
    compgen -G "$d/snapshots/snap-*" > /dev/null || continue
    if python3 - "$d" "docs/campaign/results/$(basename "$d")" "docs/campaign/results/$src-seed$seed" "$k" 2> /dev/null <<'PY'
import csv, glob, json, sys, tomllib
d, twin, src, k = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
cols = ("design", "episode", "return", "eval_return")
def rows(p):
    return [tuple(r[c] for c in cols) for r in csv.DictReader(open(p)) if int(r["design"]) < k]
a, b = rows(f"{twin}/episodes.csv"), rows(f"{src}/episodes.csv")
designs = tomllib.load(open(f"{d}/config.toml", "rb"))["schedule"]["designs"]
newest = sorted(glob.glob(f"{d}/snapshots/snap-*"))[-1]
at = json.load(open(f"{newest}/state.json"))["values"]["progress"]["design"]
sys.exit(0 if a and a == b and designs == k and at <= k else 1)
PY
    then
      echo "$d"
      return 0
    fi
  done
  return 1
}

# A fork's source that is archived but whose run directory is gone (runs/ of another machine,
# or cleared): its first K designs are run again from the archived config into SRC.prefix, the
# rows checked against the archive's, and only then moved to SRC's place for the watchers to
# fork. A binary that does not reproduce the archived rows would give forks that do not share
# the archived run's prefix, and the paired comparisons would be void: refused. One lane runs
# it (a lock directory); the others wait for it as for any source.
regenerate_prefix() {
  local src=$1 seed=$2 k=$3
  local srcdir=$root/$src-seed$seed srcarch=docs/campaign/results/$src-seed$seed
  if [ -d "$srcdir" ]; then return 0; fi
  local tmp=$srcdir.prefix
  local lock=$srcdir.prefix.lock
  take_lock "$lock" || return 0
  local here=$root/configs/$src-seed$seed.prefix.toml
  mkdir -p "$root/configs"
  config_here "$srcarch/config.toml" "$here" || { rm -rf "$lock"; return 1; }
  local mode=(--config "$here" --seed "$seed" --designs "$k" --out "$tmp")
  if compgen -G "$tmp/snapshots/snap-*" > /dev/null; then
    mode=(--resume "$tmp")
  else
    rm -rf "$tmp"
    local twin
    if twin=$(same_run "$src" "$seed" "$k"); then
      cp -a "$twin" "$tmp"
      mode=(--resume "$tmp")
      echo "campaign: $tmp starts from a copy of $twin, the same run (archived rows equal over its first $k designs), at its newest snapshot"
    fi
  fi
  echo "campaign: $srcdir is archived but gone: running its first $k designs again for the runs that start from it, into $tmp ($(date -u +%H:%M:%S))"
  if ! RAYON_NUM_THREADS=$threads lane_exec "$bin" run "${mode[@]}" --transport in-process > "$tmp.summary" 2>> "$tmp.log"; then
    rm -rf "$lock"
    echo "campaign: FAILED $tmp (see $tmp.log)" >&2
    return 1
  fi
  rm -rf "$lock"
  if grep -Eq '"interrupted": *true' "$tmp.summary"; then
    echo "campaign: stopped $tmp before design $k (the queue started again resumes it)" >&2
    return 0
  fi
  if ! python3 - "$tmp/episodes.csv" "$srcarch/episodes.csv" "$k" <<'PY'
import csv, sys
new, old, k = sys.argv[1], sys.argv[2], int(sys.argv[3])
cols = ("design", "episode", "return", "eval_return")
a = [tuple(r[c] for c in cols) for r in csv.DictReader(open(new))]
b = [tuple(r[c] for c in cols) for r in csv.DictReader(open(old)) if int(r["design"]) < k]
for i, (x, y) in enumerate(zip(a, b)):
    if x != y:
        sys.exit(f"row {i + 1}: {dict(zip(cols, x))} here, {dict(zip(cols, y))} archived")
if len(a) != len(b):
    sys.exit(f"{len(a)} rows here, {len(b)} archived before design {k}")
PY
  then
    mv "$tmp" "$tmp-mismatch-$(date +%s)"
    echo "campaign: FAILED $srcdir: this binary does not reproduce the archived first $k designs of $srcarch (above); its forks would not share that run's prefix" >&2
    return 1
  fi
  # The archived config (its whole schedule) for the forks: schedule.designs may change on resume.
  config_here "$srcarch/config.toml" "$tmp/config.toml" || return 1
  mv "$tmp" "$srcdir"
  echo "campaign: $srcdir: its first $k designs again, row for row the archived ones"
}

# A line that starts from another run's population networks (`--init-population
# runs/campaign/SRC-seedS`) whose run directory is gone but archived: the whole source is run
# again (all its designs, checked row for row as above) before the line starts. Returns 1 when it
# cannot be had.
ensure_init_population() {
  local prev="" a src
  for a in "$@"; do
    if [ "$prev" = --init-population ]; then
      src=${a%/}
      if [ ! -d "$src" ] && [[ $src == "$root"/*-seed* ]]; then
        local run=${src#"$root"/}
        local name=${run%-seed*} s=${run##*-seed}
        local arch=docs/campaign/results/$run
        [ -s "$arch/summary.json" ] || { echo "campaign: --init-population $src: no such run, archived or not" >&2; return 1; }
        local n
        n=$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["designs"])' "$arch/summary.json") || return 1
        until [ -d "$src" ]; do
          [ -e "$stopflag" ] && return 1
          regenerate_prefix "$name" "$s" "$n" || return 1
          # Another lane holds the lock and runs it: wait for it.
          [ -d "$src" ] || sleep 10
        done
      fi
    fi
    prev=$a
  done
}
