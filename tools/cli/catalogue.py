"""`servodyn list` and `servodyn models`: what ships, by the names the other verbs take (data, on stdout)."""

from __future__ import annotations

import json

from ...control.motion import builtin_motions
from ...hal.config import builtin_configs, load_config
from ...model import builtin_models, load_model
from ...model.files import read_toml
from ...model.tree import ModelError
from .common import Verb, describe


def catalogue() -> dict:
    """The built-in models, configurations and motions, with what a newcomer picks them by."""
    models = []
    for name in builtin_models():
        model = load_model(name)
        models.append({"name": name, "bodies": model.nbody, "dofs": model.nq, "mass_kg": round(model.total_mass, 3)})
    configs = []
    for name in builtin_configs():
        config = load_config(name)
        configs.append({"name": name, "model": config.model_ref,
                        "buses": {bus.name: bus.kind for bus in config.buses.values()},
                        "servos": sorted({j.servo.name for j in config.joints}),
                        "control_period_s": config.control_period})
    motions = []
    for name, path in builtin_motions().items():
        data = read_toml(path, ModelError)
        frames = data.get("keyframe", [])
        times = [f.get("t") for f in frames if isinstance(f, dict)]
        motions.append({"name": name, "model": data.get("model"), "keyframes": len(frames),
                        "duration_s": float(times[-1] - times[0]) if len(times) > 1 else 0.0})
    return {"models": models, "configurations": configs, "motions": motions}


def _list_arguments(p) -> None:
    describe(p, "List what servodyn ships: models, robot configurations and motions, each by the name the other "
             "commands take.", "servodyn list --json")
    p.add_argument("--json", action="store_true", help="as JSON, for scripts")


def _list(args) -> int:
    found = catalogue()
    if args.json:
        print(json.dumps(found, indent=1))
        return 0
    print("models (servodyn torques/export/view MODEL):")
    for m in found["models"]:
        print(f"  {m['name']:<16} {m['bodies']:>3} bodies {m['dofs']:>3} dofs {m['mass_kg']:>7.2f} kg")
    print("configurations (servodyn swing --config CONFIG, validate CONFIG MOTION, view CONFIG):")
    for c in found["configurations"]:
        buses = ", ".join(f"{name} ({kind})" for name, kind in c["buses"].items())
        print(f"  {c['name']:<16} model {c['model']}, bus {buses}, {', '.join(c['servos'])}, "
              f"{c['control_period_s'] * 1e3:g} ms period")
    print("motions (--motion NAME; or a keyframe .toml or trajectory .csv file):")
    for m in found["motions"]:
        print(f"  {m['name']:<16} {m['keyframes']} keyframes, {m['duration_s']:g} s, for model {m['model']}")
    return 0


def _models_arguments(p) -> None:
    describe(p, "List the built-in models: bodies, dofs, mass and dof names.", "servodyn models")


def _models(args) -> int:
    print(f"{'name':<12} {'bodies':>6} {'dofs':>5} {'mass kg':>8}  dofs")
    for name in builtin_models():
        model = load_model(name)
        print(f"{name:<12} {model.nbody:>6} {model.nq:>5} {model.total_mass:>8.2f}  {', '.join(model.dof_names)}")
    return 0


list_ = Verb(_list_arguments, _list)
models = Verb(_models_arguments, _models)
