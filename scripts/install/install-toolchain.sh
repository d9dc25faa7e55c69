#!/usr/bin/env bash
# install-toolchain.sh: the Cortex-M cross compiler, its C library and QEMU, from Debian's
# packages, when missing. Quick and silent when everything is there.
set -euo pipefail

need=()
command -v arm-none-eabi-gcc >/dev/null || need+=(gcc-arm-none-eabi)
# newlib provides libc, libm and nosys.specs; gcc prints the bare name when it has no such file
if ! command -v arm-none-eabi-gcc >/dev/null ||
   [ ! -f "$(arm-none-eabi-gcc -print-file-name=nosys.specs)" ]; then
  need+=(libnewlib-arm-none-eabi)
fi
command -v qemu-system-arm >/dev/null || need+=(qemu-system-arm)

[ ${#need[@]} -gt 0 ] || exit 0
exec "$(dirname "$0")/apt-install.sh" "${need[@]}"
