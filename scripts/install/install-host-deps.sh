#!/usr/bin/env bash
# install-host-deps.sh: what building the Python package needs, from Debian's packages, when
# missing: Python 3 with venv support, its headers and a C compiler for the core's extension.
set -euo pipefail
python=${PYTHON:-python3}

need=()
if ! command -v "$python" >/dev/null; then
  need+=(python3 python3-venv python3-dev)
else
  "$python" -c 'import ensurepip, venv' 2>/dev/null || need+=(python3-venv)
  "$python" -c 'import os, sys, sysconfig
sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' ||
    need+=(python3-dev)
fi
command -v cc >/dev/null || command -v gcc >/dev/null || need+=(gcc libc6-dev)

[ ${#need[@]} -gt 0 ] || exit 0
exec "$(dirname "$0")/apt-install.sh" "${need[@]}"
