#!/usr/bin/env bash
# Runs `coadapt latent` experiments one after the other (issue 15's figures), single-threaded.
#
#   usage: scripts/latent_campaign.sh NAME "FLAGS" [NAME "FLAGS" ...]
#
# Each NAME runs `coadapt latent --config configs/latent/half-cheetah.toml FLAGS --out
# runs/latent/NAME` (stdout: its JSON summary to runs/latent/NAME.json, stderr to
# runs/latent/NAME.log) unless runs/latent/NAME.json exists; a finished run's small files
# (config.toml, episodes.csv, plots/returns.svg, the summary) are copied to
# docs/latent/results/NAME/ to be committed. Set CONFIG to use another base config. A NAME
# whose run directory was left by a stopped campaign goes on with --resume (its finished runs
# kept; one that cannot be resumed is moved aside and started again). A configuration too long
# for one session runs in pieces, one seed each (NAME pieces/x-s3, FLAGS "... --runs 1 --seed
# 3"), each committed as it ends; scripts/merge_latent.py joins them.
set -euo pipefail
cd "$(dirname "$0")/.."
config=${CONFIG:-configs/latent/half-cheetah.toml}
bin=runs/latent/coadapt
# A lane started without CONFIG once ran the pixel HalfCheetah under a dmc-* name; refuse that.
for ((i = 1; i <= $#; i += 2)); do
  case "${!i}" in *dmc-*) case "$config" in *dmc*) ;; *)
    echo "latent: ${!i} names DM Control but CONFIG is $config (set CONFIG=configs/latent/dmc-cheetah.toml)" >&2
    exit 2 ;; esac ;; esac
done
mkdir -p runs/latent
# Embeddings committed from earlier sessions (docs/latent/embeddings/, built by `coadapt latent
# --embed-only`, deterministic given the config) are restored instead of built again.
for e in docs/latent/embeddings/*.safetensors; do
  [ -e "$e" ] && [ ! -e "runs/latent/$(basename "$e")" ] && cp "$e" "${e%.safetensors}.csv" runs/latent/ 2>/dev/null || true
done
[ -x "$bin" ] || { cargo build --release -q -p coadapt && cp target/release/coadapt "$bin"; }
while [ $# -ge 2 ]; do
  name=$1 flags=$2; shift 2
  out=runs/latent/$name
  mkdir -p "$(dirname "$out")"   # NAME may hold a folder: pieces/NAME-s3
  if [ -s "$out.json" ] || [ -s "docs/latent/results/$name/summary.json" ]; then echo "latent: $name done already"; continue; fi
  resume=""
  if [ -s "$out/episodes.csv" ]; then
    resume="--resume"
  elif [ -e "$out" ]; then
    mv "$out" "$out.partial-$(date +%s)"
  fi
  echo "latent: start $name ($(date -u +%H:%M:%S)) --config $config $flags $resume"
  # shellcheck disable=SC2086 # FLAGS split into words
  if RAYON_NUM_THREADS=1 "$bin" latent --config "$config" $flags --out "$out" $resume > "$out.json.tmp" 2>> "$out.log"; then
    mv "$out.json.tmp" "$out.json"
    mkdir -p "docs/latent/results/$name"
    cp "$out/config.toml" "$out/episodes.csv" "$out/plots/returns.svg" "docs/latent/results/$name/"
    cp "$out.json" "docs/latent/results/$name/summary.json"
    echo "latent: done $name ($(date -u +%H:%M:%S)): $(cat "$out.json")"
  else
    echo "latent: FAILED $name (see $out.log)" >&2
  fi
done
