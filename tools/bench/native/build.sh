#!/usr/bin/env bash
# build.sh PYTHON OUTDIR: build OUTDIR/bench, the servodyn / Pinocchio / MuJoCo benchmark.
#
# PYTHON is a venv interpreter with the pin (Pinocchio, cmeel) and mujoco wheels; Eigen 3 headers
# come from cmeel-eigen in that venv, EIGEN3_INCLUDE_DIR, or /usr/include/eigen3.
# Pinocchio is used header-only, so it is compiled with the same flags as the benchmark.
set -euo pipefail

fail() { echo "build.sh: $*" >&2; exit 1; }

[ $# -eq 2 ] || fail "usage: tools/bench/native/build.sh PYTHON OUTDIR"
command -v gcc >/dev/null && command -v g++ >/dev/null || fail "gcc and g++ are needed"
python=$1
out=$2
root=$(cd "$(dirname "$0")/../../.." && pwd)     # tools/bench/native -> the repository
start=$SECONDS

# locate the cmeel prefixes (Pinocchio, Boost, maybe Eigen) and the mujoco package
paths=$("$python" - <<'EOF'
import os, sys
prefixes = [os.path.join(p, "cmeel.prefix") for p in sys.path]
prefixes = [p for p in dict.fromkeys(prefixes) if os.path.isdir(os.path.join(p, "include"))]
pin = [p for p in prefixes if os.path.isdir(os.path.join(p, "include", "pinocchio"))]
eigen = [p for p in prefixes if os.path.isdir(os.path.join(p, "include", "eigen3", "Eigen"))]
try:
    import mujoco
    mj = os.path.dirname(mujoco.__file__)
except ImportError:
    mj = ""
print(pin[0] if pin else "")
print(os.path.join(eigen[0], "include", "eigen3") if eigen else "")
print(mj)
EOF
) || fail "cannot run $python"
mapfile -t found <<<"$paths"
pin_prefix=${found[0]:-}
eigen_dir=${EIGEN3_INCLUDE_DIR:-${found[1]:-}}
mj_dir=${found[2]:-}
if [ -z "$eigen_dir" ] && [ -d /usr/include/eigen3/Eigen ]; then eigen_dir=/usr/include/eigen3; fi

[ -n "$pin_prefix" ] || fail "Pinocchio headers not found: pip install pin into the venv of $python"
[ -n "$mj_dir" ] || fail "mujoco not importable: pip install mujoco into the venv of $python"
[ -n "$eigen_dir" ] && [ -d "$eigen_dir/Eigen" ] ||
  fail "Eigen 3 headers not found: pip install cmeel-eigen into the venv of $python" \
    "(or apt-get install libeigen3-dev, or set EIGEN3_INCLUDE_DIR)"
mj_libs=("$mj_dir"/libmujoco.so.*)
mj_lib=${mj_libs[0]}
[ -f "$mj_lib" ] && [ -f "$mj_dir/include/mujoco/mujoco.h" ] ||
  fail "libmujoco.so.* or include/mujoco/mujoco.h missing under $mj_dir"

# compile the core as C, the benchmark as C++17 (Boost.MPL limits as Pinocchio's CMake sets them)
mkdir -p "$out/obj"
objs=()
for src in "$root"/firmware/core/*.c; do
  obj="$out/obj/$(basename "${src%.c}").o"
  gcc -O3 -std=c11 -ffp-contract=off -Wall -I"$root/firmware/core/include" -c "$src" -o "$obj" ||
    fail "core does not compile: $src"
  objs+=("$obj")
done
echo "build.sh: compiling bench.cpp (the Pinocchio headers take a minute or two)"
g++ -std=c++17 -O3 -DNDEBUG -Wall \
  -DBOOST_MPL_LIMIT_LIST_SIZE=30 -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 \
  -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS -DBOOST_FUSION_INVOKE_MAX_ARITY=12 \
  -I"$root/firmware/core/include" -isystem "$eigen_dir" -isystem "$pin_prefix/include" \
  -isystem "$mj_dir/include" \
  -c "$root/tools/bench/native/bench.cpp" -o "$out/obj/bench.o" || fail "bench.cpp does not compile"

# link; the rpath lets the binary find libmujoco without LD_LIBRARY_PATH
g++ "$out/obj/bench.o" "${objs[@]}" "$mj_lib" -Wl,-rpath,"$mj_dir" -lm -o "$out/bench" ||
  fail "link failed"
echo "build.sh: built $out/bench in $((SECONDS - start)) s"
