#!/usr/bin/env bash
# Create .venv-peers (repo root) with CPU PyTorch + numpy for the peer benchmarks.
#
# PyPI only has CUDA builds of torch for linux/x86_64, whose dependencies are
# several GB of nvidia-*/cuda-* wheels (and download.pytorch.org's CPU wheels
# are not reachable here).  So: install the pinned torch wheel with --no-deps
# plus its pure-python deps, then build tiny stub libraries for the CUDA .so
# files torch links against (cuda_stubs.py; needs cc and readelf).
# Idempotent: a second run only re-checks the environment.
#   usage: bench/peers/setup.sh            torch, sim and transport peers
#          bench/peers/setup.sh transport  only what bench/peers/transport_grpc.py needs (no torch)
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
VENV="${VENV_PEERS:-$ROOT/.venv-peers}"
PY="${PYTHON:-python3}"
REQ="$HERE/requirements.txt"
TORCH_VERSION="$(sed -n 's/^torch==//p' "$REQ")"

check() {
    "$VENV/bin/python" - "$TORCH_VERSION" <<'EOF'
import sys, importlib.metadata as md
import numpy, torch
assert torch.__version__.split("+")[0] == sys.argv[1], torch.__version__
x = torch.randn(3) @ torch.randn(3)
assert not torch.cuda.is_available()
gpu = [d.metadata["Name"] for d in md.distributions()
       if d.metadata["Name"].lower().startswith(("nvidia-", "cuda-", "triton"))]
assert not gpu, gpu
print("torch", torch.__version__, "numpy", numpy.__version__, "OK")
EOF
}

sim_peer() {
    # MuJoCo + gymnasium for bench/peers/sim_mujoco.py; ordinary wheels with their dependencies.
    "$VENV/bin/python" -c 'import gymnasium, mujoco' 2>/dev/null \
        || "$VENV/bin/python" -m pip install --quiet --only-binary=:all: -r "$HERE/requirements-sim.txt"
}

transport_peer() {
    # grpcio + grpcio-tools for bench/peers/transport_grpc.py; ordinary wheels with their dependencies.
    "$VENV/bin/python" - "$HERE/requirements-transport.txt" 2>/dev/null <<'EOF' \
        || "$VENV/bin/python" -m pip install --quiet --only-binary=:all: -r "$HERE/requirements-transport.txt"
import sys, importlib.metadata as md
for line in open(sys.argv[1]):
    line = line.split("#")[0].strip()
    if line:
        name, version = line.split("==")
        assert md.version(name) == version, (name, md.version(name), version)
EOF
}

if [ "${1:-}" = transport ]; then
    # Only the transport peer: no torch needed (a later full run adds it to the same venv).
    [ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
    transport_peer
    exit 0
fi

if [ -x "$VENV/bin/python" ] && check 2>/dev/null; then
    sim_peer
    transport_peer
    exit 0
fi

for tool in cc readelf; do
    command -v "$tool" >/dev/null || { echo "setup.sh: '$tool' is required (apt-get install gcc binutils)" >&2; exit 1; }
done

[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install --quiet --no-deps --only-binary=:all: -r "$REQ"
TORCH_LIB="$("$VENV/bin/python" -c 'import importlib.util, os; print(os.path.join(os.path.dirname(importlib.util.find_spec("torch").origin), "lib"))')"
"$VENV/bin/python" "$HERE/cuda_stubs.py" "$TORCH_LIB"
check
sim_peer
transport_peer
