"""Joint trajectories and motion paths.

A trajectory CSV has the header `t`, then `q_<dof>` for every dof, optional `qd_<dof>` and
`qdd_<dof>` (derived from a C2 cubic spline of q when absent). SI units: seconds, radians. This
module is the one reader of that file: `read_trajectory_csv` gives its samples, and
`MotionPath.of_trajectory` the motion between them at any sampling, through the file's own `qd`
and `qdd` (the quintic Hermite interpolant of q, qd and qdd at every sample: where qd and qdd were
derived from the spline of q it is that spline itself).

A `MotionPath` is any motion on its own (human-speed) clock; `at_scale(s, dt)` plays it `s` times
slower, sampled every dt (the configuration's control period): the one place a motion is time
scaled, for the controller, the validator, the view and the firmware's tables alike."""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ServodynError
from .timing import SMALL_TIME_STEP, played_periods


class TrajectoryError(ServodynError, ValueError):
    """A trajectory file that cannot be used; the message names the file, row and column."""


@dataclass
class Trajectory:
    t: np.ndarray      # (N,)
    q: np.ndarray      # (N, nq)
    qd: np.ndarray     # (N, nq)
    qdd: np.ndarray    # (N, nq)
    derived: bool      # qd and qdd came from the spline

    @classmethod
    def still(cls, q, n: int, period: float, t0: float = 0.0) -> "Trajectory":
        """Pose q held for n samples every `period` s from t0: at rest throughout."""
        q = np.asarray(q, dtype=float)
        return cls(t=t0 + np.arange(n) * period, q=np.tile(q, (n, 1)), qd=np.zeros((n, len(q))),
                   qdd=np.zeros((n, len(q))), derived=False)


@dataclass(frozen=True)
class MotionPath:
    """A motion on its own clock: `evaluate(t)` gives q, qd, qdd at times t (s, from 0 to
    `duration`; an array of times gives arrays with a leading axis). `breaks`: where its quintic
    pieces meet (keyframes, a CSV's samples), when it is made of them: a controller given q, qd
    and qdd there plays the same curve (servodyn.loop.link_load's knots)."""
    name: str
    duration: float                                   # s, as written (time scale 1)
    evaluate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
    breaks: np.ndarray | None = field(default=None, compare=False)

    def at_scale(self, scale: float = 1.0, dt: float = SMALL_TIME_STEP) -> Trajectory:
        """The motion played `scale` times slower, sampled every dt of the played clock from 0 to
        its end (velocities / scale, accelerations / scale²); the last sample is held at the end
        when the played duration is not a whole number of periods."""
        if not (dt > 0 and math.isfinite(dt)):
            raise TrajectoryError(f"the sampling period must be a positive number of seconds, got {dt}")
        n = played_periods(self.duration, scale, dt)
        t = np.arange(n + 1) * dt
        q, qd, qdd = self.evaluate(np.minimum(t / scale, self.duration))
        return Trajectory(t=t, q=q, qd=qd / scale, qdd=qdd / scale**2, derived=True)

    @classmethod
    def of_trajectory(cls, name: str, traj: Trajectory, origin: str | None = None) -> "MotionPath":
        """The samples of a trajectory (a CSV's, `origin` its file) and between them the quintic
        Hermite interpolant of their q, qd and qdd, on the trajectory's clock from its first sample."""
        t = traj.t - traj.t[0]
        if len(t) == 1:
            def hold(times):
                shape = np.shape(times)
                return tuple(np.broadcast_to(v, shape + v.shape).copy() for v in (traj.q[0], traj.qd[0], traj.qdd[0]))
            return cls(name, 0.0, hold)
        from scipy.interpolate import BPoly
        with np.errstate(all="ignore"):
            try:
                poly = BPoly.from_derivatives(t, np.stack([traj.q, traj.qd, traj.qdd], axis=1))
            except ValueError:       # scipy refuses its own overflowed coefficients
                poly = None
        if poly is None or not np.all(np.isfinite(poly.c)):
            raise TrajectoryError(f"{origin or name}: the motion between the samples overflows (values or time steps too "
                                  "extreme)")
        velocity, acceleration = poly.derivative(1), poly.derivative(2)

        def evaluate(times):
            return poly(times), velocity(times), acceleration(times)
        return cls(name, float(t[-1]), evaluate, breaks=t)


def spline_derivatives(t: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """qd and qdd of the C2 cubic spline through (t, q); constant for a single sample. Values
    or time steps so extreme that the derivatives overflow raise TrajectoryError naming the
    first such sample."""
    if len(t) < 2:
        return np.zeros_like(q), np.zeros_like(q)
    with np.errstate(all="ignore"):
        if len(t) == 2:
            slope = (q[1] - q[0]) / (t[1] - t[0])
            qd, qdd = np.tile(slope, (2, 1)), np.zeros_like(q)
        else:
            from scipy.interpolate import CubicSpline
            try:
                spline = CubicSpline(t, q, axis=0, bc_type="not-a-knot" if len(t) > 3 else "natural")
                qd, qdd = spline(t, 1), spline(t, 2)
            except ValueError:      # scipy refuses its own overflowed slopes
                qd = qdd = np.full_like(q, np.inf)
    bad = ~(np.isfinite(qd) & np.isfinite(qdd)).all(axis=-1)
    if bad.any():
        row = int(np.argmax(bad))
        raise TrajectoryError(f"t = {t[row]:g} s (sample {row + 1}): the spline's velocity or acceleration "
                              "overflows (values or time steps too extreme)")
    return qd, qdd


def read_trajectory_csv(path: str | Path, dof_names: tuple[str, ...]) -> Trajectory:
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:     # a UTF-8 byte-order mark is dropped
            rows = list(csv.reader(f))
    except OSError as err:
        raise TrajectoryError(f"{path}: cannot read ({err.strerror})") from None
    except UnicodeDecodeError:
        raise TrajectoryError(f"{path}: not a text CSV file") from None
    rows = [r for r in rows if r and any(cell.strip() for cell in r)]
    if not rows:
        raise TrajectoryError(f"{path}: empty file, expected a header 't,q_<dof>,...'")
    header = [h.strip() for h in rows[0]]
    if not header or header[0] != "t":
        raise TrajectoryError(f"{path}: the first column must be 't', got '{header[0] if header else ''}'")
    known = {"t"} | {f"{p}_{d}" for p in ("q", "qd", "qdd") for d in dof_names}
    for name in header:
        if name not in known:
            raise TrajectoryError(f"{path}: unknown column '{name}' (dofs: {', '.join(dof_names)})")
    if len(set(header)) != len(header):
        raise TrajectoryError(f"{path}: a column appears twice")
    missing = [d for d in dof_names if f"q_{d}" not in header]
    if missing:
        raise TrajectoryError(f"{path}: missing column q_{missing[0]}"
                              + (f" and {len(missing) - 1} more" if len(missing) > 1 else ""))
    has_qd = [f"qd_{d}" in header for d in dof_names]
    has_qdd = [f"qdd_{d}" in header for d in dof_names]
    if (any(has_qd) and not all(has_qd)) or (any(has_qdd) and not all(has_qdd)):
        raise TrajectoryError(f"{path}: give qd_ (and qdd_) columns for every dof or for none")

    data = np.empty((len(rows) - 1, len(header)))
    for r, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise TrajectoryError(f"{path}: row {r} has {len(row)} values, the header has {len(header)}")
        for c, cell in enumerate(row):
            try:
                if "_" in cell:     # Python reads 0_5 as 5.0; no CSV writer means that
                    raise ValueError(cell)
                value = float(cell)
            except ValueError:
                raise TrajectoryError(f"{path}: row {r}, column '{header[c]}': '{cell.strip()}' is not a number") from None
            if not math.isfinite(value):
                raise TrajectoryError(f"{path}: row {r}, column '{header[c]}': value is not finite")
            data[r - 2, c] = value
    if len(data) == 0:
        raise TrajectoryError(f"{path}: no data rows after the header")
    t = data[:, 0]
    steps = np.diff(t)
    if np.any(steps <= 0):
        r = int(np.argmax(steps <= 0)) + 3
        raise TrajectoryError(f"{path}: row {r}: time must increase (t = {t[r - 2]:g} after {t[r - 3]:g})")
    col = {name: c for c, name in enumerate(header)}
    q = data[:, [col[f"q_{d}"] for d in dof_names]]
    derived = not all(has_qd)
    try:
        if all(has_qd):
            qd = data[:, [col[f"qd_{d}"] for d in dof_names]]
            qdd = (data[:, [col[f"qdd_{d}"] for d in dof_names]] if all(has_qdd)
                   else spline_derivatives(t, qd)[0])
        else:
            qd, qdd = spline_derivatives(t, q)
            if all(has_qdd):
                qdd = data[:, [col[f"qdd_{d}"] for d in dof_names]]
    except TrajectoryError as err:
        raise TrajectoryError(f"{path}: {err}") from None
    return Trajectory(t=t, q=q, qd=qd, qdd=qdd, derived=derived)


def write_columns_csv(path: str | Path, t: np.ndarray, prefix: str, dof_names, values: np.ndarray) -> None:
    """Write `t,<prefix>_<dof>...` rows with full double precision."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["t"] + [f"{prefix}_{d}" for d in dof_names])
        for ti, row in zip(t, values):
            writer.writerow([repr(float(ti))] + [repr(float(v)) for v in row])


def write_trajectory_csv(path: str | Path, traj: Trajectory, dof_names) -> None:
    """Write t, q_<dof>, qd_<dof>, qdd_<dof> with full double precision (read back exactly by
    read_trajectory_csv)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = ["t"] + [f"{p}_{d}" for p in ("q", "qd", "qdd") for d in dof_names]
    rows = np.hstack([traj.t[:, None], traj.q, traj.qd, traj.qdd])
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for row in rows:
            writer.writerow([repr(float(v)) for v in row])
