"""`servodyn firmware`: the firmware under QEMU against the simulated bus (hardware in the loop)."""

from __future__ import annotations

from pathlib import Path

from .argtypes import count
from ...hil import BOARDS, run_firmware
from .common import CliError, describe, out_folder, say


def add_arguments(p) -> None:
    describe(p, "Run the firmware under QEMU against the simulated bus (hardware in the loop).",
             "servodyn firmware --board an500 --out out/firmware")
    boards = ", ".join(f"{name} = {cpu}" for name, (_, cpu) in BOARDS.items())
    p.add_argument("--board", default=next(iter(BOARDS)), choices=list(BOARDS),
                   help=f"QEMU board: {boards} (default {next(iter(BOARDS))})")
    p.add_argument("--elf", default=None, help="firmware image (default build/fw/BOARD/servodyn-fw.elf; `make fw` "
                                               "builds it)")
    p.add_argument("--config", default="replica", help="robot configuration the image was generated for")
    p.add_argument("--icount-shift", type=count(0, 10, "QEMU takes shifts up to 10"), default=3,
                   help="QEMU -icount shift: 2^N ns of emulated time per instruction (default 3: 125 MIPS, a fast "
                        "Cortex-M4; 7 for the budget figures)")
    out_folder(p, "out/firmware")


def run(args) -> int:
    summary = run_firmware(args.board, elf=args.elf, config=args.config, out=Path(args.out),
                           icount_shift=args.icount_shift, say=say)
    if summary["fault"] != "none":
        raise CliError(f"the firmware stopped on a fault: {summary['fault']} "
                       f"(servo {summary['fault_servo']}, tick {summary['fault_tick']})")
    return 0
