"""`servodyn export MODEL OUT.urdf`: a model as URDF."""

from __future__ import annotations

from pathlib import Path

from ...model import load_model
from .common import CliError, describe, say


def add_arguments(p) -> None:
    describe(p, "Write a model (built-in or file) as URDF, with its solids as visuals.",
             "servodyn export human_arm arm.urdf")
    p.add_argument("model", help="built-in model name, .urdf or .toml file")
    p.add_argument("output", metavar="OUT.urdf", help="URDF file to write")


def run(args) -> int:
    model = load_model(args.model)
    out = Path(args.output)
    if out.suffix.lower() != ".urdf":
        raise CliError(f"{out}: export writes URDF; name the file .urdf")
    out.parent.mkdir(parents=True, exist_ok=True)
    model.to_urdf(out)
    say(f"{model.name}: {model.nbody} bodies, {model.nq} dofs -> {out}")
    return 0
