#!/usr/bin/env bash
# The test suite, as the README gives it: everything in release mode, since the learning tests
# train real agents (SAC and DDPG on Pendulum) and take minutes in a debug build.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test --workspace --release "$@"
