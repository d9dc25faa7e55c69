"""`servodyn swing`: play a motion on servos, the simulated bus by default."""

from __future__ import annotations

import argparse
import signal
from pathlib import Path

from ...control.motion import DEFAULT_MOTION
from ...control.timing import MAX_PLAYED_DURATION, OVERRUN_TOLERANCE
from ...errors import FAULT_CODES, ExitCode, ServodynError, exit_codes_help
from .argtypes import contact, number, obstacle, positive, tcp_port
from ...loop.run import RunOptions
from ...report.swing import play as play_and_report
from .prompt import ask
from ..view import live_viewer, replay_after_live
from .common import CliError, describe, out_folder, port_option, say

INTERRUPTED = {name: 128 + signal.Signals[name].value for name in ("SIGINT", "SIGTERM")}


def add_arguments(p) -> None:
    describe(p, "Validate the motion against the servos' limits, home the arm, play it under closed-form control "
             "and log it. Without --port the simulated Dynamixel bus is started and used. The log streams to "
             "OUT/swing_log.csv (on disk at least every 100 ms); OUT/summary.json is written at the end.",
             "servodyn swing --config replica_can --motion tennis_forehand --out out/can",
             exits=f"{int(ExitCode.OK)} the whole swing, 1 declined at the question before it moves, "
                   f"{INTERRUPTED['SIGINT']} SIGINT and {INTERRUPTED['SIGTERM']} SIGTERM (a safe stop too: "
                   "torque off, log and summary written); after a safe stop on a fault (one line says which) the "
                   f"firmware's fault codes: {exit_codes_help(*FAULT_CODES)}")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    port_option(p, "the real bus's serial port or CAN channel (default: the configuration's; 'auto' there means the "
                   "simulated bus); a configuration with several buses names each: --port shoulder=/dev/ttyACM0 "
                   "--port wrist=/dev/ttyUSB0")
    out_folder(p, "out/swing")
    p.add_argument("--no-feedforward", action="store_true", help="PD only, no inverse dynamics")
    p.add_argument("--time-scale", type=positive, default=None, metavar="S",
                   help="play the swing S times slower (default: the configuration's for its own motion, "
                        "else 1)")
    p.add_argument("--realtime", action="store_true",
                   help="pace the loop and the simulated plant by the wall clock (default lock-step on a simulated "
                        "bus; a real bus always runs in real time); on the simulated Dynamixel bus the loop, "
                        "the simulator and the kernel's tty work share one CPU (root: the kernel's work "
                        "queues are steered there for the run)")
    p.add_argument("--overrun-tolerance", type=number(0, what="ms"), default=None, metavar="MS",
                   help="in real time, how far (ms) the loop may fall behind its period schedule before it stops "
                        f"safely (overrun, exit {int(ExitCode.OVERRUN)}; default {OVERRUN_TOLERANCE * 1e3:g})")
    p.add_argument("--motion", default=None, metavar="NAME|FILE",
                   help="built-in motion, keyframe file or trajectory CSV (default: the configuration's `[swing] "
                        f"motion`, {DEFAULT_MOTION} unless it names another, e.g. so101_pick for so101)")
    p.add_argument("--force", action="store_true",
                   help="play a motion the validator refuses (on the simulated bus only)")
    p.add_argument("--verbose", action="store_true",
                   help="when the validator refuses the motion, list every violation (not only the first)")
    p.add_argument("--native", action="store_true",
                   help="the firmware's loop as a Linux process plays it: --controller native")
    p.add_argument("--controller", default="python", metavar="python|native|qemu:BOARD|PORT",
                   help="who runs the control loop: python (default, this process); native, the general firmware "
                        "application as a Linux process (build/fw/native/servodyn-fw-link, `make fw`); qemu:an386 "
                        "or qemu:f405, its image for the board under QEMU against the simulated arm (lock-step); "
                        "PORT, a board running it on that serial port (its own buses: it asks before it moves "
                        "unless --yes). The host validates the motion, loads the robot and streams the motion over "
                        "the host link (docs/host-link.md), e.g. servodyn swing --controller qemu:f405")
    p.add_argument("--yes", action="store_true",
                   help="on a real port, move without asking (the homing distances are still printed)")
    p.add_argument("--hold", type=number(0, MAX_PLAYED_DURATION, "s, the longest a swing plays", above=True),
                   default=None, metavar="S",
                   help="instead of the motion, hold the pose the arm is in for S seconds under the controller, "
                        "and log it")
    p.add_argument("--dry-run", action="store_true",
                   help="torque off: read the arm and log the planned homing with the torques the controller "
                        "would send, sending none")
    p.add_argument("--contact", type=contact, action="append", default=[], metavar="BODY:FX,FY,FZ@T[+D]",
                   help="the simulated plant: a push of FX,FY,FZ N (world frame) at BODY's centre of mass from T s "
                        "after the motion starts (homing excluded) for D s (default 0.3), e.g. r_hand:0,0,-10@1.2; "
                        "repeatable; summary.json's sim_contact has what was applied")
    p.add_argument("--obstacle", type=obstacle, action="append", default=[], metavar="SPEC",
                   help="the simulated plant: plane:NX,NY,NZ,D[@K] (inside where n·x < D) or sphere:X,Y,Z,R[@K], in "
                        "m in the model's base frame, a spring-damper of K N/m (default 40000, ISO/TS 15066 Table A.3's "
                        "lower arm) hit by points on the arm's solids, there from the start; repeatable")
    p.add_argument("--view", action="store_true",
                   help="show the arm live in a browser page (servodyn view), then the logged run")
    p.add_argument("--http-port", type=tcp_port, default=8080, metavar="N",
                   help="with --view: the page's TCP port (default 8080)")
    p.add_argument("--view-port", type=tcp_port, dest="http_port", default=argparse.SUPPRESS,
                   help=argparse.SUPPRESS)                  # the earlier name of --http-port
    p.add_argument("--view-host", default="127.0.0.1", help="with --view: the page's address (default 127.0.0.1)")


def play(args, observer=None) -> dict:
    """The swing the options ask for: its summary."""
    options = RunOptions(motion=args.motion, time_scale=args.time_scale, feedforward=not args.no_feedforward,
                         realtime=args.realtime, force=args.force,
                         controller="native" if args.native else args.controller,
                         port=args.port,
                         overrun_tolerance=None if args.overrun_tolerance is None else args.overrun_tolerance * 1e-3,
                         hold=args.hold, dry_run=args.dry_run, contacts=tuple(args.contact),
                         obstacles=tuple(args.obstacle))
    return play_and_report(args.config, options, Path(args.out), observer=observer, say=say,
                           confirm=None if args.yes else (lambda question: ask(question, False, say)))


def run(args) -> int:
    viewer = feed = None
    if args.view:
        viewer, feed = live_viewer(args.config, args.view_host, args.http_port, say=say)
    try:
        summary = play(args, feed.observe if feed else None)
    except ServodynError as err:
        if viewer is not None:
            viewer.close()
        if args.verbose and getattr(err, "violations", None):      # the validator's refusal, in full
            say("\n".join(f"  {line}" for line in err.violations))
        raise
    if viewer is not None and (summary.get("signal") or summary.get("error")):
        viewer.close()
    if summary.get("signal"):       # a safe stop asked for: the shell's status for that signal
        say(f"servodyn: the swing stopped: {summary['error']}, torque off (log up to then in {args.out})")
        return 128 + signal.Signals[summary["signal"]].value
    if summary.get("error"):
        raise CliError(f"the swing stopped: {summary['error']} (log up to then in {args.out})", summary["exit_code"])
    if viewer is not None:
        replay_after_live(viewer, feed, Path(args.out), say=say)
    return 0
