"""A LeRobot episode as a servodyn motion: its names mapped onto the configuration's joints, its units
turned into the joints' radians, resampled on a uniform clock and smoothed without lag, its
velocities and accelerations (which inverse dynamics needs) from a C2 spline of the smoothed angles.

Names. LeRobot names a joint's position `<motor>.pos` (`shoulder_pan.pos`); the motor's name must be
one of the configuration's dofs, and every dof must have one. Anything else is refused in one line.

Units (LeRobot's motors_bus normalisation, ../shared/notes/lerobot.md §2.2; datasets do not declare
them):
  degrees         (raw − mid)·360/4095, mid the middle of the range recorded at calibration: the
                  configuration's zero (`zero_offset`, which `servodyn calibrate --from-lerobot` sets
                  to that middle). q = value·(4095/360)·(2π/4096) / (direction · gear_ratio).
  range_m100_100  the calibrated range mapped onto −100..100 (older datasets); here the configuration's
                  position_limits (which `calibrate --from-lerobot` writes from the same range).
  the gripper     always 0..100 over its range (LeRobot's RANGE_0_100), whatever the others use.
`units="auto"` takes them from meta/info.json (the feature's "units" entry, where a writer states it),
else from the values (a body joint beyond ±100 can only be degrees), else from the codebase version
(v3.x: degrees, LeRobot's followers' default since `use_degrees`; older: range_m100_100); the reason
is said with the verdicts.

Smoothing. A 30 Hz recording differentiated twice turns its encoder steps and jitter into torque noise
larger than the arm's own torques (0.2° of noise gave hundreds of N·m unfiltered in our motion-capture
measurements). The frames are resampled onto a uniform 1/fps clock (linear between the timestamps), then
filtered by a 4th-order Butterworth low-pass run forwards and backwards (mocap.smoothing.low_pass,
the motion captures' filter, its cutoff corrected so that both passes together are 3 dB down there): the
backward pass cancels the forward pass's phase, so the smoothed angles do not lag the recording and the
inertial torques stay aligned in time with the poses and their gravity torques (a one-way filter
would shift them by its group delay, ~1/(2·cutoff) s). A smoothing spline is zero-lag too, but its
smoothing is chosen per signal by cross-validation, where a cutoff in Hz is one stated figure that
holds for every joint and episode. Default cutoff 5 Hz: above the few hertz a teleoperated arm moves at,
a third of the way to 30 Hz data's 15 Hz Nyquist."""

from __future__ import annotations

import math

import numpy as np

from scipy.interpolate import CubicSpline

from ..control.trajectory import MotionPath
from ..mocap.smoothing import low_pass
from .lerobot import Dataset, DatasetError, Episode

UNITS = ("degrees", "range_m100_100")
RESOLUTION = 4096                 # LeRobot's model_resolution_table for the STS3215 and the X-series
LEROBOT_DEGREE = (RESOLUTION - 1) / 360 * (2 * math.pi / RESOLUTION)   # rad a LeRobot "degree" is
POSITION_SUFFIX = ".pos"
GRIPPERS = ("gripper",)           # LeRobot's motors normalised 0..100 (RANGE_0_100)
CUTOFF_HZ = 5.0                   # the low-pass's default cutoff (a motion capture's is 8: a swing is faster)


def joint_columns(names: list, config, where: str) -> list[int]:
    """Per dof of the configuration, its column in the feature; one line for a name that is no
    dof of the configuration, or a dof the dataset lacks."""
    dofs = config.model.dof_names
    motors = [name[:-len(POSITION_SUFFIX)] if name.endswith(POSITION_SUFFIX) else name for name in names]
    for name, motor in zip(names, motors):
        if motor not in dofs:
            raise DatasetError(f"{where}: '{name}' names no joint of '{config.name}' (its joints: {', '.join(dofs)})")
    if len(set(motors)) != len(motors):
        twice = next(m for m in motors if motors.count(m) > 1)
        raise DatasetError(f"{where}: joint '{twice}' appears twice in the names")
    missing = [d for d in dofs if d not in motors]
    if missing:
        raise DatasetError(f"{where}: no '{missing[0]}{POSITION_SUFFIX}' for joint '{missing[0]}' of '{config.name}'")
    return [motors.index(d) for d in dofs]


def infer_units(dataset: Dataset, columns: list[int], config) -> tuple[str, str]:
    """The dataset's units for its body joints and why (see the module's docstring)."""
    declared = dataset.units_declared
    if declared is not None:
        if declared not in UNITS:
            raise DatasetError(f"{dataset.root / 'meta' / 'info.json'}: feature '{dataset.feature}' states units "
                               f"'{declared}'; servodyn reads {' or '.join(UNITS)}")
        return declared, f"stated in meta/info.json ('{dataset.feature}'.units)"
    body = [c for d, c in zip(config.model.dof_names, columns) if d not in GRIPPERS]
    peak = max((float(np.abs(e.values[:, body]).max()) for e in dataset.episodes), default=0.0) if body else 0.0
    if peak > 100.0:
        return "degrees", f"a joint reaches {peak:.1f}, beyond range_m100_100's ±100"
    major = dataset.version.lstrip("v").split(".")[0]
    if major.isdigit() and int(major) >= 3:
        return "degrees", (f"codebase {dataset.version}, whose followers record degrees by default; "
                           "--units range_m100_100 if this one did not")
    return "range_m100_100", (f"codebase {dataset.version or 'unstated'}, whose followers recorded ±100; "
                              "--units degrees if this one did not")


def to_radians(values: np.ndarray, units: str, config, columns: list[int]) -> np.ndarray:
    """(N, k) dataset values -> (N, n) joint angles in the configuration's dof order."""
    q = np.empty((len(values), len(columns)))
    for j, (joint, c) in enumerate(zip(config.joints, columns)):
        v = values[:, c]
        sense = joint.direction * joint.gear_ratio
        lower, upper = joint.position_limits
        middle, half = (lower + upper) / 2, (upper - lower) / 2
        if joint.dof in GRIPPERS:               # 0..100 from the range's one end to the other
            q[:, j] = middle + joint.direction * (v / 50.0 - 1.0) * half
        elif units == "degrees":
            q[:, j] = v * LEROBOT_DEGREE / sense
        else:                                   # ±100 over the range
            q[:, j] = middle + joint.direction * (v / 100.0) * half
    return q


def smooth(t: np.ndarray, q: np.ndarray, fps: float, cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """The frames on a uniform 1/fps clock from 0, through the zero-phase low-pass (mocap.smoothing's:
    Butterworth forwards and backwards, 3 dB down at `cutoff` for both passes together)."""
    n = int(round(t[-1] * fps)) + 1           # float32 timestamps land a hair off the frame's time
    grid = np.arange(n) / fps
    uniform = np.column_stack([np.interp(grid, t, q[:, j]) for j in range(q.shape[1])])
    return grid, low_pass(uniform, fps, cutoff)


def check_cutoff(cutoff: float, fps: float) -> None:
    if not (math.isfinite(cutoff) and 0 < cutoff < fps / 2):
        raise DatasetError(f"--cutoff must lie between 0 and half the dataset's {fps:g} fps, got {cutoff:g} Hz")


def episode_motion(episode: Episode, dataset: Dataset, config, columns: list[int], units: str,
                   cutoff: float = CUTOFF_HZ) -> MotionPath:
    """The episode as a motion on its own clock (MotionPath: time scaled and sampled like any other)."""
    check_cutoff(cutoff, dataset.fps)
    q = to_radians(episode.values, units, config, columns)
    t, q = smooth(episode.t, q, dataset.fps, cutoff)
    spline = CubicSpline(t, q, axis=0, bc_type="not-a-knot" if len(t) > 3 else "natural")

    def evaluate(times):
        return spline(times), spline(times, 1), spline(times, 2)
    return MotionPath(f"episode_{episode.index}", float(t[-1]), evaluate)
