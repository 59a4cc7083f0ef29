#!/usr/bin/env bash
# Soak: a local fleet (`coadapt run`, separate processes) of N actors for M minutes on a run
# that does not end by itself, sampled every S seconds: resident memory (VmRSS) and its peak
# (VmHWM) of every process, its open file descriptors, and /dev/shm use; then Ctrl-C and a
# summary of the first and last samples per role. Growth that does not level off is a leak.
#
#   usage: scripts/soak.sh [--transport shm|grpc] [--actors 8] [--minutes 30] [--every 30] [--flow async|lock-step]
#                          [--episodes-per-design 2] [--out DIR]
#
# --flow lock-step: one episode out at a time (the other actors wait on their polls), about one
# core; async (the default): every actor busy. --episodes-per-design: many episodes per design
# tell growth per episode from growth per design.
#
# Writes DIR/samples.csv (time_s,role,pid,rss_kb,hwm_kb,fds,shm_kb) and DIR/summary.txt; the run
# itself goes to DIR/run. Uses the release binary (built first).
set -euo pipefail
cd "$(dirname "$0")/.."
transport=shm actors=8 minutes=30 every=30 flow=async per_design=2 out=""
while [ $# -gt 0 ]; do
  case $1 in
    --transport) transport=$2; shift 2 ;;
    --actors) actors=$2; shift 2 ;;
    --minutes) minutes=$2; shift 2 ;;
    --every) every=$2; shift 2 ;;
    --flow) flow=$2; shift 2 ;;
    --episodes-per-design) per_design=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    -h|--help) sed -n 2,17p "$0"; exit 0 ;;
    *) echo "soak: unknown argument $1" >&2; exit 2 ;;
  esac
done
case $transport in shm|grpc) ;; *) echo "soak: --transport must be shm or grpc" >&2; exit 2 ;; esac
out=${out:-runs/soak-$transport-$(date -u +%Y%m%dT%H%M%S)}
mkdir -p "$out"
cargo build --release -q -p coadapt
bin=target/release/coadapt
# The tiny protocol, made endless (many designs), async flow so every actor is busy, small
# snapshots every 5 episodes.
python3 scripts/config_with.py configs/half-cheetah-tiny.toml schedule.designs=100000 "flow.mode=\"$flow\"" \
  schedule.episodes-per-design="$per_design" \
  learner.population-capacity=100000 learner.species-capacity=20000 \
  snapshot.every-episodes=5 landscape-grid=0 > "$out/soak.toml"
RAYON_NUM_THREADS=1 "$bin" run --config "$out/soak.toml" --out "$out/run" --transport "$transport" --actors "$actors" \
  > "$out/stdout.txt" 2> "$out/stderr.txt" &
sup=$!
echo "time_s,role,pid,rss_kb,hwm_kb,fds,shm_kb" > "$out/samples.csv"
start=$SECONDS
sample() {
  local t=$((SECONDS - start)) shm
  shm=$(du -sk /dev/shm 2>/dev/null | cut -f1)
  for pid in $(pgrep -P "$sup" || true); do
    [ -r "/proc/$pid/status" ] || continue
    local role rss hwm fds
    role=$(tr '\0' ' ' < "/proc/$pid/cmdline" | awk '{print $2}')
    [ "$role" = actor ] && role="actor-$(tr '\0' ' ' < "/proc/$pid/cmdline" | sed -n 's/.*--id \([0-9]*\).*/\1/p')"
    rss=$(awk '/^VmRSS/ {print $2}' "/proc/$pid/status")
    hwm=$(awk '/^VmHWM/ {print $2}' "/proc/$pid/status")
    fds=$(find "/proc/$pid/fd" -mindepth 1 -maxdepth 1 2>/dev/null | wc -l)
    echo "$t,$role,$pid,$rss,$hwm,$fds,$shm" >> "$out/samples.csv"
  done
}
sleep 20
while [ $((SECONDS - start)) -lt $((minutes * 60)) ]; do
  kill -0 "$sup" 2>/dev/null || { echo "soak: the run ended early (see $out/stderr.txt)" >&2; break; }
  sample
  sleep "$every"
done
sample
kill -INT "$sup" 2>/dev/null || true
wait "$sup" || true
episodes=$(($(wc -l < "$out/run/episodes.csv") - 1))
python3 - "$out" "$episodes" "$minutes" "$transport" "$actors" <<'EOF' | tee "$out/summary.txt"
import csv, sys, collections
out, episodes, minutes, transport, actors = sys.argv[1:]
rows = list(csv.DictReader(open(f"{out}/samples.csv")))
by = collections.defaultdict(list)
for r in rows:
    by[r["role"]].append(r)
print(f"soak: {transport}, {actors} actors, {minutes} min, {episodes} episodes, {len(rows)} samples; first and last sample per process")
print("| process | RSS first -> last (MB) | peak RSS last (MB) | fds first -> last |")
print("|---|---|---|---|")
for role in sorted(by, key=lambda r: (r != "learner", r != "optimizer", len(r), r)):
    s = by[role]
    a, b = s[0], s[-1]
    mb = lambda kb: f"{int(kb) / 1024:.1f}"
    print(f"| {role} | {mb(a['rss_kb'])} -> {mb(b['rss_kb'])} | {mb(b['hwm_kb'])} | {a['fds']} -> {b['fds']} |")
shm = [int(r["shm_kb"]) for r in rows]
print(f"/dev/shm: {shm[0] / 1024:.1f} MB first, {shm[-1] / 1024:.1f} MB last, {max(shm) / 1024:.1f} MB most")
EOF
