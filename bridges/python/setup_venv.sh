#!/usr/bin/env bash
# Creates (or updates) the Python virtual environment of the coadapt bridge.
#
#   bridges/python/setup_venv.sh VENV_DIR
#
# - creates VENV_DIR with `python3 -m venv` when it does not exist;
# - installs the pinned requirements.txt, wheels only (--only-binary=:all:);
# - installs this package editable, without dependencies (`pip install --no-deps -e`);
# - writes VENV_DIR/.coadapt-bridge-stamp: the sha256 of requirements.txt + pyproject.toml
#   (then the bridge's path). A later call whose stamp matches does nothing and prints nothing.
#
# Safe when several processes call it at once: the work happens under `flock` on
# VENV_DIR.lock, and a caller that waited re-reads the stamp before doing anything.
# Progress goes to stderr; stdout stays empty.
set -euo pipefail

if [ "$#" -ne 1 ] || [ -z "$1" ]; then
    echo "usage: $0 VENV_DIR" >&2
    exit 2
fi

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$1"
case "$venv" in
    /*) ;;
    *) venv="$PWD/$venv" ;;
esac
venv="${venv%/}"
stamp="$venv/.coadapt-bridge-stamp"

want="$(cat "$here/requirements.txt" "$here/pyproject.toml" | sha256sum | cut -d' ' -f1)
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
echo "setup_venv: installing $here/requirements.txt" >&2
"${pip[@]}" install -q --only-binary=:all: -r "$here/requirements.txt" 1>&2
echo "setup_venv: installing coadapt-bridge (editable) from $here" >&2
"${pip[@]}" install -q --no-deps --no-build-isolation -e "$here" 1>&2

printf '%s\n' "$want" >"$stamp.tmp"
mv "$stamp.tmp" "$stamp"
echo "setup_venv: $venv is ready" >&2
