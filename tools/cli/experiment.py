"""`servodyn experiment NAME --out DIR`: one of the paper's experiments."""

from __future__ import annotations

from pathlib import Path

from ..experiments import EXPERIMENTS
from .common import describe


def add_arguments(p) -> None:
    describe(p, "The paper's experiments (section 4): pendulum (Fig. 5), still (Fig. 6), swing (Figs. 7-8), and "
             "numbers (tracking and energy drift against control mode, step ratio and integrator). Writes CSV, PNG "
             "and summary.json.", "servodyn experiment pendulum --out out/pendulum")
    p.add_argument("name", choices=list(EXPERIMENTS))
    p.add_argument("-o", "--out", default=None, metavar="DIR", help="output folder (default out/<name>)")


def run(args) -> int:
    if args.out is None:
        args.out = f"out/{args.name}"
    EXPERIMENTS[args.name](Path(args.out))
    return 0
