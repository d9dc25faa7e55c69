#!/usr/bin/env bash
# install-browser.sh: Debian's chromium for the browser tests of `servodyn view`, when missing.
set -uo pipefail
here=$(dirname "$0")
command -v chromium >/dev/null || command -v chromium-browser >/dev/null && exit 0
"$here/apt-install.sh" chromium
