"""Motions: keyframes (TOML) interpolated with C2 continuity by the C core, and the validation
every trajectory passes before it reaches a controller — increasing finite times, finite values,
the model's joint limits and any velocity and acceleration limits — with errors that name the
keyframe or row and the dof."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _core
from ..model.files import read_toml, string_key
from .trajectory import MotionPath, Trajectory, TrajectoryError, read_trajectory_csv

MOTIONS_DIR = Path(__file__).parent / "motions"
DEFAULT_MOTION = "tennis_forehand"   # what a swing plays unless told otherwise: the paper's forehand


def builtin_motions() -> dict[str, Path]:
    return {p.stem: p for p in sorted(MOTIONS_DIR.glob("*.toml"))}


@dataclass
class Motion:
    """Keyframes of every dof of a model, sampled through the core's C2 interpolation."""
    name: str
    model: str                        # the model the keyframes are written for
    t: np.ndarray                     # (K,) keyframe times (s)
    q: np.ndarray                     # (K, n) keyframe positions (rad), model dof order
    dof_names: tuple[str, ...]
    phases: list[str] = field(default_factory=list)
    description: str = ""
    source: str = ""

    def __post_init__(self):
        try:
            self._trajectory = _core.Trajectory(self.t - self.t[0], self.q)
        except ValueError as err:
            raise TrajectoryError(f"motion '{self.name}': {err}") from None

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, qd, qdd at a time or an array of times (s from the first keyframe)."""
        return self._trajectory.eval(np.asarray(t, dtype=float))

    @property
    def path(self) -> MotionPath:
        return MotionPath(self.name, self.duration, self.at, breaks=self.t - self.t[0])

    def sample(self, dt: float, time_scale: float = 1.0) -> Trajectory:
        """The motion every dt seconds; time_scale > 1 plays it slower (MotionPath.at_scale)."""
        return self.path.at_scale(time_scale, dt)


def motion_path(spec: str | Path, model) -> MotionPath:
    """Any motion a command takes: a built-in motion by name, a keyframe file (.toml) or a
    trajectory CSV (.csv), checked against the model's dofs (keyframes: and its limits)."""
    if str(spec).lower().endswith(".csv"):
        return MotionPath.of_trajectory(Path(spec).stem, read_trajectory_csv(spec, model.dof_names), str(spec))
    return load_motion(spec, model).path


def save_motion(motion: Motion, path: str | Path) -> None:
    """Write a motion as a keyframe file that load_motion reads back to the same keyframes."""
    lines = [f"name = {json.dumps(motion.name)}", f"model = {json.dumps(motion.model)}"]
    for key, text in (("description", motion.description), ("source", motion.source)):
        if text:
            lines.append(f"{key} = {json.dumps(text)}")
    for k, t in enumerate(motion.t):
        lines += ["", "[[keyframe]]", f"t = {float(t)!r}"]
        if k < len(motion.phases) and motion.phases[k]:
            lines.append(f"phase = {json.dumps(motion.phases[k])}")
        angles = ", ".join(f"{name} = {float(v)!r}" for name, v in zip(motion.dof_names, motion.q[k]))
        lines.append(f"q = {{ {angles} }}")
    Path(path).write_text("\n".join(lines) + "\n")


def load_motion(name_or_path: str | Path, model) -> Motion:
    """A built-in motion by name or a keyframe file, checked against the model's dofs and limits."""
    builtins = builtin_motions()
    path = builtins.get(str(name_or_path), Path(name_or_path))
    try:
        data = read_toml(path, TrajectoryError)
    except FileNotFoundError:
        raise TrajectoryError(f"{name_or_path}: no such keyframe file, and not a built-in motion "
                              f"({', '.join(builtins) or 'none installed'})") from None
    frames = data.get("keyframe")
    if not isinstance(frames, list) or len(frames) < 2 or not all(isinstance(f, dict) for f in frames):
        raise TrajectoryError(f"{path}: needs at least two [[keyframe]] entries")
    names = model.dof_names
    t = np.empty(len(frames))
    q = np.empty((len(frames), len(names)))
    for k, frame in enumerate(frames):
        where = f"{path}: keyframe {k + 1}"
        value = frame.get("t")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise TrajectoryError(f"{where}: 't' must be a finite number of seconds")
        t[k] = value
        if k and t[k] <= t[k - 1]:
            raise TrajectoryError(f"{where}: time must increase (t = {t[k]:g} after {t[k - 1]:g})")
        angles = frame.get("q")
        if not isinstance(angles, dict):
            raise TrajectoryError(f"{where}: needs a table q = {{dof = angle, ...}}")
        unknown = sorted(set(angles) - set(names))
        if unknown:
            raise TrajectoryError(f"{where}: unknown dof '{unknown[0]}' for model '{model.name}'")
        for j, name in enumerate(names):
            value = angles.get(name)
            if value is None:
                raise TrajectoryError(f"{where}: missing dof '{name}'")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise TrajectoryError(f"{where}, dof '{name}': angle must be a finite number")
            q[k, j] = value
    motion = Motion(name=string_key(data, "name", path.stem, TrajectoryError, str(path), empty=False),
                    model=string_key(data, "model", model.name, TrajectoryError, str(path), empty=False),
                    t=t, q=q, dof_names=names,
                    phases=[string_key(f, "phase", "", TrajectoryError, f"{path}: keyframe {k + 1}") for k, f in enumerate(frames)],
                    description=string_key(data, "description", "", TrajectoryError, str(path)),
                    source=string_key(data, "source", "", TrajectoryError, str(path)))
    check_limits(motion.sample(1e-3), model, origin=str(path))
    return motion


def check_limits(traj: Trajectory, model, origin: str = "trajectory", velocity=None,
                 acceleration=None) -> None:
    """Raise TrajectoryError at the first sample outside the model's joint limits, or beyond the
    given velocity or acceleration limits (rad/s, rad/s²; scalars or one per dof)."""
    names = model.dof_names
    checks = [("position", traj.q, model.lower, model.upper, "rad")]
    for what, limit, values, unit in (("speed", velocity, traj.qd, "rad/s"),
                                      ("acceleration", acceleration, traj.qdd, "rad/s²")):
        if limit is None:
            continue
        limit = np.broadcast_to(np.asarray(limit, dtype=float), (len(names),))
        # a NaN limit compares false and would switch the check off; a negative one refuses all
        if not np.all(limit > 0):
            raise TrajectoryError(f"the {what} limit must be a positive number of {unit}, got "
                                  f"{limit[np.argmax(~(limit > 0))]:g}")
        checks.append((what, np.abs(values), -np.inf * limit, limit, unit))
    tol = 1e-9
    for what, values, lo, hi, unit in checks:
        bad = (values < lo - tol) | (values > hi + tol)
        if np.any(bad):
            row, j = np.argwhere(bad)[0]
            limit = lo[j] if values[row, j] < lo[j] else hi[j]
            raise TrajectoryError(f"{origin}: t = {traj.t[row]:.3f} s (sample {row + 1}), dof "
                                  f"'{names[j]}': {what} {values[row, j]:.4g} {unit} beyond the "
                                  f"limit {limit:.4g} {unit}")
