"""Inverse kinematics: joint angles that put the hand at a position (and, if given, an orientation).

    >>> from servodyn.model import load_model
    >>> from servodyn.model import ik
    >>> arm = load_model("human_arm")
    >>> r = ik.solve(arm, [0.3, -0.1, -0.2])                 # position only, cold
    >>> r.q, r.reach, r.swivel, r.method                      # q (nq,), fraction, rad, "srs"
    >>> r = ik.solve(arm, p, rotation=R, q_prev=r.q)          # nearest the previous pose
    >>> path = ik.solve_path(arm, positions, dt=0.01, max_speed=6.0)   # a hand path, (N, nq)

The hand is the origin of the end body (`end`, by default the body named like a right hand, else
the last one) and its orientation the rotation of that body's frame as the model file gives it
(`Model.user_poses`), in the base frame. Only the dofs on the path from the base to the hand move;
the others keep q_prev (the neutral pose without one).

Two solvers (`method`):

- **srs**, closed form (IKAN: Tolani, Goswami, Badler, Graphical Models 2000) for a spherical-
  revolute-spherical arm: the last seven dofs on the path are a shoulder of three axes through one
  point S, an elbow hinge, and a wrist of three axes through one point W, the hand's origin. The
  structure is read off the model's own axes and order (any axes, any offsets of the elbow), so
  human_arm and the replicas qualify. The elbow angle follows from |W − S| by the law of cosines;
  the swivel φ, the angle of the elbow about the shoulder–wrist line, is the free parameter; the
  shoulder and wrist angles are Euler angles about the model's axes (two branches each). Of the
  branches inside the limits, the one nearest q_prev is taken.
- **dls**, damped least squares with the limits as box bounds (scipy's bounded least squares on
  [J; λI] dx = [e; 0]), for any chain of hinges; a cold solve restarts from random poses.

`method="auto"` (the default) takes the closed form where the arm is S-R-S and falls back to DLS
otherwise, and when the closed form finds no swivel inside the limits.

The swivel φ is the angle about the shoulder→wrist line n of the elbow's bending direction
n × (elbow axis): 0 when it points as far down (−z of the base) as the line allows, positive
turning right-handed about n. Without `swivel`, a solve with q_prev keeps the previous elbow
direction (continuity along a drag or a path) and a cold solve starts from 0 (elbow down), each
moving to the nearest swivel inside the limits when that one is not.

Refusals are `IkError`s (a `ModelError`, one line): `OutOfReach` ("out of reach"), `NoSwivel`
("no swivel inside the limits"), and `IkError` for a chain the solvers cannot take.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .ik_chain import _EYE, Chain, IkError, NoSwivel, OutOfReach
from .ik_dls import LeastSquares
from .ik_srs import TOL_REACH, ClosedForm
from .rotations import rotation_angle
from .tree import Model


@dataclass(frozen=True)
class IkResult:
    q: np.ndarray               # (nq,) the whole model's q, in limits
    position_error: float       # m, |hand - target|
    rotation_error: float       # rad, angle of R_hand R_targetᵀ (0 without a rotation target)
    reach: float                # |target - shoulder| / the farthest the arm reaches (1 = stretched)
    reach_m: float              # m, |target - shoulder| (the first dof's pivot without an S-R-S arm)
    swivel: float               # rad, the elbow's swivel (nan without an S-R-S arm)
    method: str                 # "srs" or "dls"
    iterations: int = 0         # DLS iterations (0 for the closed form)


@dataclass(frozen=True)
class PathResult:
    q: np.ndarray               # (N, nq)
    position_error: np.ndarray  # (N,) m
    rotation_error: np.ndarray  # (N,) rad
    swivel: np.ndarray          # (N,) rad
    slowed: np.ndarray          # (N,) bool: the speed bound held the arm back at this sample
    reach: np.ndarray           # (N,)


class Arm(ClosedForm, LeastSquares, Chain):
    """The kinematic chain from the base to the hand (ik_chain.Chain) with its two solvers: the
    closed form (ik_srs.ClosedForm) and damped least squares (ik_dls.LeastSquares). Built once
    per model and end body (`Arm.of`)."""


# -------------------------------------------------------------------------------------- the API
def _target(position, rotation):
    try:
        pos = np.asarray(position, dtype=float)
    except (TypeError, ValueError):
        pos = np.array([math.nan])
    if pos.shape != (3,) or not np.all(np.isfinite(pos)):
        raise IkError(f"the target position must be three finite numbers (m), got {position!r}")
    if rotation is None:
        return pos, None
    try:
        rot = np.asarray(rotation, dtype=float)
    except (TypeError, ValueError):
        rot = np.array([math.nan])
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)) or \
            np.abs(rot @ rot.T - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) < 0:
        raise IkError("the target rotation must be a 3 x 3 rotation matrix")
    u, _, vt = np.linalg.svd(rot)
    return pos, u @ vt


def solve(model: Model, position, rotation=None, q_prev=None, swivel: float | None = None,
          end: str | None = None, method: str = "auto", restarts: int = 12, seed: int = 0) -> IkResult:
    """Joint angles that put the hand (the origin of body `end`) at `position` (m, base frame)
    and, if given, its frame at `rotation` (3 x 3, base ← hand), inside the joint limits.

    q_prev: the pose to stay near (branch, swivel, and the dofs that do not move); None is a cold
    solve. swivel: the elbow's swivel in rad (S-R-S arms; None: keep q_prev's or the nearest to 0
    inside the limits). method: "auto", "srs" (closed form only) or "dls" (least squares only).
    Raises OutOfReach, NoSwivel or IkError.
    """
    if method not in ("auto", "srs", "dls"):
        raise IkError(f"method must be 'auto', 'srs' or 'dls', got {method!r}")
    arm = Arm.of(model, end)
    pos, rot = _target(position, rotation)
    cold = q_prev is None
    q = model.neutral_q() if cold else np.array(q_prev, dtype=float)
    if q.shape != (model.nq,) or not np.all(np.isfinite(q)):
        raise IkError(f"q_prev must be {model.nq} finite numbers")
    x_prev = q[arm.q_index]
    if swivel is not None and not math.isfinite(float(swivel)):
        raise IkError(f"the swivel must be a finite angle, got {swivel!r}")
    if method == "srs" and arm.srs is None:
        raise IkError(f"model '{model.name}': no closed form: {arm.why_not_srs}")
    Rp, pp = arm._prefix(x_prev) if arm.srs is not None else (_EYE, np.zeros(3))
    reach_m = float(np.linalg.norm(pos - (Rp @ arm._shoulder() + pp)))
    refusal = None
    x, phi, how, iterations = None, math.nan, "srs", 0
    if arm.srs is not None and method != "dls":
        try:
            x_tail, phi = arm.solve_srs(x_prev, pos, rot, swivel, cold)
            x = x_prev.copy()
            x[-7:] = x_tail
        except IkError as err:
            # the closed form holds the dofs before the shoulder: least squares may still move them
            if method == "srs" or swivel is not None or (arm.n == 7 and isinstance(err, OutOfReach)):
                raise
            refusal = err
    if x is None:
        if arm.n == 7 and arm.srs is not None and reach_m > arm.max_reach() * (1 + TOL_REACH):
            raise OutOfReach(f"out of reach: the target is {reach_m:.3f} m from the shoulder, the arm "
                             f"reaches {arm.max_reach():.3f} m")
        how = "dls"
        rng = np.random.default_rng(seed)
        starts = [x_prev] + [rng.uniform(np.maximum(arm.lower, -math.pi), np.minimum(arm.upper, math.pi))
                             for _ in range(restarts if cold or refusal is not None else 0)]
        for start in starts:
            x, n_it, ok = arm.solve_dls(start, pos, rot)
            iterations += n_it
            if ok:
                break
        else:
            if refusal is not None:
                raise refusal
            if reach_m > arm.max_reach():
                raise OutOfReach(f"out of reach: the target is {reach_m:.3f} m from the shoulder, the arm "
                                 f"reaches {arm.max_reach():.3f} m")
            raise NoSwivel("no pose inside the limits reaches the target (least squares from "
                           f"{len(starts)} starts left {np.linalg.norm(arm.hand(_put(q, arm, x))[1] - pos) * 1e3:.1f} mm)")
        if arm.srs is not None:
            phi = arm.swivel_of(x)
    x = np.clip(x, arm.lower, arm.upper)
    q = _put(q, arm, x)
    R, p = arm.hand(q)
    return IkResult(q=q, position_error=float(np.linalg.norm(p - pos)),
                    rotation_error=0.0 if rot is None else float(rotation_angle(R @ rot.T)),
                    reach=reach_m / arm.max_reach(), reach_m=reach_m, swivel=float(phi), method=how,
                    iterations=iterations)


def _put(q, arm, x):
    q = np.array(q, dtype=float)
    q[arm.q_index] = x
    return q


def solve_path(model: Model, positions, rotations=None, q0=None, dt: float = 0.01,
               max_speed: float | np.ndarray | None = None, swivel: float | None = None,
               end: str | None = None, progress=None) -> PathResult:
    """A hand path: one solve per sample, each from the previous pose (so the swivel and the
    branches carry on), the first one cold unless q0 is given.

    positions (N, 3) m; rotations (N, 3, 3) or None; dt s between samples; max_speed rad/s (one
    number or one per dof of the model): a step that would turn a dof faster is replaced by the
    pose nearest the target within the step's bounds (the limits and ±max_speed·dt, by bounded
    least squares), and the sample is marked `slowed`. A sample out of reach or without a swivel
    in the limits raises, naming the sample. progress(i, N), if given, is called after each sample.
    """
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise IkError(f"positions must have shape (N, 3), got {positions.shape}")
    if rotations is not None:
        rotations = np.asarray(rotations, dtype=float)
        if rotations.shape != (len(positions), 3, 3):
            raise IkError(f"rotations must have shape ({len(positions)}, 3, 3), got {rotations.shape}")
    if not (dt > 0 and math.isfinite(dt)):
        raise IkError(f"dt must be a positive number of seconds, got {dt}")
    arm = Arm.of(model, end)
    step = None
    if max_speed is not None:
        speed = np.broadcast_to(np.asarray(max_speed, dtype=float), (model.nv,))
        if not np.all(speed > 0):
            raise IkError("max_speed must be positive (rad/s)")
        step = speed[arm.q_index] * dt
    N = len(positions)
    out = PathResult(q=np.empty((N, model.nq)), position_error=np.empty(N), rotation_error=np.empty(N),
                     swivel=np.empty(N), slowed=np.zeros(N, dtype=bool), reach=np.empty(N))
    q = q0
    for i in range(N):
        rot = None if rotations is None else rotations[i]
        try:
            r = solve(model, positions[i], rot, q_prev=q, swivel=swivel, end=end)
        except IkError as err:
            raise type(err)(f"sample {i + 1} of {N}: {err}") from None
        q_new = r.q
        if step is not None and q is not None:
            x_prev = np.asarray(q, dtype=float)[arm.q_index]
            x_new = q_new[arm.q_index]
            if np.any(np.abs(x_new - x_prev) > step * (1 + 1e-9)):
                lo = np.maximum(arm.lower, x_prev - step)
                hi = np.minimum(arm.upper, x_prev + step)
                x, _, _ = arm.solve_dls(np.clip(x_new, lo, hi), positions[i], rot, lo, hi, 30)
                q_new = _put(q, arm, x)
                R, p = arm.hand(q_new)
                r = IkResult(q=q_new, position_error=float(np.linalg.norm(p - positions[i])),
                             rotation_error=0.0 if rot is None else float(rotation_angle(R @ rot.T)),
                             reach=r.reach, reach_m=r.reach_m,
                             swivel=arm.swivel_of(x) if arm.srs is not None else math.nan, method="dls")
                out.slowed[i] = True
        out.q[i], out.position_error[i], out.rotation_error[i] = r.q, r.position_error, r.rotation_error
        out.swivel[i], out.reach[i] = r.swivel, r.reach
        q = r.q
        if progress is not None:
            progress(i + 1, N)
    return out


__all__ = ["Arm", "IkError", "IkResult", "NoSwivel", "OutOfReach", "PathResult", "solve", "solve_path"]
