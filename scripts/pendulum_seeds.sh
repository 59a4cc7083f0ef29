#!/usr/bin/env bash
# Five-seed Pendulum study: for each seed, trains for 20,000 steps and reports the first step at
# which the mean return of the last 10 episodes exceeds -200, and the final mean.
#   usage: [PENDULUM_TAG=name] scripts/pendulum_seeds.sh [sac|ddpg] [extra `coadapt train` flags...]
# Writes runs/pendulum-seeds-<algo>[-<tag>]/seed<N>/ and .../summary.jsonl, and
# prints a Markdown table for docs/EXPERIMENTS.md.
set -euo pipefail
cd "$(dirname "$0")/.."
algo=${1:-sac}
shift || true
out=runs/pendulum-seeds-$algo${PENDULUM_TAG:+-$PENDULUM_TAG}
mkdir -p "$out"
: > "$out/summary.jsonl"
cargo build --release -q
for seed in 1 2 3 4 5; do
  ./target/release/coadapt train --env pendulum --algo "$algo" --steps 20000 --seed "$seed" \
    --target-return -200 --quiet --out "$out/seed$seed" "$@" | tee -a "$out/summary.jsonl"
done
echo
echo "| seed | first step with mean10 > -200 | mean10 at 20k | wall s |"
echo "|---|---|---|---|"
sed -E 's/.*"seed":([0-9]+).*"mean_return_last_10":([-0-9.e]+).*"first_step_reaching_target":([0-9a-z]+).*"wall_s":([0-9.]+).*/| \1 | \3 | \2 | \4 |/' "$out/summary.jsonl"
reached=$(grep -c '"first_step_reaching_target":[0-9]' "$out/summary.jsonl" || true)
echo
echo "$reached of 5 seeds reached -200 within 20,000 steps"
