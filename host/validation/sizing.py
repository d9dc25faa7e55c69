"""Sizing: a servo per joint from the catalogue such that every motion passes every check of the
validator, with each chosen servo's housing and rotor mounted on the model.

The catalogue is every backend's (hal: the Dynamixel SERVOS, the CAN MOTORS); a servo is a
candidate when the backend can drive it by its torque (ServoSpec.current_control), the supply
voltage lies in its supply range (ServoSpec.supply_range, or the span of its data sheet's rows
where none is published), and its housing is a part (model/parts.toml: its mass and size). Each
joint is driven at the horn (gear_ratio 1), as the built-in configurations do.

Where a servo sits. A model names its servos as parts: the servo of a dof drives the body that
holds the dof and is bolted to the body before it, its parent (host/model/builtin/README.md), so
its housing is a solid of the parent naming that part, and the dof names it as its `motor` (its
armature). Sizing puts the candidate's part in that solid's place, its horn face where the old
one's horn face was and its shaft along the same axis, and names it as the dof's motor (its
armature: the part's). A dof whose model has no housing for it gets one at its
joint's origin, on the parent; a dof on the fixed base carries its housing on the base.
A housing's place is its output flange: a differently sized servo is mounted with its horn face
(output flange) where the old one's was, so what is bolted to the horn keeps its geometry; the
housing grows or shrinks behind it. Across the shaft, its centre keeps its side of the shaft
line, off it in proportion to the housing's height (a box servo's shaft sits off its centre
along H, the replica's H/4), on it for a round motor (coaxial). A part with no armature in
parts.toml is never a candidate: an unknown rotor inertia is not 0.

Why from the hand inwards, and when it is optimal. The torque of a dof depends on the masses
outboard of it — its body's subtree — and on its own servo's armature, not on anything inboard;
the per-joint checks (position, speed, torque_speed, current, temperature, command_range) of a
joint depend only on its torque and its own servo. So with the dofs taken in reverse model
order (children before parents, in a chain or a tree), when a dof is sized every servo whose
housing it carries is already chosen, and its candidates are checked exactly. For the mass
objective, choose at each dof the lightest candidate that passes. This is optimal when a joint's
worst ratio does not fall as the servos outboard of it get lighter (mass monotone): then by
induction from the hand every dof's greedy servo is no heavier than that dof's servo in any
passing assignment (the outboard servos are no heavier, so whatever passed there passes here),
which makes the total the least. The assumption can fail where an outboard mass counterbalances
(a housing on the far side of an axis lowers that axis's gravity torque in some poses), or where
a lighter servo is larger and carries more inertia; the brute-force agreement in
tests/test_size.py is the check on small cases. The robot-wide checks (supply, bus) depend on
every choice and are checked on the result: the bus by the control period chosen for the joint
count (at most BUS_SHARE of it on the wire), the supply by validating the result.

The margin objective — the largest reserve, the least of every joint's worst ratio — is not
greedy per joint (a strong wrist servo's mass costs the shoulder its margin). Under the same
assumption, "some assignment keeps every ratio within r" is decided exactly by the mass greedy at
margin r, and it is monotone in r, so a bisection on r finds the least reachable worst ratio
(to MARGIN_TOLERANCE) and the lightest set that reaches it.

When no set passes, the result names the dof and check that ruled it out (its candidate nearest
passing) and, by the validator's fit scan (fit.smallest_passing_scale), the smallest time scale at
which the greedy finds a set, and that set.
"""

from __future__ import annotations

import copy
import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from ..control.timing import SMALL_TIME_STEP
from ..control.trajectory import Trajectory
from ..errors import ServodynError
from ..hal.backend import backend, servo_catalogue
from ..hal.config import config_from_dict
from ..model import builtin_models
from ..model.files import read_toml
from ..model.modelfile import model_from_dict, parts, resolved_body
from ..model.shapes import BOX_FROM_ELLIPSOID
from ..model.rotations import rpy_to_matrix
from ..model.tree import ModelError
from .checks import CHECKS, check
from .fit import FIT_GRID, smallest_passing_scale
from .limits import Limits
from ..hal.thermal import AMBIENT

SIZING_MARGIN = 0.8     # the share of each limit a sized servo may use by default: 20 % kept in reserve
FAMILIES = ("dynamixel", "can", "any")
OBJECTIVES = ("mass", "margin")
JOINT_CHECKS = tuple(c for c in CHECKS if c not in ("supply", "bus"))   # a joint's own checks
SERVO_CHECKS = tuple(c for c in JOINT_CHECKS if c != "position")        # those a servo changes
BUS_SHARE = 0.8             # of the control period one tick's transactions may take on the wire
PERIODS = (0.001, 0.002, 0.0025, 0.005, 0.01)   # s: control periods that divide the ID period
MARGIN_TOLERANCE = 0.01     # relative width the margin objective's bisection stops at
SIZE_FIT_TOLERANCE = 0.01   # relative width of the time-scale scan when nothing passes
BUS_NAMES = {"dynamixel": "arm", "can": "can"}   # a sized configuration's bus of each kind (its table: the backend's)


class SizingError(ServodynError, ValueError):
    """Input sizing cannot work with; one line."""


# ---------------------------------------------------------------------------- the catalogue

def rated_span(servo) -> tuple[float, float]:
    """V: the supply range the data sheet allows, or the span of its rated rows where none is given."""
    if servo.supply_range is not None:
        return servo.supply_range
    volts = [servo.nominal_voltage, *(row[0] for row in servo.ratings)]
    return min(volts), max(volts)


def unusable(servo, voltage: float) -> str | None:
    """Why sizing never picks `servo` at this supply voltage, or None."""
    if not servo.current_control:
        return "no current control mode (the backend drives every joint by its torque)"
    low, high = rated_span(servo)
    if not low <= voltage <= high:
        return f"{voltage:g} V is outside its supply range, {low:g} to {high:g} V"
    if servo.name not in parts():
        return "no housing in parts.toml (mass and size unknown)"
    if parts()[servo.name]["armature"] is None:
        return "no armature in parts.toml (its rotor inertia unknown, not 0)"
    return None


def catalogue(family: str) -> dict:
    """The servos of a family by name (every backend's for 'any')."""
    if family not in FAMILIES:
        raise SizingError(f"no servo family {family!r} (the families: {', '.join(FAMILIES)})")
    kinds = ("dynamixel", "can") if family == "any" else (family,)
    found = {}
    for kind in kinds:
        found.update(servo_catalogue(kind))
    return found


def supply_voltages(family: str) -> list[float]:
    """The supply voltages worth trying when none is given: each servo's nominal voltage."""
    return sorted({s.nominal_voltage for s in catalogue(family).values() if s.current_control})


def part_mass(name: str) -> float:
    return float(parts()[name]["mass"])


# ---------------------------------------------------------------------------- the model's housings

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


# ---------------------------------------------------------------------------- configurations

def config_data(name: str, model_ref: str, dofs, choice: dict, voltage: float, period: float,
                servos: dict) -> dict:
    """A configuration's tables: the chosen servos at the horn on one bus per kind, ids from 1 in
    model order, the supply voltage and the control period."""
    kinds = [servos[choice[d]].kind for d in dofs]
    buses = {BUS_NAMES[k]: backend(k).new_bus() for k in dict.fromkeys(kinds)}
    joints, ids = [], {}
    for dof, kind in zip(dofs, kinds):
        bus = BUS_NAMES[kind]
        ids[bus] = ids.get(bus, 0) + 1
        joints.append({"dof": dof, "bus": bus, "id": ids[bus], backend(kind).device_key: choice[dof], "direction": 1,
                       "gear_ratio": 1.0})
    data = {"name": name, "model": model_ref, "bus": buses, "joint": joints, "supply": {"voltage": float(voltage)}}
    if period != SMALL_TIME_STEP:
        data["control"] = {"period": period}
    return data


def control_period(servos: dict, dofs, model_ref: str, base: Path | None) -> float:
    """The shortest of PERIODS whose every bus, all joints on it (the worst case), takes at most
    BUS_SHARE of it on the wire."""
    wire = 0.0
    for kind in sorted({s.kind for s in servos.values()}):
        example = next(s for s in servos.values() if s.kind == kind)
        config = config_from_dict(config_data("bus", model_ref, dofs, {d: example.name for d in dofs}, example.nominal_voltage,
                                              SMALL_TIME_STEP, servos), base=base)
        wire = max(wire, *(seconds for _, seconds, _ in Limits.of(config, example.nominal_voltage).wire))
    return next((p for p in PERIODS if wire <= BUS_SHARE * p), PERIODS[-1])


def _column(limits: Limits, k: int) -> Limits:
    """One joint's limits, the robot-wide ones (supply, bus) left out."""
    arrays = {f.name: getattr(limits, f.name)[[k]] for f in fields(limits)
              if isinstance(getattr(limits, f.name), np.ndarray)}
    return replace(limits, **arrays, supply_current=None, wire=[])


class _Torques:
    """A joint's torques, computed already, where the checks ask a model for them."""

    def __init__(self, tau: np.ndarray):
        self.tau = tau

    def inverse_dynamics(self, q, qd, qdd):
        return self.tau


# ---------------------------------------------------------------------------- one joint's candidates

@dataclass
class Row:
    """One candidate at one joint: its worst check over every motion (ratio / what it allows)."""
    servo: str
    mass_kg: float
    worst_check: str | None = None
    worst_ratio: float | None = None
    score: float = math.inf            # worst ratio / what the check allows: ≤ 1 passes
    motion: str | None = None
    why_not: str | None = None         # unusable: why it is never chosen

    @property
    def passed(self) -> bool:
        return self.why_not is None and self.score <= 1.0


@dataclass
class Problem:
    """What sizing checks against: the model's tables, the motions sampled, the candidates' limits."""
    data: dict
    folder: Path | None
    model_ref: str
    places: list[Housing]
    dofs: tuple[str, ...]
    motions: list                       # MotionPath
    time_scale: float
    voltage: float
    margin: float
    payload: float
    repeat: int
    ambient: float
    period: float
    servos: dict                        # name -> ServoSpec, the family's whole catalogue
    limits: dict = field(default_factory=dict)   # usable name -> Limits, every joint driven by it
    reasons: dict = field(default_factory=dict)  # unusable name -> why
    samples: dict = field(default_factory=dict)  # time scale -> [Trajectory per motion]

    def trajectories(self, scale: float) -> list[Trajectory]:
        if scale not in self.samples:
            self.samples[scale] = [m.at_scale(scale, self.period) for m in self.motions]
        return self.samples[scale]

    def model(self, data: dict):
        model = model_from_dict(data, origin=Path(self.model_ref).stem, folder=self.folder)
        return model.with_payload(self.payload) if self.payload else model


def problem(model_ref: str, motions, *, family: str = "dynamixel", voltage: float, time_scale: float = 1.0,
            margin: float = 1.0, payload: float = 0.0, repeat: int = 1, ambient: float = AMBIENT) -> Problem:
    """Everything sizing needs, checked: the model file, the catalogue at the voltage, the period."""
    data, folder, ref = load_model_data(model_ref)
    places = housings(data)
    model = model_from_dict(data, origin=Path(ref).stem, folder=folder)
    dofs = model.dof_names
    servos = catalogue(family)
    period = control_period(servos, dofs, ref, folder)
    p = Problem(data, folder, ref, places, dofs, list(motions), time_scale, voltage, margin, payload, repeat,
                ambient, period, servos)
    for name, servo in servos.items():
        why = unusable(servo, voltage)
        if why:
            p.reasons[name] = why
            continue
        config = config_from_dict(config_data(name, ref, dofs, {d: name for d in dofs}, voltage, period, servos),
                                  origin=f"{name} at every joint", base=folder)
        p.limits[name] = Limits.of(config, voltage)
    if not p.limits:
        raise SizingError(f"no {family} servo of the catalogue can run at {voltage:g} V: "
                          + "; ".join(f"{n}: {why}" for n, why in p.reasons.items()))
    return p


def _score(tau_k, traj, k, limits, margin, repeat, ambient) -> tuple[str, float, float]:
    """(worst check, its peak ratio, ratio / allowed) of joint k on one motion."""
    one = Trajectory(traj.t, traj.q[:, [k]], traj.qd[:, [k]], traj.qdd[:, [k]], traj.derived)
    result = check(_Torques(tau_k), _column(limits, k), one, margin, repeat, ambient)
    # the binding check among those a servo changes; position (the motion against the model's
    # limits) only when it fails, which no servo mends
    peak = {c: float(result.ratios[c].max(initial=0.0)) / result.allowed(c) for c in JOINT_CHECKS}
    name = "position" if peak["position"] > 1 else max(SERVO_CHECKS, key=peak.get)
    ratio = float(result.ratios[name].max(initial=0.0))
    return name, ratio, ratio / result.allowed(name)


_WORK: dict = {}        # a worker's problem, inherited through fork


def _motion_rows(task):
    """The candidates of dof k on one motion: (name, worst check, ratio, score) each."""
    m, k, scale, data, names = task
    p = _WORK["problem"]
    traj = p.trajectories(scale)[m]
    tau0 = p.model(data).inverse_dynamics(traj.q, traj.qd, traj.qdd)[:, [k]]
    out = []
    for name in names:
        tau = tau0 + parts()[name]["armature"] * traj.qdd[:, [k]]
        out.append((name, *_score(tau, traj, k, p.limits[name], p.margin, p.repeat, p.ambient)))
    return m, out


def joint_rows(p: Problem, k: int, choice: dict, scale: float, margin: float, pool=None) -> list[Row]:
    """Every catalogue servo at dof k, the servos outboard of it as chosen: its worst check over
    every motion, at margin `margin`. Sorted by mass, then by score."""
    data = mounted(p.data, p.places, choice, bare=p.dofs[k])
    names = sorted(p.limits)
    tasks = [(m, k, scale, data, names) for m in range(len(p.motions))]
    saved, p.margin = p.margin, margin
    try:
        if pool is None:
            _WORK["problem"] = p
            results = [_motion_rows(t) for t in tasks]
        else:
            results = list(pool.map(_motion_rows, tasks))
    finally:
        p.margin = saved
    rows = {n: Row(n, part_mass(n) if n in parts() else math.nan, why_not=p.reasons.get(n)) for n in p.servos}
    for m, found in results:
        for name, check_name, ratio, score in found:
            row = rows[name]
            if row.worst_check is None or score > row.score:
                row.worst_check, row.worst_ratio, row.score, row.motion = check_name, ratio, score, p.motions[m].name
    return sorted(rows.values(), key=lambda r: (r.why_not is not None, r.mass_kg, r.score))


# ---------------------------------------------------------------------------- the search

@dataclass
class Sizing:
    """A search's outcome: the chosen servo per dof (all of them when `passed`), each dof's rows,
    and where it stopped when a dof had no passing candidate."""
    choice: dict
    rows: dict                          # dof -> [Row]
    failed_dof: str | None = None

    @property
    def passed(self) -> bool:
        return self.failed_dof is None


def greedy(p: Problem, scale: float, margin: float, pool=None, progress=None) -> Sizing:
    """From the hand inwards, each dof's lightest passing candidate (ties: the larger reserve)."""
    choice, table = {}, {}
    for k in reversed(range(len(p.dofs))):
        dof = p.dofs[k]
        rows = joint_rows(p, k, choice, scale, margin, pool)
        table[dof] = rows
        passing = [r for r in rows if r.passed]
        if progress:
            progress(dof, passing[0] if passing else None)
        if not passing:
            return Sizing(choice, table, failed_dof=dof)
        choice[dof] = min(passing, key=lambda r: (r.mass_kg, r.score)).servo
    return Sizing(choice, table)


def size(p: Problem, objective: str = "mass", jobs: int = 1, progress=None, fit: bool = True) -> dict:
    """Size the problem's model for its motions: the choice, each dof's candidates, and when none
    passes (and `fit`) the time scale at which a set passes, and that set."""
    if objective not in OBJECTIVES:
        raise SizingError(f"no sizing objective {objective!r} (the objectives: {', '.join(OBJECTIVES)})")
    with _pool(p, jobs) as pool:
        found = greedy(p, p.time_scale, p.margin, pool, progress)
        outcome = {"sizing": found, "reached_margin": None, "fit": None}
        if found.passed and objective == "margin":
            low, high, best = 0.0, p.margin, found
            while high - low > MARGIN_TOLERANCE * high:
                middle = (low + high) / 2
                trial = greedy(p, p.time_scale, middle, pool)
                if trial.passed:
                    high, best = middle, trial
                else:
                    low = middle
            outcome.update(sizing=best, reached_margin=high)
        elif not found.passed and fit:
            outcome["fit"] = fit_scale(p, pool)
    return outcome


def fit_scale(p: Problem, pool=None) -> dict:
    """The smallest time scale above the problem's at which the greedy finds a set, and the set."""
    sets = {}

    def passes(scale):
        sets[scale] = greedy(p, scale, p.margin, pool)
        return sets[scale].passed
    scale, how = smallest_passing_scale(passes, first=p.time_scale, last=FIT_GRID[1],
                                        tolerance=SIZE_FIT_TOLERANCE)
    return {"time_scale": scale, "how": how, "choice": dict(sets[scale].choice) if scale is not None else None}


class _pool:
    """A process pool over the motions for jobs > 1 (fork: the workers inherit the sampled problem)."""

    def __init__(self, p: Problem, jobs: int):
        self.p, self.jobs, self.executor = p, jobs, None

    def __enter__(self):
        if self.jobs > 1 and len(self.p.motions) > 1:
            _WORK["problem"] = self.p
            self.p.trajectories(self.p.time_scale)
            self.executor = ProcessPoolExecutor(min(self.jobs, len(self.p.motions)),
                                                mp_context=multiprocessing.get_context("fork"))
        return self.executor

    def __exit__(self, *exc):
        if self.executor is not None:
            self.executor.shutdown()
        return False
