"""`servodyn ik`: joint angles for a hand position (one pose), or a joint trajectory for a hand path.

    servodyn ik human_arm --to 0.3,-0.1,-0.2 [--rpy 0,-90,0] [--swivel 20]
    servodyn ik replica --path targets.csv -o motion.csv [--dt 0.01] [--max-speed 6]

A targets CSV has the header `t,x,y,z` (s, m, in the model's base frame: x forward, y left, z up
for the built-in arms) and optionally `roll,pitch,yaw` (rad, URDF convention: the hand's frame
is Rz(yaw) Ry(pitch) Rx(roll)). The path is sampled every dt (a C2 spline of the positions,
rotations turned at constant rate between rows), solved sample by sample from the previous pose
(servodyn.model.ik.solve_path), and written as a trajectory CSV with q, qd and qdd (those of the
C2 spline of q) that `validate`, `swing` and `view` read.

Exit status: 0 solved; 1 refused (out of reach, no swivel inside the limits) or a path the speed
bound kept more than --tolerance from its targets; 2 bad input.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..control.timing import MAX_PLAYED_DURATION, MIN_CONTROL_PERIOD
from ..control.trajectory import Trajectory, spline_derivatives, write_trajectory_csv
from ..errors import ServodynError
from ..model import Model
from ..model import ik
from ..model.rotations import matrix_to_quat, quat_to_matrix, rpy_to_matrix
from ..outputs import refuse_input_as_output


class IkInputError(ServodynError, ValueError):
    """A targets file or option that cannot be used (exit 2); the message names it."""


@dataclass
class Targets:
    t: np.ndarray                   # (N,) s
    position: np.ndarray            # (N, 3) m
    rotation: np.ndarray | None     # (N, 3, 3) or None
    source: Path | None = None      # the targets file read


@dataclass
class PathTrajectory(Trajectory):
    """A hand path's joint trajectory, and the targets file it was solved from (never written over)."""
    targets: Path | None = None


def parse_triple(text: str, what: str) -> np.ndarray:
    """'X,Y,Z' → three finite floats, or IkInputError naming the option."""
    parts = text.replace(" ", "").split(",")
    try:
        values = np.array([float(p) for p in parts])
    except ValueError:
        raise IkInputError(f"{what} must be three numbers separated by commas, got {text!r}") from None
    if values.shape != (3,) or not np.all(np.isfinite(values)):
        raise IkInputError(f"{what} must be three finite numbers separated by commas, got {text!r}")
    return values


def read_targets(path: str | Path) -> Targets:
    """The rows of a targets CSV (t, x, y, z[, roll, pitch, yaw]); IkInputError names the row."""
    path = Path(path)
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except (UnicodeDecodeError, csv.Error):
        raise IkInputError(f"{path}: not a text file; expected a CSV with the header t,x,y,z[,roll,pitch,yaw]") from None
    if not rows:
        raise IkInputError(f"{path}: empty; expected the header t,x,y,z[,roll,pitch,yaw]")
    header = [h.strip() for h in rows[0]]
    need = ["t", "x", "y", "z"]
    missing = [c for c in need if c not in header]
    if missing:
        raise IkInputError(f"{path}: no column {missing[0]!r}; the header must hold t,x,y,z[,roll,pitch,yaw]")
    angles = [c for c in ("roll", "pitch", "yaw") if c in header]
    if angles and len(angles) != 3:
        raise IkInputError(f"{path}: give roll, pitch and yaw together, or none")
    cols = [header.index(c) for c in need + angles]
    data = []
    for i, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        try:
            values = [float(row[c]) for c in cols]
        except (ValueError, IndexError):
            raise IkInputError(f"{path}: row {i}: expected numbers in every column") from None
        if not all(math.isfinite(v) for v in values):
            raise IkInputError(f"{path}: row {i}: a NaN or infinite number")
        data.append(values)
    if len(data) < 2:
        raise IkInputError(f"{path}: a path needs at least two rows, got {len(data)}")
    data = np.array(data)
    t = data[:, 0]
    if np.any(np.diff(t) <= 0):
        row = int(np.argmax(np.diff(t) <= 0)) + 3
        raise IkInputError(f"{path}: row {row}: t must increase")
    if t[-1] - t[0] > MAX_PLAYED_DURATION:
        raise IkInputError(f"{path}: t spans {t[-1] - t[0]:.4g} s; a motion lasts at most {MAX_PLAYED_DURATION:g} s "
                           "(the longest a swing plays)")
    rotation = np.array([rpy_to_matrix(r) for r in data[:, 4:7]]) if angles else None
    return Targets(t=t - t[0], position=data[:, 1:4], rotation=rotation, source=path)


def densify(targets: Targets, dt: float) -> Targets:
    """Samples every dt from 0 to the end: a C2 spline of the positions, and between rows each
    rotation turned about one axis at a constant rate."""
    from scipy.interpolate import CubicSpline
    n = max(int(math.ceil(targets.t[-1] / dt - 1e-9)), 1)
    t = np.minimum(np.arange(n + 1) * dt, targets.t[-1])
    kind = "not-a-knot" if len(targets.t) > 3 else "natural"
    position = CubicSpline(targets.t, targets.position, axis=0, bc_type=kind)(t)
    rotation = None
    if targets.rotation is not None:
        from scipy.spatial.transform import Rotation, Slerp
        quats = np.array([matrix_to_quat(R) for R in targets.rotation])
        slerp = Slerp(targets.t, Rotation.from_quat(quats))
        rotation = np.array([quat_to_matrix(qq) for qq in slerp(t).as_quat()])
    return Targets(t=t, position=position, rotation=rotation)


def solve_pose(model: Model, to, rpy_deg=None, swivel_deg=None, end=None) -> ik.IkResult:
    rotation = None if rpy_deg is None else rpy_to_matrix(np.radians(rpy_deg))
    swivel = None if swivel_deg is None else math.radians(swivel_deg)
    return ik.solve(model, to, rotation, swivel=swivel, end=end)


def pose_report(model: Model, result: ik.IkResult, end: str | None = None) -> list[str]:
    arm = ik.Arm.of(model, end)
    lines = [f"{'dof':<24} {'deg':>9} {'rad':>10}   limits (deg)"]
    for name, k in zip(arm.dof_names, arm.q_index):
        lo, hi = model.lower[k], model.upper[k]
        lines.append(f"{name:<24} {math.degrees(result.q[k]):>9.3f} {result.q[k]:>10.6f}   "
                     f"[{math.degrees(lo):.0f}, {math.degrees(hi):.0f}]")
    how = "closed form (S-R-S)" if result.method == "srs" else f"damped least squares, {result.iterations} iterations"
    swivel = "" if math.isnan(result.swivel) else f", swivel {math.degrees(result.swivel):.2f}°"
    lines.append(f"reach {result.reach:.3f} ({result.reach_m:.4f} m of {arm.max_reach():.4f} m){swivel}")
    def small(x, unit):
        # rounding's digits differ from machine to machine: below 1e-12 is exact here
        return f"< 1e-12 {unit}" if x < 1e-12 else f"{x:.2e} {unit}"
    lines.append(f"error {small(result.position_error, 'm')}, {small(result.rotation_error, 'rad')} ({how})")
    return lines


def solve_targets(model: Model, targets: Targets, dt: float, max_speed=None, swivel_deg=None,
                  end=None, progress=None) -> tuple[Trajectory, ik.PathResult]:
    """The dense joint trajectory of a targets path (and the per-sample IK result)."""
    if not (math.isfinite(dt) and dt >= MIN_CONTROL_PERIOD):
        raise IkInputError(f"--dt {dt:g}: a path is sampled every {MIN_CONTROL_PERIOD * 1e3:g} ms or more (the "
                           "shortest control period: a servo plays nothing finer)")
    dense = densify(targets, dt)
    swivel = None if swivel_deg is None else math.radians(swivel_deg)
    result = ik.solve_path(model, dense.position, dense.rotation, dt=dt, max_speed=max_speed,
                           swivel=swivel, end=end, progress=progress)
    qd, qdd = spline_derivatives(dense.t, result.q)
    return PathTrajectory(t=dense.t, q=result.q, qd=qd, qdd=qdd, derived=True, targets=targets.source), result


def write_path(model: Model, traj: Trajectory, out: str | Path) -> None:
    """The trajectory CSV; never over the targets file it was solved from."""
    refuse_input_as_output(out, "-o", {"--path": getattr(traj, "targets", None)})
    write_trajectory_csv(out, traj, model.dof_names)
