"""`servodyn excite --config FILE`: an exciting trajectory for `servodyn identify`."""

from __future__ import annotations

from pathlib import Path

from .argtypes import count, positive
from ..excite import run as run_excite
from .common import describe, say

DEFAULT_OUT = "out/excite/excitation.csv"


def add_arguments(p) -> None:
    describe(p, "A finite Fourier series per joint (Swevers et al.), its coefficients chosen for a well conditioned "
             "identification, starting and ending at rest, written as a trajectory CSV for servodyn swing --motion. "
             "The margin: each joint stays inside its position limits less --margin of its range at both ends and "
             "under 0.6 of its velocity limit; then servodyn validate checks it on the configuration, and while it "
             "fails every excursion is scaled by 0.85. With --heat, a heating run for the thermal constants instead "
             "(README: the heating run).", "servodyn excite --config replica --duration 30 -o out/excite/x.csv",
             exits="0 written")
    p.add_argument("--config", required=True, help="robot configuration: built-in name or .toml file")
    p.add_argument("--duration", type=positive, default=None, metavar="S",
                   help="seconds, whole periods of about 10 s (default 30); with --heat the whole run (default 3 of "
                        "the slowest heated joint's thermal time constants each side of the move, at most 600 s, the "
                        "longest a swing plays)")
    p.add_argument("--joints", nargs="+", default=None, metavar="DOF",
                   help="only these joints move (default all); with --heat, only these are heated")
    p.add_argument("--heat", action="store_true",
                   help="a heating run instead, for the thermal constants: hold a pose gravity loads, then rest "
                        "where the arm hangs while the windings cool; every winding predicted within half its "
                        "headroom (temperature limit less 25 °C) on the configured thermal constants")
    p.add_argument("--harmonics", type=count(2, what="harmonics"), default=5, metavar="N",
                   help="harmonics per joint (default 5)")
    p.add_argument("--margin", type=float, default=0.1, metavar="F",
                   help="fraction of each joint's range kept clear at both ends (default 0.1)")
    p.add_argument("--seed", type=count(0, what="seed"), default=0, help="the optimiser's start (default 0)")
    p.add_argument("-o", "--out", default=DEFAULT_OUT, metavar="CSV",
                   help=f"trajectory CSV to write (a file; default {DEFAULT_OUT})")


def run(args) -> int:
    return run_excite(args.config, args.duration, args.joints, Path(args.out), harmonics=args.harmonics,
                      margin=args.margin, seed=args.seed, heat=args.heat, say=say)
