"""`servodyn contact --config FILE`: the contact observer's thresholds from clean runs."""

from __future__ import annotations

from pathlib import Path

from ...control.motion import DEFAULT_MOTION
from .argtypes import count, number
from ..contact_thresholds import calibrate
from .common import describe, out_folder, port_option, say
from .prompt import ask


def add_arguments(p) -> None:
    describe(p, "Play each motion --runs times with the contact guard off, feed the momentum observer every tick, "
             "and set each joint's contact threshold to --margin times the largest residual seen: the thresholds "
             "are shown, then written to the configuration's [safety] contact_threshold_nm after asking (a built-in "
             "configuration's copy goes to --write, default ./NAME.toml; comments kept). Without a port the "
             "simulated buses are used; on a real arm, play motions it will really play, with nothing in reach.",
             "servodyn contact --config replica --runs 3 --motion tennis_forehand",
             exits="0 written or nothing to change, 1 declined or a run did not complete cleanly")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    p.add_argument("--motion", action="append", default=None, metavar="NAME|FILE",
                   help="a motion to play (repeatable; default the configuration's `[swing] motion`, "
                        f"{DEFAULT_MOTION} unless it names another), at the configuration's time scale")
    p.add_argument("--runs", type=count(1, what="runs"), default=3, metavar="N",
                   help="clean runs of each motion (default 3)")
    p.add_argument("--margin", type=number(1.0, 10.0, "times the largest residual"), default=1.2, metavar="F",
                   help="threshold = F x the largest |residual| of each joint (default 1.2)")
    port_option(p, "the real bus's port (default: the configuration's; 'auto' means simulated)")
    out_folder(p, "out/contact", "folder for the runs' logs")
    p.add_argument("--write", default=None, metavar="FILE",
                   help="for a built-in configuration: the file its patched copy goes to (default ./NAME.toml)")
    p.add_argument("--yes", action="store_true", help="write without asking")


def run(args) -> int:
    return calibrate(args.config, args.motion or [], args.runs, args.margin, Path(args.out),
                     port=args.port, write_to=args.write,
                     confirm=(lambda question: True) if args.yes else (lambda question: ask(question, False, say)),
                     say=say)
