"""`servodyn codegen`: a configuration and a keyframe motion as C source for the firmware."""

from __future__ import annotations

from pathlib import Path

from ...control.motion import DEFAULT_MOTION
from ..codegen import write
from .common import describe, out_folder, say


def add_arguments(p) -> None:
    describe(p, "Write a robot configuration and a keyframe motion as C source (servodyn_gen.h, servodyn_gen.c) for "
             "the firmware.", "servodyn codegen --config replica -o build/gen")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    p.add_argument("--motion", default=DEFAULT_MOTION, help=f"motion (default {DEFAULT_MOTION})")
    out_folder(p, None)


def run(args) -> int:
    paths = write(args.config, Path(args.out), args.motion)
    say("wrote " + ", ".join(str(p) for p in paths))
    return 0
