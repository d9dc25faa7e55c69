"""Speed near people: each link's Cartesian speed over a motion, its effective mass along that
velocity, and ISO/TS 15066's transient-contact limits per body region.

A link hitting a person transfers the energy of its effective mass along its velocity (the
inertia the contact point "feels" in that direction); ISO/TS 15066 Annex A.3 bounds the relative
speed at which a transient contact stays below the Table A.2 force limit of the body region hit:

    v_max = F_T / sqrt(μ·k),   μ = (1/m_R + 1/m_H)⁻¹ (the reduced mass)

with F_T the region's transient force, k its spring constant and m_H its effective mass (Table
A.3), m_R the robot's effective mass at the contact point along its velocity u:

    m_R = 1 / (uᵀ J_v M(q)⁻¹ J_vᵀ u)

M(q) the joint-space inertia *with the armature* (each dof's reflected rotor inertia, on M's
diagonal: the servos' rotors make a light arm hit like a heavier one), J_v the point's linear
Jacobian. Both come from the C core in batched calls, in the body's own frame (the speed and m_R
do not depend on the frame they are written in): the Jacobian's rows by virtual work — a unit
force e at the point needs the joint torques J_vᵀ e to balance it at rest, which the RNEA of a
weightless copy of the model returns (with a minus sign) for that external force — and
M⁻¹ J_vᵀ e from its forward dynamics. tests/test_near_people.py checks both against Pinocchio.

The points: every link's centre of mass, and for the last body (the hand) also the point of its
solids farthest from its joint, when the model gives solids (the fastest point of a turning hand).
Every link is checked against every region (a hand may hit a chest); skull, forehead and face
take no transient contact at any speed (Table A.2), so no speed makes them acceptable: keeping
the arm away from the head is the cell's layout or separation monitoring, not this check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control.trajectory import MotionPath, Trajectory
from ..errors import InputError
from ..model.shapes import solid_mesh
from .fit import smallest_passing_scale


@dataclass(frozen=True)
class Region:
    """A body region of ISO/TS 15066 Annex A."""
    name: str
    force_n: float            # Table A.2: transient contact force, 2x the quasi-static maximum
    stiffness_n_m: float      # Table A.3: spring constant k
    mass_kg: float            # Table A.3: effective mass m_H


# ISO/TS 15066:2016 Annex A, Table A.2 (transient force = 2 x the quasi-static maximum force) and
# Table A.3 (spring constant k, effective mass m_H), for the regions an arm can reach at work;
# skull/forehead and face: transient contact not permissible (Table A.2)
REGIONS = (
    Region("hand", 280.0, 75e3, 0.6),
    Region("lower arm", 320.0, 40e3, 2.0),
    Region("upper arm", 300.0, 30e3, 3.0),
    Region("chest", 280.0, 25e3, 40.0),
)
NO_CONTACT = ("skull and forehead", "face")
MOVING = 1e-9               # m/s: below it a point is at rest (no direction, no effective mass)


@dataclass(frozen=True)
class Point:
    """A point fixed in a body: `local` in its user frame (m); `where` says which point."""
    body: int
    name: str                 # the body's name
    key: str                  # "com" or "tip"
    where: str
    local: np.ndarray


def contact_points(model) -> list[Point]:
    """Every moving link's centre of mass, and for the last body also its solids' farthest point
    from its joint (when it has solids). A link moves when a dof turns it (it or an ancestor has
    one) and it has mass."""
    if model.free_root or any(b.ball for b in model.bodies):
        raise InputError("--near-people reads a fixed-base model of hinge joints (no free root, no ball joint)")
    moving, points = [], []
    for i, body in enumerate(model.bodies):
        moving.append(bool(body.dofs) or (body.parent >= 0 and moving[body.parent]))
        if not moving[i] or body.mass <= 0:
            continue
        points.append(Point(i, body.name, "com", "centre of mass", np.asarray(body.com, dtype=float)))
        if i == model.nbody - 1 and body.solids:
            vertices = np.vstack([solid_mesh(s)[0] for s in body.solids])
            tip = vertices[int(np.argmax(np.linalg.norm(vertices, axis=1)))]
            points.append(Point(i, body.name, "tip", "farthest point of its solids from its joint", tip))
    if not points:
        raise InputError(f"model '{model.name}' has no moving link with mass: nothing to check near people")
    return points


def _unit_forces(model, point: Point) -> np.ndarray:
    """(3, nbody, 6): a unit force along each axis of the point's body frame at the point, as the
    core's external wrench (torque about the body origin, force); the same for every sample."""
    f = np.zeros((3, model.nbody, 6))
    for k in range(3):
        e = np.eye(3)[k]
        f[k, point.body, :3] = np.cross(point.local, e)
        f[k, point.body, 3:] = e
    return f


def point_jacobian(weightless, point: Point, q: np.ndarray) -> np.ndarray:
    """(N, 3, nv) linear Jacobian of the point in its body's frame, at each q (N, nv): row k is
    J_vᵀ e_k, minus the torques the weightless model's RNEA needs at rest against a unit force
    e_k at the point (virtual work)."""
    q = np.atleast_2d(q)
    zero = np.zeros((len(q), weightless.nv))
    forces = _unit_forces(weightless, point)
    return np.stack([-weightless.inverse_dynamics(q, zero, zero, f_ext=f) for f in forces], axis=1)


def point_motion(weightless, point: Point, q: np.ndarray, qd: np.ndarray):
    """Speed (N,) of the point, its effective mass along its velocity (N,; NaN at rest) and the
    inverse Cartesian inertia J_v M⁻¹ J_vᵀ (N, 3, 3), all in the body's frame."""
    J = point_jacobian(weightless, point, q)
    zero = np.zeros_like(qd)
    # M⁻¹ J_vᵀ e_k: the accelerations the torques J_vᵀ e_k give at rest, weightless (armature included)
    Minv_Jt = np.stack([weightless.forward_dynamics(q, zero, J[:, k, :]) for k in range(3)], axis=2)
    inverse_inertia = J @ Minv_Jt
    v = np.einsum("nkj,nj->nk", J, qd)
    speed = np.linalg.norm(v, axis=1)
    moving = speed > MOVING
    u = np.where(moving[:, None], v / np.where(moving, speed, 1.0)[:, None], 0.0)
    along = np.einsum("nk,nkl,nl->n", u, inverse_inertia, u)
    with np.errstate(divide="ignore", invalid="ignore"):
        mass = np.where(moving, 1.0 / along, np.nan)
    return speed, mass, inverse_inertia


def permitted_speed(effective_mass, region: Region):
    """ISO/TS 15066 A.3: the relative speed at which a transient contact of a robot of this
    effective mass (kg) with the region reaches its transient force limit (m/s)."""
    m = np.asarray(effective_mass, dtype=float)
    reduced = 1.0 / (1.0 / m + 1.0 / region.mass_kg)
    return region.force_n / np.sqrt(reduced * region.stiffness_n_m)


@dataclass
class PointCheck:
    point: Point
    speed: np.ndarray          # (N,) m/s
    mass: np.ndarray           # (N,) kg (NaN at rest)
    ratios: np.ndarray         # (N, regions) speed / permitted speed (0 at rest)


def weightless_model(model):
    """The model without gravity: its RNEA at rest is then the external force's torques alone."""
    return model.with_gravity(np.zeros(3))


def check_points(weightless, points: list[Point], traj: Trajectory) -> list[PointCheck]:
    """Each point's speed, effective mass and ratio to each region's permitted speed, per sample."""
    out = []
    for point in points:
        speed, mass, _ = point_motion(weightless, point, traj.q, traj.qd)
        at_rest = np.isnan(mass)
        filled = np.where(at_rest, 1.0, mass)
        ratios = np.stack([np.where(at_rest, 0.0, speed / permitted_speed(filled, r)) for r in REGIONS], axis=1)
        out.append(PointCheck(point, speed, mass, ratios))
    return out


def allowed_ratio(margin: float) -> float:
    """The margin tightens the ISO limits (0.8 keeps 20 % in reserve) but never loosens them."""
    return min(margin, 1.0)


def near_people(model, traj: Trajectory, margin: float = 1.0, weightless=None) -> dict:
    """Each link's peak speed, effective mass and ISO/TS 15066 transient-contact verdict per
    region over a sampled motion (report.json's `near_people`). `traj`: anything with the samples'
    t, q and qd (a Trajectory, or the checks' Result of the same samples)."""
    weightless = weightless or weightless_model(model)
    allowed = allowed_ratio(margin)
    links = {}
    for check in check_points(weightless, contact_points(model), traj):
        links.setdefault(check.point.name, {})[check.point.key] = _point_figures(check, traj.t, allowed)
    table = {}
    for name, points in links.items():
        worst = max(points.values(), key=lambda p: p["worst_ratio"])
        table[name] = {key: worst[key] for key in ("point", "peak_speed_m_s", "peak_at_s", "effective_mass_kg",
                                                   "limiting_region", "permitted_speed_m_s", "worst_ratio", "passed")}
        table[name]["passed"] = all(p["passed"] for p in points.values())
        table[name]["points"] = points
    return {"passed": all(row["passed"] for row in table.values()), "allowed_ratio": allowed,
            "links": table,
            "regions": {r.name: {"transient_force_n": r.force_n, "stiffness_n_per_mm": r.stiffness_n_m / 1e3,
                                 "effective_mass_kg": r.mass_kg} for r in REGIONS},
            "no_contact": {"regions": list(NO_CONTACT),
                           "why": "transient contact not permissible at any speed (ISO/TS 15066 Table A.2)"},
            "effective_mass": "1 / (uᵀ J_v M⁻¹ J_vᵀ u), u the point's velocity direction; M includes the "
                              "armature (the servos' reflected rotor inertia)",
            "source": "ISO/TS 15066:2016 Annex A, Tables A.2 (transient = 2 x quasi-static force) and A.3"}


def _point_figures(check: PointCheck, t: np.ndarray, allowed: float) -> dict:
    peak = int(np.argmax(check.speed))
    masses = check.mass[~np.isnan(check.mass)]
    regions = {}
    for r, region in enumerate(REGIONS):
        k = int(np.argmax(check.ratios[:, r]))
        ratio = float(check.ratios[k, r])
        regions[region.name] = {"passed": ratio <= allowed, "worst_ratio": ratio, "at_s": float(t[k]),
                                "speed_m_s": float(check.speed[k]),
                                "permitted_speed_m_s": _permitted(check.mass[k], region)}
    limiting = max(regions, key=lambda name: regions[name]["worst_ratio"])
    at_peak = check.mass[peak]
    return {"point": check.point.where, "local_m": [float(x) for x in check.point.local],
            "peak_speed_m_s": float(check.speed[peak]), "peak_at_s": float(t[peak]),
            "effective_mass_kg": None if np.isnan(at_peak) else float(at_peak),
            "effective_mass_range_kg": [float(masses.min()), float(masses.max())] if masses.size else None,
            "limiting_region": limiting, "permitted_speed_m_s": regions[limiting]["permitted_speed_m_s"],
            "worst_ratio": regions[limiting]["worst_ratio"], "passed": all(r["passed"] for r in regions.values()),
            "regions": regions}


def _permitted(mass: float, region: Region) -> float | None:
    """The permitted speed for an effective mass, None at rest (any speed is then a finite number)."""
    return None if math.isnan(mass) else float(permitted_speed(mass, region))


def fit_near_people(model, path: MotionPath, period: float, margin: float = 1.0, weightless=None):
    """The smallest uniform time scale at which every link passes every region near people, found
    like --fit (validation.fit: a geometric scan, then a bisection), each candidate sampled at
    the control period; (scale or None, how)."""
    weightless = weightless or weightless_model(model)
    points, allowed = contact_points(model), allowed_ratio(margin)

    def passes(scale):
        checks = check_points(weightless, points, path.at_scale(scale, period))
        return all(float(c.ratios.max(initial=0.0)) <= allowed for c in checks)
    return smallest_passing_scale(passes)
