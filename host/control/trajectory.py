"""Joint trajectories as CSV: header `t`, then `q_<dof>` for every dof, optional `qd_<dof>` and
`qdd_<dof>` (derived from a C2 cubic spline of q when absent). SI units: seconds, radians."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class TrajectoryError(ValueError):
    """A trajectory file that cannot be used; the message names the file, row and column."""


@dataclass
class Trajectory:
    t: np.ndarray      # (N,)
    q: np.ndarray      # (N, nq)
    qd: np.ndarray     # (N, nq)
    qdd: np.ndarray    # (N, nq)
    derived: bool      # qd and qdd came from the spline


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
