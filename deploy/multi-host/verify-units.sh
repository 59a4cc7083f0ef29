#!/usr/bin/env bash
# Checks the systemd units offline: stages an install (install.sh --root) with a copy of this
# host's systemd units beside them and runs `systemd-analyze verify` on ours; any warning fails.
# Exit 0: clean; 1: a finding; 77: systemd-analyze is not installed (apt-get install systemd).
set -euo pipefail

case ${1:-} in
  -h | --help)
    echo "Usage: deploy/multi-host/verify-units.sh [COADAPT_BIN]  (default: a stand-in script)"
    exit 0
    ;;
esac
SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
command -v systemd-analyze >/dev/null 2>&1 || { echo "verify-units.sh: SKIP: systemd-analyze not found (Debian: apt-get install systemd)" >&2; exit 77; }
[[ -d /usr/lib/systemd/system ]] || { echo "verify-units.sh: SKIP: no /usr/lib/systemd/system to verify against" >&2; exit 77; }

stage=$(mktemp -d)
trap 'rm -rf -- "$stage"' EXIT
bin=${1:-}
if [[ -z $bin ]]; then
  bin=$stage/coadapt-stand-in
  printf '#!/bin/sh\nexit 0\n' >"$bin"
  chmod +x "$bin"
fi
"$SCRIPT_DIR/install.sh" --role all --bin "$bin" --root "$stage/root" 2>/dev/null
mkdir -p "$stage/root/usr/lib/systemd"
cp -a /usr/lib/systemd/system "$stage/root/usr/lib/systemd/"
cd "$stage/root"
units=(etc/systemd/system/coadapt-learner.service etc/systemd/system/coadapt-optimizer.service
  "etc/systemd/system/coadapt-actor@0.service" "etc/systemd/system/coadapt-actor@17.service")
# verify wants instance files to exist for templates: link them to the template.
for u in "${units[@]}"; do [[ -e $u ]] || ln -s "coadapt-actor@.service" "$u"; done
status=0
findings=$(systemd-analyze verify --root="$stage/root" "${units[@]}" 2>&1) || status=$?
if [[ $status -ne 0 || -n $findings ]]; then
  printf 'verify-units.sh: FAIL (status %s):\n%s\n' "$status" "$findings" >&2
  exit 1
fi
echo "verify-units.sh: OK: systemd-analyze verify is clean for ${units[*]##*/}" >&2
