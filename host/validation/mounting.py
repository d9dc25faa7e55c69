"""Where a dof's servo sits in a model file and how another one is mounted there: a dof's housing
(`Housing`, `housings`), its shaft line and output flange, and the model's tables with the chosen
servos mounted (`mount`, `mounted`) — horn face kept, the housing growing behind it (the rules:
validation/sizing.py's docstring, "Where a servo sits")."""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..model import builtin_models
from ..model.files import read_toml
from ..model.modelfile import parts, resolved_body
from ..model.rotations import rpy_to_matrix
from ..model.shapes import BOX_FROM_ELLIPSOID
from ..model.tree import ModelError
from .servos import SizingError, catalogue


@dataclass(frozen=True)
class Housing:
    """Where a dof's servo sits in a model file: the body holding the dof (index, and the dof's
    index in it), the body carrying its housing (None: the fixed base) and the housing's solid
    there (None: the model has none; one is added)."""
    dof: str
    body: int
    dof_index: int
    carrier: int | None
    solid: int | None
    original: str | None       # the servo the model has there (its motor or housing part)


def load_model_data(ref: str) -> tuple[dict, Path | None, str]:
    """A model file's tables with every `from` body resolved, its folder and its name (a built-in
    name or a .toml path); SizingError for anything else."""
    path = builtin_models().get(str(ref), Path(ref))
    if path.suffix.lower() != ".toml":
        raise SizingError(f"{ref}: sizing mounts servos as parts of a servodyn model file (.toml): give a "
                          f"built-in model ({', '.join(builtin_models())}) or a .toml file")
    try:
        data = read_toml(path, ModelError)
    except FileNotFoundError:
        raise SizingError(f"{ref}: no such file, and not a built-in model ({', '.join(builtin_models())})") from None
    bodies = data.get("body")
    if not isinstance(bodies, list):
        raise SizingError(f"{ref}: needs [[body]] tables")
    data["body"] = [_as_lists(resolved_body(b, path.parent)) if isinstance(b, dict) else b for b in bodies]
    return data, path.parent, str(path)


def _as_lists(body: dict) -> dict:
    body = dict(body)
    for key in ("dof", "solid"):
        if isinstance(body.get(key), dict):
            body[key] = [body[key]]
    return body


def housings(data: dict) -> list[Housing]:
    """Each dof's housing in the model file's tables, in model dof order."""
    index = {b["name"]: i for i, b in enumerate(data["body"])}
    servos = catalogue("any")
    used: set[tuple[int, int]] = set()
    found = []
    for i, body in enumerate(data["body"]):
        if body.get("free") or body.get("ball"):
            raise SizingError(f"body '{body['name']}': sizing drives one servo per dof; a free or ball joint has none")
        carrier = index.get(body.get("parent", "base"))
        for j, dof in enumerate(body.get("dof", [])):
            motor = dof.get("motor")
            solid = None
            if carrier is not None:
                solids = data["body"][carrier].get("solid", [])
                wanted = [k for k, s in enumerate(solids) if (carrier, k) not in used and s.get("part") is not None
                          and (s["part"] == motor if motor else s["part"] in servos)]
                solid = wanted[0] if wanted else None
                if solid is not None:
                    used.add((carrier, solid))
            original = motor or (data["body"][carrier]["solid"][solid]["part"] if solid is not None else None)
            found.append(Housing(dof["name"], i, j, carrier, solid, original))
    return found


def _centroid(part: str) -> float:
    """Along the part's local z, from where `pos` puts it to its centroid (a cylinder's back face)."""
    entry = parts()[part]
    return float(entry["length"]) / 2 if entry["type"] == "cylinder" else 0.0


def _flange(part: str) -> float:
    """Along the part's local z (its output shaft), from where `pos` puts it to its output flange:
    a round motor's length (pos is its back face), a box servo's D/2 (pos is its centre)."""
    entry = parts()[part]
    if entry["type"] == "cylinder":
        return float(entry["length"])
    return float(entry["semi_axes"][2]) * BOX_FROM_ELLIPSOID / 2


def _shaft_offset_scale(part: str) -> float:
    """What a housing's centre lies off its shaft line in proportion to: a box servo's height H
    (its shaft towards one end of it), 0 for a round motor (coaxial)."""
    entry = parts()[part]
    return 0.0 if entry["type"] == "cylinder" else float(entry["semi_axes"][1]) * BOX_FROM_ELLIPSOID


def shaft_line(data: dict, housing: Housing) -> tuple[np.ndarray, np.ndarray]:
    """(a point, the unit direction) of the dof's axis in its carrier's frame: the line through
    the joint's origin along the dof's axis, where the housing's shaft lies."""
    child = data["body"][housing.body]
    R = rpy_to_matrix(child.get("rpy", [0.0, 0.0, 0.0]))
    axis = R @ np.asarray(child["dof"][housing.dof_index]["axis"], dtype=float)
    return np.asarray(child.get("pos", [0.0, 0.0, 0.0]), dtype=float), axis / np.linalg.norm(axis)


def flange_centre(data: dict, housing: Housing) -> np.ndarray:
    """Where the housing's output flange meets its shaft axis, in the carrier's frame: what
    mounting another servo keeps."""
    solid = data["body"][housing.carrier]["solid"][housing.solid]
    R = rpy_to_matrix(solid.get("rpy", [0.0, 0.0, 0.0]))
    pos = np.asarray(solid.get("pos", [0.0, 0.0, 0.0]), dtype=float)
    point, axis = shaft_line(data, housing)
    face = pos + R @ np.array([0.0, 0.0, _flange(solid["part"])])
    return point + axis * float(axis @ (face - point))


def mount(data: dict, housing: Housing, servo: str | None) -> None:
    """Put `servo`'s part in the housing's place and name it as the dof's motor (tables edited in
    place: plain dicts or a tomlkit document). servo None: the dof's own rotor left out (armature 0),
    the housing untouched — what its joint's torque is without its own servo."""
    dof = data["body"][housing.body]["dof"][housing.dof_index]
    dof.pop("motor", None)
    dof.pop("armature", None)
    if servo is None:
        dof["armature"] = 0.0
        return
    if parts()[servo]["armature"] is None:
        raise SizingError(f"{servo}: no armature in parts.toml (its rotor inertia unknown, not 0)")
    dof["motor"] = servo
    if housing.carrier is None:
        return                          # on the fixed base: its mass moves nothing
    carrier = data["body"][housing.carrier]
    if housing.solid is not None:
        solid = carrier["solid"][housing.solid]
        old = solid["part"]
        R = rpy_to_matrix(solid.get("rpy", [0.0, 0.0, 0.0]))
        pos = np.asarray(solid.get("pos", [0.0, 0.0, 0.0]), dtype=float)
        point, axis = shaft_line(data, housing)
        # along the shaft: the flange stays; across it: the centre's offset scales with the housing
        along = R @ np.array([0.0, 0.0, _flange(old) - _flange(servo)])
        off = (pos - point) - axis * float(axis @ (pos - point))
        scale = _shaft_offset_scale(old)
        across = off * (_shaft_offset_scale(servo) / scale - 1.0) if scale > 0 else np.zeros(3)
        solid["part"] = servo
        solid["pos"] = [float(x) for x in pos + along + across]
        return
    child = data["body"][housing.body]
    R = rpy_to_matrix(child.get("rpy", [0.0, 0.0, 0.0]))
    pos = np.asarray(child.get("pos", [0.0, 0.0, 0.0]), dtype=float) - R @ np.array([0.0, 0.0, _centroid(servo)])
    added = {"part": servo, "pos": [float(x) for x in pos], "rpy": [float(x) for x in child.get("rpy", [0.0] * 3)]}
    if "solid" not in carrier:
        carrier["solid"] = []
    carrier["solid"].append(added)


def mounted(data: dict, places: list[Housing], choice: dict, bare: str | None = None) -> dict:
    """A copy of the model tables with the chosen servos mounted (and `bare`'s own rotor left out)."""
    out = copy.deepcopy(data)
    # added housings append solids: fill the modelled ones first so solid indices hold
    for housing in sorted(places, key=lambda h: h.solid is None):
        if housing.dof in choice:
            mount(out, housing, choice[housing.dof])
        elif housing.dof == bare:
            mount(out, housing, None)
    return out
