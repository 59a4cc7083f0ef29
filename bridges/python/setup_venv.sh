#!/usr/bin/env bash
# Creates (or updates) the Python virtual environment of the coadapt bridge.
#
#   bridges/python/setup_venv.sh [--dmc] VENV_DIR
#
# - creates VENV_DIR with `python3 -m venv` when it does not exist;
# - installs the pinned requirements.txt, wheels only (--only-binary=:all:);
#   with --dmc (or COADAPT_BRIDGE_DMC=1) requirements-dmc.txt instead: the same pins plus
#   dm_control 1.0.50 for `coadapt-gym-serve --dmc cheetah-run`, with MuJoCo 3.17.0 instead of
#   4.0.0 (dm_control needs it). Headless rendering also needs EGL from Debian: libegl1
#   libegl-mesa0 libgl1-mesa-dri. Switching a venv between the two replaces MuJoCo (and
#   removes dm_control when going back);
# - installs this package editable, without dependencies (`pip install --no-deps -e`);
# - writes VENV_DIR/.coadapt-bridge-stamp: the sha256 of requirements.txt + pyproject.toml
#   (requirements-dmc.txt with --dmc) (then the bridge's path). A later call whose stamp matches
#   does nothing and prints nothing.
#
# Safe when several processes call it at once: the work happens under `flock` on
# VENV_DIR.lock, and a caller that waited re-reads the stamp before doing anything.
# Progress goes to stderr; stdout stays empty.
set -euo pipefail

dmc="${COADAPT_BRIDGE_DMC:-0}"
if [ "${1:-}" = "--dmc" ]; then
    dmc=1
    shift
fi
if [ "$#" -ne 1 ] || [ -z "$1" ]; then
    echo "usage: $0 [--dmc] VENV_DIR" >&2
    exit 2
fi
case "$dmc" in
    0 | "") dmc=0 ;;
    *) dmc=1 ;;
esac

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
requirements="$here/requirements.txt"
if [ "$dmc" = 1 ]; then
    requirements="$here/requirements-dmc.txt"
fi
venv="$1"
case "$venv" in
    /*) ;;
    *) venv="$PWD/$venv" ;;
esac
venv="${venv%/}"
stamp="$venv/.coadapt-bridge-stamp"

want="$(cat "$requirements" "$here/pyproject.toml" | sha256sum | cut -d' ' -f1)
bridge: $here"

up_to_date() {
    [ -f "$stamp" ] && [ -x "$venv/bin/python" ] && [ "$(cat "$stamp")" = "$want" ]
}

# Fast path: no lock, no Python started.
if up_to_date; then
    exit 0
fi

mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
flock 9

# Another caller may have finished the work while we waited for the lock.
if up_to_date; then
    exit 0
fi

if [ ! -x "$venv/bin/python" ]; then
    echo "setup_venv: creating $venv" >&2
    python3 -m venv "$venv"
fi
rm -f "$stamp"

pip=("$venv/bin/python" -m pip --disable-pip-version-check --no-input)

# The two requirement files pin different MuJoCo versions; MuJoCo 4 is split into mujoco,
# mujoco-core and mujoco-studio, which share the `mujoco` package directory: remove the old
# version completely before installing the other.
installed() {
    "$venv/bin/python" -c 'import importlib.metadata as m, sys; print(m.version(sys.argv[1]))' "$1" 2>/dev/null || true
}
want_mujoco="$(sed -n 's/^mujoco==//p' "$requirements")"
have_mujoco="$(installed mujoco)"
if [ -n "$have_mujoco" ] && [ "$have_mujoco" != "$want_mujoco" ]; then
    echo "setup_venv: replacing MuJoCo $have_mujoco by $want_mujoco" >&2
    "${pip[@]}" uninstall -q -y mujoco mujoco-core mujoco-studio 1>&2 2>/dev/null || true
fi
if [ "$dmc" = 0 ] && [ -n "$(installed dm_control)" ]; then
    echo "setup_venv: removing dm_control (no --dmc)" >&2
    "${pip[@]}" uninstall -q -y dm_control 1>&2
fi

echo "setup_venv: installing $requirements" >&2
"${pip[@]}" install -q --only-binary=:all: -r "$requirements" 1>&2
echo "setup_venv: installing coadapt-bridge (editable) from $here" >&2
"${pip[@]}" install -q --no-deps --no-build-isolation -e "$here" 1>&2

printf '%s\n' "$want" >"$stamp.tmp"
mv "$stamp.tmp" "$stamp"
echo "setup_venv: $venv is ready" >&2
