#!/usr/bin/env bash
# lint-imports.sh VENV: check the import-linter contracts of pyproject.toml (the package's layers).
#
# The servodyn package is assembled from four folders (host/ is servodyn, hal/ servodyn.hal, sim/
# servodyn.sim, tools/ servodyn.tools); import-linter reads a package from one directory tree, so
# the Python files are laid out as the installed package in build/layers first.
set -euo pipefail
venv=${1:-.venv}
root=$(cd "$(dirname "$0")/.." && pwd)
tree="$root/build/layers"
rm -rf "$tree"
mkdir -p "$tree/servodyn/hal" "$tree/servodyn/sim" "$tree/servodyn/tools"
copy() {   # copy FROM TO: the .py files of folder FROM as package folder TO
  (cd "$root/$1" && find . -name '*.py' -exec cp --parents -t "$tree/$2" {} +)
}
copy host servodyn
copy hal servodyn/hal
copy sim servodyn/sim
copy tools servodyn/tools
cd "$root"
PYTHONPATH="$tree" "$venv/bin/lint-imports" --no-cache
