"""`servodyn view [CONFIG|MODEL]`: the arm in 3-D in a browser page."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...control.motion import DEFAULT_MOTION
from .argtypes import positive, tcp_port
from ..view import open_view, serve_forever
from .common import CliError, describe, say


def add_arguments(p) -> None:
    describe(p, "Serve a page with the arm drawn from its solids: play, pause and scrub a motion or a logged run "
             "(the planned arm as a ghost, the measured one solid, angle, tracking error and torque plots, each "
             "joint coloured by its torque's share of the servo's limit), or edit a keyframe motion and see its "
             "torques and the validator's verdict at once.",
             "servodyn view replica --log out/swing", "servodyn view --config replica_can --http-port 8081")
    p.add_argument("subject", nargs="?", default=None, metavar="CONFIG|MODEL",
                   help="robot configuration or model, by name or file (default replica)")
    p.add_argument("--config", default=None, metavar="CONFIG|MODEL", help="the same, as the other commands name it")
    p.add_argument("--log", default=None, metavar="DIR", help="a run's folder (swing_log.csv) to replay")
    p.add_argument("--motion", default=None, metavar="NAME|FILE",
                   help=f"built-in motion, keyframe file (editable) or trajectory CSV (default {DEFAULT_MOTION})")
    p.add_argument("--time-scale", type=positive, default=None, metavar="S",
                   help=f"play the motion S times slower (default: the configuration's for {DEFAULT_MOTION})")
    p.add_argument("--save", default=None, metavar="FILE",
                   help="where 'Save keyframes' writes (default out/view/<motion>.toml)")
    p.add_argument("--source", default=None, metavar="CLIP.bvh",
                   help="overlay the captured arm the --motion CSV was retargeted from (servodyn retarget)")
    p.add_argument("--http-port", type=tcp_port, default=8080, metavar="N",
                   help="the page's TCP port (default 8080; the next free one if taken)")
    p.add_argument("--port", type=tcp_port, dest="http_port", default=argparse.SUPPRESS,
                   help=argparse.SUPPRESS)                  # the earlier name of --http-port
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")


def run(args) -> int:
    if args.subject is not None and args.config is not None:
        raise CliError(f"give the configuration once: {args.subject!r} or --config {args.config!r}")
    viewer = open_view(args.config or args.subject or "replica", log=args.log, motion=args.motion,
                       time_scale=args.time_scale, host=args.host, port=args.http_port,
                       save_to=Path(args.save) if args.save else None, source=args.source, say=say)
    serve_forever(viewer, say=say)
    return 0
