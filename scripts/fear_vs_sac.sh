#!/usr/bin/env bash
# Does FEAR's learner learn one body as well as plain SAC? (issue 10, section 2.) For each seed:
# FEAR's schedule on the original HalfCheetah alone (one design, its first 3 episodes acting with
# the untrained population policy and training nothing, then 1000 individual updates after each
# episode) against `coadapt train` (SAC with the same settings, 100 random steps, then one update
# per step), both for EPISODES episodes of 1000 steps. Same networks, SAC settings and updates per
# collected step; FEAR updates in bursts after each episode, plain SAC after every step.
#
#   usage: scripts/fear_vs_sac.sh [EPISODES, default 30] [SEEDS..., default 1 2 3]
#
# Variants, to tell the causes of a difference apart (environment variables):
#   TAG=name        write to runs/fear-vs-sac-name/ instead
#   BASE=config     FEAR's base config (default configs/half-cheetah-reduced.toml); with
#   ROBOT=robot     the robot of plain SAC (default half-cheetah), e.g. the MuJoCo cheetah
#                   served by the bridge: BASE=configs/mujoco-half-cheetah-reduced.toml
#                   ROBOT=dm-env-rpc://127.0.0.1:50071
#   FEAR_SET="k=v ..."  config overrides for FEAR (scripts/config_with.py), e.g.
#                   "learner.sac.auto-alpha=true" or "learner.warmup-episodes=0"
#   SAC_FLAGS="..." extra `coadapt train` flags
#   ONLY=fear|sac   run one learner only
#   BIN=path        run this coadapt binary instead of building the checkout (e.g. a copy built
#                   before a change to the robot, to rerun the runs it made)
# Writes runs/fear-vs-sac/{fear,sac}-seedN/ and prints one line per run: the mean training
# return of the last 10 episodes, its maximum over the run (of the 10-episode mean), and, for
# FEAR, the last and best deterministic evaluation returns. Single-threaded, two runs at a time.
set -euo pipefail
cd "$(dirname "$0")/.."
episodes=${1:-30}
shift || true
if [ $# -gt 0 ]; then seeds=("$@"); else seeds=(1 2 3); fi
root=runs/fear-vs-sac${TAG:+-$TAG}
base=${BASE:-configs/half-cheetah-reduced.toml}
env=${ROBOT:-half-cheetah}
only=${ONLY:-both}
read -r -a fear_set <<< "${FEAR_SET:-}"
read -r -a sac_flags <<< "${SAC_FLAGS:-}"
mkdir -p "$root"
bin=$root/coadapt
if [ -n "${BIN:-}" ]; then
  cp "$BIN" "$bin.new" && mv "$bin.new" "$bin"
else
  cargo build --release -q -p coadapt
  cp target/release/coadapt "$bin.new" && mv "$bin.new" "$bin"
fi
cfg=$root/one-design.toml
python3 scripts/config_with.py "$base" \
  schedule.designs=1 "schedule.initial-designs=[[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]]" \
  "schedule.initial-episodes=$episodes" landscape-grid=0 ${fear_set[@]+"${fear_set[@]}"} > "$cfg"
for seed in "${seeds[@]}"; do
  [ "$only" = sac ] || [ -s "$root/fear-seed$seed/summary.json" ] || { rm -rf "$root/fear-seed$seed"; RAYON_NUM_THREADS=1 "$bin" run --config "$cfg" --seed "$seed" \
      --transport in-process --out "$root/fear-seed$seed" > "$root/fear-seed$seed.summary" 2> "$root/fear-seed$seed.log" \
      && mv "$root/fear-seed$seed.summary" "$root/fear-seed$seed/summary.json"; } &
  [ "$only" = fear ] || [ -s "$root/sac-seed$seed/summary.json" ] || { rm -rf "$root/sac-seed$seed"; RAYON_NUM_THREADS=1 "$bin" train --env "$env" --algo sac \
      ${sac_flags[@]+"${sac_flags[@]}"} --steps $((episodes * 1000)) --seed "$seed" --quiet --out "$root/sac-seed$seed" > "$root/sac-seed$seed.summary" 2> "$root/sac-seed$seed.log" \
      && mv "$root/sac-seed$seed.summary" "$root/sac-seed$seed/summary.json"; } &
  wait
done
python3 - "$root" "${seeds[@]}" <<'PY'
import csv, sys, statistics
root, seeds = sys.argv[1], sys.argv[2:]
def mean10(returns):
    return [statistics.mean(returns[max(0, i - 9):i + 1]) for i in range(len(returns))]
print("| seed | learner | mean return, last 10 episodes | best 10-episode mean | last / best evaluation (FEAR) |")
print("|---|---|---|---|---|")
for s in seeds:
    for kind in ("fear", "sac"):
        try:
            rows = list(csv.DictReader(open(f"{root}/{kind}-seed{s}/episodes.csv")))
        except FileNotFoundError:
            continue
        r = [float(x["return"]) for x in rows]
        m = mean10(r)
        ev = ""
        if kind == "fear":
            e = [float(x["eval_return"]) for x in rows if x["eval_return"]]
            ev = f"{e[-1]:.1f} / {max(e):.1f}" if e else ""
        print(f"| {s} | {kind} | {m[-1]:.1f} | {max(m):.1f} | {ev} |")
PY
