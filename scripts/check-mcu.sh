#!/usr/bin/env bash
# check-mcu.sh ELF OBJDIR: checks of the core's Cortex-M4F build (made by firmware/mcu/rules.mk).
#
#   1. the linked image has no heap (malloc, sbrk) and, being a float build, no double-precision
#      helper (__aeabi_d*, __aeabi_f2d, ...) and no double libm call (sin, cos, sqrt, fabs, ...);
#   2. reports code and data size, the core's and the CAN codec's code (the codec within its
#      budget), and the worst stack frame from the -fstack-usage files;
#   3. runs the image under QEMU (mps2-an386): it must exit 0 within 10 s.
# Any failure prints one line starting with "check-mcu: FAIL" and exits non-zero.
set -euo pipefail

elf=${1:?usage: check-mcu.sh ELF OBJDIR}
objdir=${2:?usage: check-mcu.sh ELF OBJDIR}
fail() { echo "check-mcu: FAIL: $*"; exit 1; }

# --- 1. forbidden symbols ----------------------------------------------------------------------
heap='^_?(malloc|calloc|realloc|free|sbrk)(_r)?$|^_(malloc|calloc|realloc|free)_r$'
double_helpers='^__aeabi_(d[a-z0-9]+|f2d|i2d|ui2d|l2d|ul2d)$|^__(add|sub|mul|div|neg|eq|ne|lt|le|gt|ge|un|cmp)df[23]$|^__(extendsfdf2|truncdfsf2|fix(uns)?df[sd]i|float(un)?[sd]idf)$'
double_libm='^(sin|cos|tan|asin|acos|atan|atan2|sinh|cosh|tanh|exp|exp2|expm1|log|log2|log10|log1p|pow|sqrt|cbrt|hypot|fabs|floor|ceil|round|lround|trunc|fmod|remainder|fmin|fmax|fma|ldexp|frexp|modf|scalbn|copysign)$|^__(ieee754|kernel)_[a-z0-9_]*[^f]$'

# name each forbidden symbol our objects call; the library code they drag in is listed once
roots=0
pulled=()
while read -r name; do
  if [[ $name =~ $heap ]]; then what="heap allocation"
  elif [[ $name =~ $double_helpers ]]; then what="double-precision helper"
  elif [[ $name =~ $double_libm ]]; then what="double-precision libm call"
  else continue
  fi
  users=""
  for obj in $(find "$objdir" -name '*.o'); do
    if arm-none-eabi-nm -u "$obj" | awk -v n="$name" '$NF == n {hit = 1} END {exit !hit}'; then
      users+=" ${obj#"$objdir"/}"
    fi
  done
  if [ -n "$users" ]; then
    echo "check-mcu: FAIL: forbidden symbol $name ($what) in $elf, used by$users"
    roots=$((roots + 1))
  else
    pulled+=("$name")
  fi
done < <(arm-none-eabi-nm --format=posix "$elf" | awk '{print $1}' | sort -u)
if [ ${#pulled[@]} -gt 0 ]; then
  [ $roots -gt 0 ] || echo "check-mcu: FAIL: forbidden symbols in $elf from the libraries (see the .map):"
  echo "  linked from the libraries: ${pulled[*]}"
fi
[ $roots -eq 0 ] && [ ${#pulled[@]} -eq 0 ] || exit 1
echo "  symbols: no malloc/sbrk, no double-precision helpers or libm calls"

# --- 2. size and stack -------------------------------------------------------------------------
read -r text data bss _ < <(arm-none-eabi-size "$elf" | tail -n 1)
# code in the image of the functions and constants our objects under a path define
code_of() {
  local syms
  syms=$(find "$objdir" -path "*$1/*.o" -exec arm-none-eabi-nm --defined-only {} + |
         awk 'NF == 3 && $2 ~ /[tTrRdDbB]/ {print $3}' | sort -u)
  arm-none-eabi-nm -S --radix=d "$elf" | awk -v names="$syms" '
    BEGIN { n = split(names, list, "\n"); for (i = 1; i <= n; i++) mine[list[i]] = 1 }
    NF == 4 && $3 ~ /[tT]/ && ($4 in mine) { total += $2 }
    END { print total + 0 }'
}
core_text=$(code_of firmware/core)
# the CAN codec in float is ~2 KB; past its budget something heavy came in (a table, a library call)
can_budget=4096
can_text=$(code_of hal/can/c)
stack=$(arm-none-eabi-nm --radix=d "$elf" | awk '$3 == "__stack_bottom" {b = $1} $3 == "__stack_top" {t = $1}
                                             END {print t - b}')
echo "  size: text $text B (core code $core_text B, CAN codec $can_text B), data $data B, bss $bss B (stack $stack B of it)"
[ "$can_text" -gt 0 ] || fail "the CAN codec (hal/can/c) is not linked into $elf"
[ "$can_text" -le $can_budget ] || fail "the CAN codec's code is $can_text B, over its $can_budget B budget"

su_files=$(find "$objdir" -name '*.su')
[ -n "$su_files" ] || fail "no .su files in $objdir (built without -fstack-usage?)"
worst=$(cat $su_files | sort -t $'\t' -k2,2n | tail -n 1)
worst_fn=${worst%%$'\t'*}
worst_rest=${worst#*$'\t'}
echo "  worst stack frame: ${worst_fn##*:} ${worst_rest%%$'\t'*} B (${worst_rest#*$'\t'}, ${worst_fn%:*})"
dynamic=$(cat $su_files | awk -F '\t' '$3 == "dynamic" {print $1}' | tr '\n' ' ')
[ -z "$dynamic" ] || echo "  warning: stack frames of unbounded size: $dynamic"

# --- 3. QEMU -----------------------------------------------------------------------------------
command -v qemu-system-arm >/dev/null || fail "qemu-system-arm not found (run make toolchain)"
set +e
output=$(timeout 10 qemu-system-arm -M mps2-an386 -cpu cortex-m4 -display none -monitor none \
           -serial none -semihosting-config enable=on,target=native -kernel "$elf" \
           </dev/null 2>&1)
rc=$?
set -e
case $rc in
  0) echo "  QEMU mps2-an386: passed: $output"; exit 0 ;;
  1) why="sd_model_setup rejected the arm model" ;;
  2) why="a non-finite result" ;;
  3) why="forward(rnea(qdd)) differs from qdd by more than 1e-3" ;;
  4) why="the core counted a warning" ;;
  5) why="the CAN codec's check failed (firmware/mcu/canmotor_check.c)" ;;
  99) why="a CPU fault" ;;
  124) why="no exit within 10 s" ;;
  *) why="unexpected exit code" ;;
esac
fail "QEMU mps2-an386 run exited $rc: $why${output:+ -- $output}"
