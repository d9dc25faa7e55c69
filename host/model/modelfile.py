"""servodyn's own model file: TOML, body by body, with inertias from solid primitives (paper §2).

See host/model/builtin/README.md for the schema; every error names the body and the key.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .. import _core
from .files import read_toml
from .tree import Body, Dof, Model, ModelError, Solid
from .rotations import rpy_to_matrix

SOLID_DIMS = {
    "cylinder": ("radius", "length"),
    "sphere": ("radius",),
    "ellipsoid": ("semi_axes",),
    "frustum": ("r0", "r1", "length"),
}


def _volume(kind: str, dims: list[float]) -> float:
    if kind == "cylinder":
        return math.pi * dims[0] ** 2 * dims[1]
    if kind == "sphere":
        return 4.0 / 3.0 * math.pi * dims[0] ** 3
    if kind == "ellipsoid":
        return 4.0 / 3.0 * math.pi * dims[0] * dims[1] * dims[2]
    r0, r1, length = dims
    return math.pi * length * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0


def _vector(table: dict, key: str, where: str, default=(0.0, 0.0, 0.0), size: int = 3) -> np.ndarray:
    value = table.get(key, default)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"{where}: '{key}' must be a list of {size} numbers") from None
    if arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise ModelError(f"{where}: '{key}' must be a list of {size} finite numbers, got {value!r}")
    return arr


def _number(table: dict, key: str, where: str, default=None) -> float:
    if key not in table:
        if default is None:
            raise ModelError(f"{where}: '{key}' is missing")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ModelError(f"{where}: '{key}' must be a finite number, got {value!r}")
    return float(value)


def combine(parts: list[tuple[float, np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, com and inertia about the com of rigidly joined parts (mass, com, inertia about own com)."""
    mass = sum(m for m, _, _ in parts)
    if mass <= 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, I in parts:
        d = c - com
        inertia += I + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


def _solid(solid: dict, where: str, total_mass: float | None):
    """((mass, com, inertia about com) in the body frame, the solid's shape) of one solid."""
    kind = solid.get("type")
    if kind not in SOLID_DIMS:
        raise ModelError(f"{where}: 'type' must be one of {', '.join(SOLID_DIMS)}, got {kind!r}")
    if kind == "ellipsoid":
        dims = list(_vector(solid, "semi_axes", where, default=None))
    else:
        dims = [_number(solid, key, where) for key in SOLID_DIMS[kind]]
    if min(dims) <= 0:
        raise ModelError(f"{where}: dimensions must be positive, got {dims}")
    given = [k for k in ("mass", "mass_fraction", "density") if k in solid]
    if len(given) != 1:
        raise ModelError(f"{where}: give exactly one of 'mass', 'mass_fraction', 'density'")
    if given[0] == "mass":
        mass = _number(solid, "mass", where)
    elif given[0] == "mass_fraction":
        if total_mass is None:
            raise ModelError(f"{where}: 'mass_fraction' needs a top-level 'total_mass'")
        mass = _number(solid, "mass_fraction", where) * total_mass
    else:
        mass = _number(solid, "density", where) * _volume(kind, dims)
    if mass <= 0:
        raise ModelError(f"{where}: the mass must be positive, got {mass}")
    # the core's argument order is the SOLID_DIMS order: cylinder (radius, length), frustum (r0, r1, length)
    com_z, I6 = _core.solid_inertia(kind, mass, dims)
    I_local = np.array([[I6[0], I6[3], I6[4]], [I6[3], I6[1], I6[5]], [I6[4], I6[5], I6[2]]])
    R = rpy_to_matrix(_vector(solid, "rpy", where))
    pos = _vector(solid, "pos", where)
    draw = solid.get("draw", "")
    if draw not in ("", "box") or (draw and kind != "ellipsoid"):
        raise ModelError(f"{where}: 'draw' can only be \"box\", on an ellipsoid (a box of the same inertia)")
    shape = Solid(kind, tuple(dims), pos, R, mass, draw)
    return (mass, pos + R @ np.array([0.0, 0.0, com_z]), R @ I_local @ R.T), shape


def model_from_dict(data: dict, origin: str = "model") -> Model:
    """Build a Model from the parsed contents of a model file."""
    total_mass = _number(data, "total_mass", origin, default=-1.0)
    total_mass = total_mass if total_mass > 0 else None
    gravity = _vector(data, "gravity", origin, default=(0.0, 0.0, -9.81))
    bodies_in = data.get("body")
    if not isinstance(bodies_in, list) or not bodies_in:
        raise ModelError(f"{origin}: needs at least one [[body]]")
    index: dict[str, int] = {}
    bodies: list[Body] = []
    for n, entry in enumerate(bodies_in):
        name = entry.get("name")
        if not isinstance(name, str) or not name:
            raise ModelError(f"{origin}: body #{n + 1} needs a 'name'")
        where = f"body '{name}'"
        parent_name = entry.get("parent", "base")
        if parent_name != "base" and parent_name not in index:
            raise ModelError(f"{where}: parent '{parent_name}' is not an earlier body")
        dofs = []
        for k, dof in enumerate(entry.get("dof", [])):
            dname = dof.get("name")
            if not isinstance(dname, str) or not dname:
                raise ModelError(f"{where}: dof #{k + 1} needs a 'name'")
            dwhere = f"dof '{dname}'"
            dofs.append(Dof(dname, _vector(dof, "axis", dwhere, default=None),
                            _number(dof, "lower", dwhere, default=-math.inf),
                            _number(dof, "upper", dwhere, default=math.inf)))
        solids = entry.get("solid", [])
        solids = [solids] if isinstance(solids, dict) else list(solids)
        shaped = [_solid(s, f"{where} solid", total_mass) for s in solids]
        parts = [part for part, _ in shaped]
        if "inertial" in entry:
            inertial = entry["inertial"]
            iwhere = f"{where} inertial"
            I6 = _vector(inertial, "inertia", iwhere, default=None, size=6)
            parts.append((_number(inertial, "mass", iwhere), _vector(inertial, "com", iwhere),
                          np.array([[I6[0], I6[3], I6[4]], [I6[3], I6[1], I6[5]], [I6[4], I6[5], I6[2]]])))
        if not parts:
            raise ModelError(f"{where}: needs a [body.solid] or a [body.inertial]")
        mass, com, inertia = combine(parts)
        bodies.append(Body(name=name, parent=index.get(parent_name, -1),
                           pos=_vector(entry, "pos", where), rot=rpy_to_matrix(_vector(entry, "rpy", where)),
                           dofs=dofs, mass=mass, com=com, inertia=inertia,
                           solids=[shape for _, shape in shaped]))
        index[name] = n
    return Model(bodies, name=str(data.get("name", origin)), gravity=gravity,
                 description=str(data.get("description", "")), source=str(data.get("source", "")))


def load_model_file(path: str | Path) -> Model:
    path = Path(path)
    try:
        data = read_toml(path, ModelError)
    except FileNotFoundError:
        raise ModelError(f"{path}: no such file") from None
    return model_from_dict(data, origin=path.stem)
