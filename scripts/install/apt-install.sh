#!/usr/bin/env bash
# apt-install.sh PACKAGE...: install Debian packages without recommends, through sudo when not
# root. On failure prints one line naming the packages and the log, and exits non-zero.
set -uo pipefail
[ $# -gt 0 ] || exit 0
me=$(basename "$0" .sh)

if ! command -v apt-get >/dev/null; then
  echo "$me: apt-get not found: install $* with this system's package manager"
  exit 1
fi
if [ "$(id -u)" -eq 0 ]; then
  as_root=()
elif command -v sudo >/dev/null; then
  # without a terminal (CI) sudo must not wait for a password
  if [ -t 0 ]; then as_root=(sudo); else as_root=(sudo -n); fi
else
  echo "$me: not root and no sudo: run 'apt-get install -y --no-install-recommends $*' as root"
  exit 1
fi

log=$(mktemp "${TMPDIR:-/tmp}/servodyn-apt.XXXXXX.log")
echo "$me: installing $* (log: $log)"
if "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update >"$log" 2>&1 &&
   "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive \
     apt-get install -y --no-install-recommends "$@" >>"$log" 2>&1; then
  rm -f "$log"
  exit 0
fi
echo "$me: FAILED to install $* with apt-get: $(tail -n 1 "$log") (full log: $log)"
exit 1
