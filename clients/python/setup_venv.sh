#!/usr/bin/env bash
# Creates (or updates) the virtual environment of the Python client example.
#
#   clients/python/setup_venv.sh VENV_DIR
#
# Installs the pinned requirements.txt, wheels only, then the coadapt-client package itself
# (`pip install ./clients/python`, as a user does: its stubs are generated from proto/ as it
# builds), and writes VENV_DIR/.coadapt-client-stamp (the sha256 of requirements.txt, the
# package's files and the protos): a later call whose stamp matches does nothing. Safe when
# several processes call it at once (flock on VENV_DIR.lock). Progress goes to stderr.
set -euo pipefail
if [ "$#" -ne 1 ] || [ -z "$1" ]; then
    echo "usage: $0 VENV_DIR" >&2
    exit 2
fi
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$1"
case "$venv" in /*) ;; *) venv="$PWD/$venv" ;; esac
venv="${venv%/}"
stamp="$venv/.coadapt-client-stamp"
want="$(cd "$here" && cat requirements.txt pyproject.toml setup.py src/coadapt_client/*.py ../../proto/coadapt/v1/design.proto \
    ../../proto/inference/grpc_predict_v2.proto | sha256sum | cut -d' ' -f1)"
up_to_date() { [ -f "$stamp" ] && [ -x "$venv/bin/python" ] && [ "$(cat "$stamp")" = "$want" ]; }
if up_to_date; then exit 0; fi
mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
flock 9
if up_to_date; then exit 0; fi
if [ ! -x "$venv/bin/python" ]; then
    echo "setup_venv: creating $venv" >&2
    python3 -m venv "$venv"
fi
rm -f "$stamp"
echo "setup_venv: installing $here/requirements.txt" >&2
"$venv/bin/python" -m pip --disable-pip-version-check --no-input install -q --only-binary=:all: -r "$here/requirements.txt" 1>&2
echo "setup_venv: installing the coadapt-client package ($here)" >&2
"$venv/bin/python" -m pip --disable-pip-version-check --no-input install -q --force-reinstall --no-deps "$here" 1>&2
rm -rf "$here/build" "$here"/src/*.egg-info
printf '%s\n' "$want" >"$stamp.tmp"
mv "$stamp.tmp" "$stamp"
echo "setup_venv: $venv is ready" >&2
