#!/usr/bin/env bash
# Issue 31 section 2: does exploring through a learned design-dependent action space (thesis
# 6.2) make SAC more sample-efficient on bodies the action space never saw?
#
#   usage: [BIN=coadapt] scripts/latent_exploration.sh [-n DESIGNS] [-s SEEDS] [-t STEPS] [-b BETA]
#                                                      [-u UPDATES] [-p f32|bf16] [-d K] [-S SEED]
#                                                      SRC_RUN NAME
#
# SRC_RUN: a finished co-adaptation (the action space learns from its population replay, e.g.
# runs/campaign/as-hc-50x8-seed1); not needed once NAME's action space is archived. Steps, each
# skipped when its output is already there, so the script resumes where it stopped, on this
# machine or another:
# 1. `coadapt action-space SRC_RUN --out SRC_RUN/action-space` (UPDATES Adam updates, 20000),
#    its weights, figures, summary and loss and SRC_RUN's config.toml archived in
#    docs/campaign/results/latent-exploration/NAME/action-space/;
# 2. DESIGNS new designs (3), uniform in the robot's box from a fixed seed (none is one of the
#    run's: the run chose from a continuum);
# 3. per design and seed (1..SEEDS, 3): `coadapt train --algo sac` on that body for STEPS steps
#    (30000) twice, exploring through the action space (`--latent-exploration`, beta BETA, 0.5)
#    and with SAC's own Gaussian, into runs/latent-exploration/NAME/{latent,sac}-d<k>-seed<s>;
#    both arms with the products of -p (bf16 by default: about 1.6-1.9x the f32 update rate
#    on a CPU with AVX-512 BF16, f32 products elsewhere; BENCHMARKS.md "Mixed precision");
# 4. each finished pair's small files (summary.json, config.toml, episodes.csv; both arms at once,
#    when the second ends) copied to
#    docs/campaign/results/latent-exploration/NAME/ to be committed, with designs.json.
# -d K runs design K's pairs only, -S SEED seed SEED's only: two lanes on two cores take pairs
# of their own (after the action space and designs.json are archived: let one lane write them
# first).
# Then `python3 scripts/latent_exploration_report.py docs/campaign/results/latent-exploration/NAME`
# prints episodes to a return, paired by design and seed.
set -euo pipefail
cd "$(dirname "$0")/.."
designs=3 seeds=3 steps=30000 beta=0.5 updates=20000 precision=bf16 only="" only_seed=""
while getopts "n:s:t:b:u:p:d:S:" o; do
  case $o in
    n) designs=$OPTARG ;; s) seeds=$OPTARG ;; t) steps=$OPTARG ;; b) beta=$OPTARG ;; u) updates=$OPTARG ;;
    p) precision=$OPTARG ;; d) only=$OPTARG ;; S) only_seed=$OPTARG ;;
    *) echo "usage: scripts/latent_exploration.sh [-n DESIGNS] [-s SEEDS] [-t STEPS] [-b BETA] [-u UPDATES] [-p f32|bf16] [-d K] [-S SEED] SRC_RUN NAME" >&2; exit 2 ;;
  esac
done
shift $((OPTIND - 1))
for v in designs seeds steps updates; do
  [[ ${!v} =~ ^[1-9][0-9]*$ ]] || { echo "latent_exploration: $v must be a positive whole number, not '${!v}'" >&2; exit 2; }
done
if [ -n "$only" ] && ! { [[ $only =~ ^[1-9][0-9]*$ ]] && [ "$only" -le "$designs" ]; }; then
  echo "latent_exploration: -d takes a design number from 1 to $designs, not '$only'" >&2; exit 2
fi
if [ -n "$only_seed" ] && ! { [[ $only_seed =~ ^[1-9][0-9]*$ ]] && [ "$only_seed" -le "$seeds" ]; }; then
  echo "latent_exploration: -S takes a seed from 1 to $seeds, not '$only_seed'" >&2; exit 2
fi
src=${1:?usage: scripts/latent_exploration.sh [options] SRC_RUN NAME}
name=${2:?usage: scripts/latent_exploration.sh [options] SRC_RUN NAME}
bin=${BIN:-target/release/coadapt}
[ -x "$bin" ] || { echo "latent_exploration: no coadapt binary at $bin (cargo build --release, or BIN=...)" >&2; exit 2; }
out=runs/latent-exploration/$name
archive=docs/campaign/results/latent-exploration/$name
space=$archive/action-space/action_space.safetensors
# The learned action space is archived with the comparison (about 50 KB): a later session, on a
# machine without SRC_RUN's replay, goes on from it (run directories do not outlive a machine).
if [ ! -s "$space" ]; then
  [ -s "$src/config.toml" ] || { echo "latent_exploration: $src has no config.toml: not a run directory (and $space is not archived yet)" >&2; exit 2; }
  if [ ! -s "$src/action-space/action_space.safetensors" ]; then
    echo "latent_exploration: learning the action space of $src ($updates updates)" >&2
    RAYON_NUM_THREADS=${RAYON_NUM_THREADS:-1} "$bin" action-space "$src" --out "$src/action-space" --updates "$updates" > /dev/null
  fi
  mkdir -p "$archive/action-space"
  cp "$src/config.toml" "$archive/action-space/source-config.toml"
  cp "$src/action-space"/{summary.json,loss.csv,latent_plane.svg,decoded_grid.svg} "$archive/action-space/"
  cp "$src/action-space/action_space.safetensors" "$space.new" && mv "$space.new" "$space"
fi
mkdir -p "$out"

env=$(python3 -c 'import sys, tomllib; print(tomllib.load(open(sys.argv[1], "rb"))["env"])' "$archive/action-space/source-config.toml")
if [ ! -s "$archive/designs.json" ]; then
  python3 - "$env" "$designs" > "$archive/designs.json" <<'PY'
import json, random, sys
sys.path.insert(0, "scripts")
from campaign_report import BOUNDS
env, n = sys.argv[1], int(sys.argv[2])
if env not in BOUNDS:
    raise SystemExit(f"latent_exploration: no design box known for {env} (scripts/campaign_report.py BOUNDS)")
low, high = BOUNDS[env]
rng = random.Random(31)  # issue 31: the same new bodies every time
print(json.dumps({"env": env, "designs": [[round(rng.uniform(l, h), 4) for l, h in zip(low, high)] for _ in range(n)]}))
PY
fi

for k in $(seq 1 "$designs"); do
  if [ -n "$only" ] && [ "$k" != "$only" ]; then continue; fi
  design=$(python3 -c 'import json, sys; print(",".join(map(str, json.load(open(sys.argv[1]))["designs"][int(sys.argv[2]) - 1])))' "$archive/designs.json" "$k")
  for s in $(seq 1 "$seeds"); do
    if [ -n "$only_seed" ] && [ "$s" != "$only_seed" ]; then continue; fi
    for arm in latent sac; do
      dir=$out/$arm-d$k-seed$s
      if [ -s "$archive/$arm-d$k-seed$s/summary.json" ] || [ -s "$dir/summary.json" ]; then continue; fi
      flags=()
      if [ "$arm" = latent ]; then flags=(--latent-exploration "$space" --latent-beta "$beta"); fi
      rm -rf "$dir"
      echo "latent_exploration: $arm, design $k ($design), seed $s ($(date -u +%H:%M:%S))" >&2
      RAYON_NUM_THREADS=${RAYON_NUM_THREADS:-1} "$bin" train --env "$env" --algo sac --design "$design" --steps "$steps" \
        --seed "$s" --precision "$precision" --quiet --out "$dir" "${flags[@]}" > "$dir.summary" 2>> "$out/log.txt"
      # Ctrl-C stops coadapt train with exit 0 and "interrupted": true: not a finished run.
      if grep -Eq '"interrupted": *true' "$dir.summary"; then
        echo "latent_exploration: stopped during $arm, design $k, seed $s (not archived; run again to go on)" >&2
        exit 130
      fi
      mv "$dir.summary" "$dir/summary.json"
    done
    # The pair is archived whole, when both arms have ended, so that the archive (and a commit
    # made meanwhile) never holds half a pair.
    for arm in latent sac; do
      dir=$out/$arm-d$k-seed$s
      if [ -s "$archive/$arm-d$k-seed$s/summary.json" ]; then continue; fi
      mkdir -p "$archive/$arm-d$k-seed$s"
      # summary.json last: it is what marks an arm archived (the skips above), so a copy cut
      # short leaves the arm to be copied again.
      cp "$dir"/{config.toml,episodes.csv} "$archive/$arm-d$k-seed$s/"
      cp "$dir/summary.json" "$archive/$arm-d$k-seed$s/summary.json"
    done
  done
done
echo "latent_exploration: $name done; python3 scripts/latent_exploration_report.py $archive" >&2
