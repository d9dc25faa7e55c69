#!/usr/bin/env bash
# install-fuzz.sh: clang with libFuzzer and the sanitizers' runtimes (Debian's clang and
# libclang-rt-14-dev), when missing. Prints the clang to use. Quick and silent when it is there.
set -euo pipefail

# a clang that links -fsanitize=fuzzer,address,undefined
works() {
  command -v "$1" >/dev/null || return 1
  local dir
  dir=$(mktemp -d)
  printf '#include <stdint.h>\n#include <stddef.h>\nint LLVMFuzzerTestOneInput(const uint8_t* d, size_t n) { (void)d; (void)n; return 0; }\n' \
    >"$dir/t.c"
  "$1" -fsanitize=fuzzer,address,undefined -o "$dir/t" "$dir/t.c" >/dev/null 2>&1
  local ok=$?
  rm -rf "$dir"
  return $ok
}

for cc in ${FUZZ_CC:-} clang clang-14; do
  if works "$cc"; then echo "$cc"; exit 0; fi
done
"$(dirname "$0")/apt-install.sh" clang libclang-rt-14-dev >&2
for cc in clang clang-14; do
  if works "$cc"; then echo "$cc"; exit 0; fi
done
echo "install-fuzz: clang cannot link -fsanitize=fuzzer,address,undefined after installing clang and libclang-rt-14-dev" >&2
exit 1
