"""servodyn's own model file: TOML, body by body, with inertias from solid primitives (paper §2).

See host/model/builtin/README.md for the schema; every error names the body and the key.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .. import _core
from .files import builtin_models, read_toml, string_key
from .tree import Body, Dof, Model, ModelError, Solid, combine
from .rotations import rpy_to_matrix
from .shapes import BOX_FROM_ELLIPSOID

PARTS_FILE = Path(__file__).parent / "parts.toml"
_parts: dict | None = None

SOLID_DIMS = {
    "cylinder": ("radius", "length"),
    "sphere": ("radius",),
    "ellipsoid": ("semi_axes",),
    "frustum": ("r0", "r1", "length"),
}



def _shown(name) -> str:
    """A name from the file as an error shows it: on one line (a newline in it escaped)."""
    return str(name).encode("unicode_escape").decode("ascii")

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


def _table(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise ModelError(f"{where} must be a table, got {value!r}")
    return value


def _tables(value, where: str) -> list[dict]:
    """An array of tables ([[body]], [[body.dof]]); one table is taken as an array of one."""
    items = [value] if isinstance(value, dict) else value
    if not isinstance(items, list):
        raise ModelError(f"{where} must be an array of tables, got {value!r}")
    return [_table(item, f"{where} #{k + 1}") for k, item in enumerate(items)]


def parts() -> dict[str, dict]:
    """The bought parts a model file may place (parts.toml): name -> its solid's keys and source."""
    global _parts
    if _parts is None:
        table = read_toml(PARTS_FILE, ModelError).get("part", {})
        # armature None: not known (never 0, which would make the part look lighter to drive)
        _parts = {name: _part_solid(name, entry)
                  | {"armature": float(entry["armature"]) if "armature" in entry else None}
                  for name, entry in table.items()}
    return _parts


def _dof_armature(dof: dict, where: str) -> tuple[float, str]:
    """(armature, motor) of a [[body.dof]]: its `motor` part's armature (rotor inertia x gear
    ratio², at the output), or its own `armature`, 0 by default."""
    if "motor" not in dof:
        return _number(dof, "armature", where, default=0.0), ""
    name = dof["motor"]
    catalogue = parts()
    if "armature" in dof:
        raise ModelError(f"{where}: give 'motor' or 'armature', not both (the motor brings its armature)")
    if not isinstance(name, str) or name not in catalogue or not (catalogue[name]["armature"] or 0.0) > 0:
        motors = [k for k, v in catalogue.items() if (v["armature"] or 0.0) > 0]
        raise ModelError(f"{where}: unknown motor {name!r} (parts with an armature: {', '.join(motors)})")
    return catalogue[name]["armature"], name


def _part_solid(name: str, entry: dict) -> dict:
    """A catalogue entry as the keys of a [[body.solid]]: a box is the ellipsoid of its inertia."""
    solid = {"mass": entry["mass"], "source": entry["source"]}
    if entry["type"] == "box":
        sides = np.asarray(entry["sides"], dtype=float)
        solid.update(type="ellipsoid", draw="box", semi_axes=list(sides / BOX_FROM_ELLIPSOID))
    else:
        solid.update({k: entry[k] for k in ("type",) + SOLID_DIMS[entry["type"]]})
    return solid


def _placed_part(solid: dict, where: str) -> dict:
    """A solid that says `part = NAME`: the part's type, size and mass, at the solid's pos and rpy."""
    name = solid["part"]
    catalogue = parts()
    if not isinstance(name, str) or name not in catalogue:
        raise ModelError(f"{where}: unknown part {name!r} (parts: {', '.join(catalogue)})")
    extra = sorted(set(solid) - {"part", "pos", "rpy"})
    if extra:
        raise ModelError(f"{where}: part '{name}' brings its own type, size and mass; "
                         f"give it only pos and rpy, not {', '.join(extra)}")
    return {k: v for k, v in catalogue[name].items() if k not in ("source", "armature")} | solid


def _solid(solid: dict, where: str, total_mass: float | None):
    """((mass, com, inertia about com) in the body frame, the solid's shape) of one solid."""
    if "part" in solid:
        solid = _placed_part(solid, where)
    kind = solid.get("type")
    if not isinstance(kind, str) or kind not in SOLID_DIMS:
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
    with np.errstate(all="ignore"):        # a huge size or position: refused below, not warned of
        part = (mass, pos + R @ np.array([0.0, 0.0, com_z]), R @ I_local @ R.T)
    return _finite(part, where), shape


def _finite(part: tuple[float, np.ndarray, np.ndarray], where: str) -> tuple[float, np.ndarray, np.ndarray]:
    """A (mass, com, inertia) whose every number is finite, or ModelError: sizes and positions
    valid each on its own can still overflow a solid's or a body's inertia (1e154 m squared)."""
    mass, com, inertia = part
    if not (math.isfinite(mass) and np.isfinite(com).all() and np.isfinite(inertia).all()):
        raise ModelError(f"{where}: its mass, centre of mass or inertia is not finite (a size or position too large)")
    return part


def _other_file(name, where: str, folder: Path | None) -> Path:
    if not isinstance(name, str) or not name:
        raise ModelError(f"{where}: 'from' must name a model file, got {name!r}")
    builtins = builtin_models()
    if name in builtins:
        return builtins[name]
    path = (folder or Path.cwd()) / name
    if not path.is_file():
        raise ModelError(f"{where}: 'from' names {name!r}, neither a built-in model "
                         f"({', '.join(builtins)}) nor a file beside this one")
    return path


def _body_from(entry: dict, where: str, folder: Path | None, chain: tuple[Path, ...] = ()) -> dict:
    """A body that says `from = FILE`: the body of the same name in that model file (a built-in
    name, or a path relative to this file), with this entry's own keys in place of its keys."""
    path = _other_file(entry["from"], where, folder)
    if path in chain:
        raise ModelError(f"{where}: 'from' goes round in a circle through {path.name}")
    bodies = read_toml(path, ModelError).get("body", [])
    found = [b for b in bodies if isinstance(b, dict) and b.get("name") == entry.get("name")]
    if not found:
        raise ModelError(f"{where}: {path.stem} has no body '{entry.get('name')}'")
    body = found[0]
    if "from" in body:
        body = _body_from(body, f"{path.stem}: body '{body['name']}'", path.parent, chain + (path,))
    return body | {k: v for k, v in entry.items() if k != "from"}


def resolved_body(entry: dict, folder: Path | None) -> dict:
    """A [[body]] table whole: itself, or for one that says `from = FILE` the body it takes from that
    file with its own keys in place (what the model is built from; sizing edits its solids)."""
    return _body_from(entry, f"body '{entry.get('name')}'", folder) if "from" in entry else entry


def model_from_dict(data: dict, origin: str = "model", folder: Path | None = None) -> Model:
    """Build a Model from the parsed contents of a model file (folder: where it lies, for the
    files its bodies name with `from`)."""
    total_mass = _number(data, "total_mass", origin, default=-1.0)
    total_mass = total_mass if total_mass > 0 else None
    gravity = _vector(data, "gravity", origin, default=(0.0, 0.0, -9.81))
    bodies_in = data.get("body")
    if not isinstance(bodies_in, list) or not bodies_in:
        raise ModelError(f"{origin}: needs at least one [[body]]")
    index: dict[str, int] = {}
    bodies: list[Body] = []
    for n, entry in enumerate(_tables(bodies_in, f"{origin}: body")):
        name = entry.get("name")
        if not isinstance(name, str) or not name:
            raise ModelError(f"{origin}: body #{n + 1} needs a 'name'")
        where = f"body '{_shown(name)}'"
        if "from" in entry:
            entry = _body_from(entry, where, folder)
        parent_name = entry.get("parent", "base")
        if not isinstance(parent_name, str) or (parent_name != "base" and parent_name not in index):
            raise ModelError(f"{where}: parent '{_shown(parent_name)}' is not an earlier body")
        dofs = []
        for k, dof in enumerate(_tables(entry.get("dof", []), f"{where}: dof")):
            dname = dof.get("name")
            if not isinstance(dname, str) or not dname:
                raise ModelError(f"{where}: dof #{k + 1} needs a 'name'")
            dwhere = f"dof '{dname}'"
            armature, motor = _dof_armature(dof, dwhere)
            dofs.append(Dof(dname, _vector(dof, "axis", dwhere, default=None),
                            _number(dof, "lower", dwhere, default=-math.inf),
                            _number(dof, "upper", dwhere, default=math.inf), armature, motor))
        solids = _tables(entry.get("solid", []), f"{where}: solid")
        shaped = [_solid(s, f"{where} solid", total_mass) for s in solids]
        parts = [part for part, _ in shaped]
        if "inertial" in entry:
            inertial = _table(entry["inertial"], f"{where}: inertial")
            iwhere = f"{where} inertial"
            I6 = _vector(inertial, "inertia", iwhere, default=None, size=6)
            parts.append((_number(inertial, "mass", iwhere), _vector(inertial, "com", iwhere),
                          np.array([[I6[0], I6[3], I6[4]], [I6[3], I6[1], I6[5]], [I6[4], I6[5], I6[2]]])))
        if not parts:
            raise ModelError(f"{where}: needs a [body.solid] or a [body.inertial]")
        with np.errstate(all="ignore"):
            mass, com, inertia = _finite(combine(parts), where)
        bodies.append(Body(name=name, parent=index.get(parent_name, -1),
                           pos=_vector(entry, "pos", where), rot=rpy_to_matrix(_vector(entry, "rpy", where)),
                           dofs=dofs, mass=mass, com=com, inertia=inertia,
                           solids=[shape for _, shape in shaped]))
        index[name] = n
    return Model(bodies, name=string_key(data, "name", origin, ModelError, origin, empty=False), gravity=gravity,
                 description=string_key(data, "description", "", ModelError, origin),
                 source=string_key(data, "source", "", ModelError, origin))


def load_model_file(path: str | Path) -> Model:
    path = Path(path)
    try:
        data = read_toml(path, ModelError)
    except FileNotFoundError:
        raise ModelError(f"{path}: no such file") from None
    return model_from_dict(data, origin=path.stem, folder=path.parent)
