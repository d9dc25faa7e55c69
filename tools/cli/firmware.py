"""`servodyn firmware`: the firmware under QEMU against the simulated bus (hardware in the loop)."""

from __future__ import annotations

from pathlib import Path

from .argtypes import count
from ...hil import BOARDS, run_firmware
from ...loop.link_controllers import QEMU_LINK_BOARDS
from ...loop.qemu import QEMU_ICOUNT_SHIFT, to_instructions
from ...loop.run import RunOptions
from ...report.swing import play as play_and_report
from .common import CliError, describe, out_folder, say


def add_arguments(p) -> None:
    describe(p, "Run the firmware under QEMU against the simulated bus (hardware in the loop). On "
             f"{' and '.join(QEMU_LINK_BOARDS)} the general application plays any configuration and motion, loaded "
             "and streamed over the host link (servodyn swing --controller qemu:BOARD, with each command compared "
             "to the host's double-precision controller); --elf, or an500, runs an image generated for one robot "
             "(servodyn codegen).",
             "servodyn firmware --board f405 --motion tennis_forehand --out out/firmware")
    boards = ", ".join(f"{name} = {cpu}" for name, (_, cpu) in BOARDS.items())
    p.add_argument("--board", default=next(iter(BOARDS)), choices=list(BOARDS),
                   help=f"QEMU board: {boards} (default {next(iter(BOARDS))})")
    p.add_argument("--elf", default=None, help="a generated firmware image (build/fw/BOARD/servodyn-fw.elf; `make "
                                               "fw` builds it): the robot and motion compiled into it")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    p.add_argument("--motion", default=None, metavar="NAME|FILE",
                   help="with the general application: built-in motion, keyframe file or trajectory CSV (default: "
                        "the configuration's)")
    p.add_argument("--icount-shift", type=count(0, 10, "QEMU takes shifts up to 10"), default=3,
                   help="QEMU -icount shift: 2^N ns of emulated time per instruction (default 3: 125 MIPS, a fast "
                        "Cortex-M4; 7 for the budget figures); the generated image")
    out_folder(p, "out/firmware")


def run(args) -> int:
    if args.elf is None and args.board in QEMU_LINK_BOARDS:
        return _general(args)
    if args.motion is not None:
        raise CliError(f"--motion: a generated image plays the motion compiled into it (the general application, "
                       f"on {', '.join(QEMU_LINK_BOARDS)} without --elf, plays any)")
    summary = run_firmware(args.board, elf=args.elf, config=args.config, out=Path(args.out),
                           icount_shift=args.icount_shift, say=say)
    if summary["fault"] != "none":
        raise CliError(f"the firmware stopped on a fault: {summary['fault']} "
                       f"(servo {summary['fault_servo']}, tick {summary['fault_tick']})")
    return 0


def _general(args) -> int:
    summary = play_and_report(args.config, RunOptions(motion=args.motion, controller=f"qemu:{args.board}"),
                              Path(args.out), say=say)
    agreement, report = summary.get("agreement") or {}, summary.get("controller_report") or {}
    if agreement.get("ticks"):
        say(f"  commands vs the host's double controller on the same measurements: largest difference "
            f"{agreement['max_units']} unit(s) over {agreement['ticks']} ticks")
    if report.get("worst_work"):
        ins = {k: round(to_instructions(report[k], args.board, QEMU_ICOUNT_SHIFT))
               for k in ("worst_work", "worst_control", "worst_link")}
        say(f"  worst tick {ins['worst_work']} instructions (control {ins['worst_control']}, link "
            f"{ins['worst_link']}; -icount shift {QEMU_ICOUNT_SHIFT}); stack used {report.get('stack')} B")
    if summary.get("error"):
        raise CliError(f"the firmware stopped: {summary['error']} (log up to then in {args.out})",
                       summary.get("exit_code", 2))
    return 0
