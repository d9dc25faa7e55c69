#!/usr/bin/env bash
# install-browser.sh: Debian's chromium for the browser tests of `servodyn view`, when missing.
# Prints the browser's path on its last line.
set -uo pipefail
here=$(dirname "$0")
for name in chromium chromium-browser; do
  if command -v "$name" >/dev/null; then command -v "$name"; exit 0; fi
done
"$here/apt-install.sh" chromium || exit 1
command -v chromium
