#!/usr/bin/env bash
# Builds the design benchmark's campaign binary (docs/EXPERIMENTS.md 5.13, "The binary"): the tree
# of 77e8fa3 with 131268b's change to crates/nn/src/simd.rs (ReLU's backward pass with AVX2), the
# build every run of the benchmark since 2026-12-02 11:50 went through (the same rows as 77e8fa3,
# bit for bit). A machine without runs/ builds it again with this script; the campaign checks its
# rows against the archive wherever it runs an archived prefix again.
#
#   usage: scripts/campaign_bin.sh   (prints the binary's path: runs/bin/coadapt-77e8fa3-avx2)
#   then:  scripts/lanes.sh --until TIME "docs/campaign/A.queue ..." ... with BIN= that path
# The worktree (runs/wt-campaign-bin) and the build (runs/target-campaign-bin, or
# $CARGO_TARGET_DIR) stay in runs/, beside the snapshots; a second call reuses them.
set -euo pipefail
cd "$(dirname "$0")/.."
base=77e8fa3
patch=131268b
out=runs/bin/coadapt-$base-avx2
wt=runs/wt-campaign-bin
mkdir -p runs/bin
if [ -x "$out" ]; then echo "$out"; exit 0; fi
git cat-file -e "$base^{commit}" 2> /dev/null && git cat-file -e "$patch^{commit}" 2> /dev/null \
  || { echo "campaign_bin: this checkout lacks commit $base or $patch (a shallow clone? git fetch --unshallow)" >&2; exit 1; }
if [ ! -d "$wt" ]; then
  git worktree prune
  git worktree add -q --detach "$wt" "$base" >&2
fi
# The tree of $base with only $patch's change to simd.rs: the same file every time.
git -C "$wt" checkout -q --detach "$base"
git -C "$wt" checkout -q -- .
git show "$patch" -- crates/nn/src/simd.rs | git -C "$wt" apply
echo "campaign_bin: building $base + $patch's simd.rs in $wt" >&2
target=${CARGO_TARGET_DIR:-$PWD/runs/target-campaign-bin}
CARGO_TARGET_DIR=$target cargo build -q --release -p coadapt --manifest-path "$wt/Cargo.toml" >&2
cp "$target/release/coadapt" "$out.tmp" && mv "$out.tmp" "$out"
echo "$out"
