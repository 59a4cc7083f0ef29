#!/usr/bin/env bash
# Installs Debian's Chromium and ChromeDriver for the operator page's browser test
# (cli/tests/operator_page.rs), as bridges/python/setup_venv.sh makes the Python virtualenv:
# the project's own file, never a step by hand.
#
#   scripts/setup_browser.sh        (exit 0: /usr/bin/chromium and /usr/bin/chromedriver are there)
#
# Exit 3 when they are missing and cannot be installed here (not root, or no apt-get): the test
# then skips with a loud message. Safe when several processes call it at once (flock).
# Progress goes to stderr; stdout stays empty.
set -euo pipefail
have() { command -v chromium > /dev/null 2>&1 && command -v chromedriver > /dev/null 2>&1; }
have && exit 0
if [ "$(id -u)" != 0 ] || ! command -v apt-get > /dev/null 2>&1; then
    echo "setup_browser: chromium and chromium-driver are missing, and this is not root with apt-get: cannot install them" >&2
    exit 3
fi
exec 9> /tmp/coadapt-setup-browser.lock
flock 9
have && exit 0
export DEBIAN_FRONTEND=noninteractive
echo "setup_browser: apt-get install chromium chromium-driver (about 1-2 minutes, once per machine)" >&2
if ! apt-get install -y -q --no-install-recommends chromium chromium-driver >&2; then
    # A fresh machine may not have the package lists yet.
    apt-get update -q >&2
    apt-get install -y -q --no-install-recommends chromium chromium-driver >&2
fi
have || { echo "setup_browser: installed, but chromium or chromedriver is still not on PATH" >&2; exit 1; }
