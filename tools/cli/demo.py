"""`servodyn demo`: the torque profile of a sample reach (what `make demo` runs)."""

from __future__ import annotations

from pathlib import Path

from ..demo import run_demo
from .common import describe, out_folder


def add_arguments(p) -> None:
    describe(p, "Torque profile of a sample reach of the built-in arm: CSV and PNG.", "servodyn demo --out out/demo")
    p.add_argument("--model", default="human_arm", help="model (default human_arm)")
    out_folder(p, "out/demo")


def run(args) -> int:
    run_demo(args.model, Path(args.out))
    return 0
