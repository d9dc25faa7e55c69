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

import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from ..control.timing import SMALL_TIME_STEP
from ..control.trajectory import Trajectory
from ..hal.backend import backend
from ..hal.config import config_from_dict
from ..model.modelfile import model_from_dict, parts
from ..model.rotations import rpy_to_matrix  # noqa: F401  (tests/test_size.py reads it from here)
from .checks import CHECKS, check
from .fit import FIT_GRID, smallest_passing_scale
from .limits import Limits
from .mounting import Housing, housings, load_model_data, mounted
# the model's housings and the catalogue, importable from here as before the split
from .mounting import _centroid, _flange, _shaft_offset_scale, flange_centre, mount, shaft_line  # noqa: F401
from .servos import (FAMILIES, SizingError, catalogue, default_family, part_mass, supply_voltages,  # noqa: F401
                     unusable)
from ..hal.thermal import AMBIENT

SIZING_MARGIN = 0.8     # the share of each limit a sized servo may use by default: 20 % kept in reserve
OBJECTIVES = ("mass", "margin")
JOINT_CHECKS = tuple(c for c in CHECKS if c not in ("supply", "bus"))   # a joint's own checks
SERVO_CHECKS = tuple(c for c in JOINT_CHECKS if c != "position")        # those a servo changes
BUS_SHARE = 0.8             # of the control period one tick's transactions may take on the wire
PERIODS = (0.001, 0.002, 0.0025, 0.005, 0.01)   # s: control periods that divide the ID period
MARGIN_TOLERANCE = 0.01     # relative width the margin objective's bisection stops at
SIZE_FIT_TOLERANCE = 0.01   # relative width of the time-scale scan when nothing passes
BUS_NAMES = {"dynamixel": "arm", "can": "can", "feetech": "arm"}   # a sized configuration's bus of each kind (its table: the backend's)


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
