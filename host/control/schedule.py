"""What the loop follows besides the motion: a homing move to the motion's start and PD gains
scheduled along the plan. The host loop and the firmware (whose tables `servodyn codegen` writes
from these) use the same schedules, since the firmware cannot afford the mass matrix inverse at
run time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .timing import (BANDWIDTH, ERROR_FILTER_RATIO, GAIN_PERIOD, HOME_DURATION, MAX_BANDWIDTH, MIN_STIFFNESS,
                     QUANTUM_SHARE)
from .trajectory import Trajectory


def homing(q_from, q_to, duration: float, dt: float) -> Trajectory:
    """A minimum-jerk move between two poses, at rest at both ends."""
    n = max(2, int(round(duration / dt)) + 1)
    t = np.arange(n) * dt
    s = t / t[-1]
    blend = 10 * s**3 - 15 * s**4 + 6 * s**5
    rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / t[-1]
    accel = (60 * s - 180 * s**2 + 120 * s**3) / t[-1] ** 2
    delta = np.asarray(q_to) - np.asarray(q_from)
    return Trajectory(t=t, q=q_from + np.outer(blend, delta), qd=np.outer(rate, delta),
                      qdd=np.outer(accel, delta), derived=True)


@dataclass(frozen=True)
class Sensors:
    """What one count of each joint's measurement is worth, at the joint: the position a servo
    reports (rad, an encoder tick over the gear) and the velocity (rad/s, one unit of its
    register); 0 where the measurement is exact (a loopback bus). The HAL's backends say it
    (hal.backend.joint_sensors)."""
    position_step: np.ndarray     # (n,) rad
    velocity_step: np.ndarray     # (n,) rad/s

    @property
    def quantised(self) -> bool:
        return bool(np.any(self.position_step > 0) or np.any(self.velocity_step > 0))

    def quantum_torque(self, kp, kd) -> np.ndarray:
        """N m the PD commands for one count of each sensor: kp dq + kd dv."""
        return np.asarray(kp) * self.position_step + np.asarray(kd) * self.velocity_step


def resolution_bandwidth(inertia, sensors: Sensors, torque_scale) -> np.ndarray:
    """The highest bandwidth w (rad/s) whose critically damped PD on `inertia`, kp = I w² and
    kd = 2 I w, commands at most QUANTUM_SHARE of `torque_scale` for one count of each sensor:
    the root of I (w² dq + 2 w dv) = Q, written so that a zero dq (or dv) divides by nothing.
    Infinite where both sensors are exact."""
    c = QUANTUM_SHARE * np.asarray(torque_scale, dtype=float) / np.asarray(inertia, dtype=float)
    dq, dv = sensors.position_step, sensors.velocity_step
    denominator = dv + np.sqrt(dv**2 + dq * c)
    with np.errstate(divide="ignore"):
        return np.where(denominator > 0, c / np.where(denominator > 0, denominator, 1.0), np.inf)


def scheduled_gains(model, q, sensors: Sensors | None = None, torque_scale=None) -> tuple[np.ndarray, np.ndarray]:
    """PD gains for pose q: each joint gets the bandwidth that gives it MIN_STIFFNESS on its own
    effective inertia, kept between BANDWIDTH and MAX_BANDWIDTH. That inertia varies with the pose
    (shoulder rotation's by 100x between a straight and a bent elbow), so fixed gains are either
    unstable bent or too weak straight: the loop re-schedules them every time_step from the
    desired pose. Light distal joints get the higher bandwidth that stiffness against friction needs.

    With the joints' `sensors` and `torque_scale` (N m, the largest torque each joint's plan
    asks, planned_torque_scale), the bandwidth is also kept under resolution_bandwidth: a servo's
    measurement moves in counts (a Dynamixel's 0.088° tick and 0.229 rpm unit), and a PD stiff for
    the rotor inertia turns each count into a step of torque that buzzes (on the replica's wrist
    flexion one tick and one velocity unit commanded 56 % of the largest torque the swing asks).
    The feed-forward carries the motion, so the PD is softer there, never under MIN_STIFFNESS
    (the servo's friction)."""
    # the inertia a joint sees with the others free, 1 / (M^-1)_ii <= M_ii: gains on M_ii would
    # overdrive a light joint whose neighbours move with it
    inertia = 1.0 / np.diag(np.linalg.inv(model.mass_matrix(q)))
    bandwidth = bandwidth_of(inertia, sensors, torque_scale)
    return inertia * bandwidth**2, 2 * inertia * bandwidth


def bandwidth_of(inertia, sensors: Sensors | None = None, torque_scale=None) -> np.ndarray:
    """The bandwidth (rad/s) scheduled_gains gives joints of these effective inertias."""
    stiff = np.sqrt(MIN_STIFFNESS / inertia)
    bandwidth = np.clip(stiff, BANDWIDTH, MAX_BANDWIDTH)
    if sensors is not None and torque_scale is not None:
        bandwidth = np.maximum(np.minimum(bandwidth, resolution_bandwidth(inertia, sensors, torque_scale)),
                               np.minimum(stiff, MAX_BANDWIDTH))
    return bandwidth


def error_lowpass(bandwidth, dt: float) -> np.ndarray:
    """The one-pole coefficient of the low-pass the controller step puts on each joint's errors,
    cut off at ERROR_FILTER_RATIO times its bandwidth (rad/s), for a control period dt: the
    estimate of the tracking error (and so of the velocity) that the PD acts on. The desired
    motion is its prediction and the measurement its correction, so the lag (1 / the cut-off,
    8 to 13 ms on the replica) delays only the PD's answer to an error, not the motion; the
    count-sized steps of a quantised measurement are smoothed to a fraction above the cut-off."""
    return 1.0 - np.exp(-ERROR_FILTER_RATIO * np.asarray(bandwidth, dtype=float) * dt)


def planned_torque_scale(model, *trajectories: Trajectory) -> np.ndarray:
    """Each joint's torque scale (N m): the largest |feed-forward| (inverse dynamics of the
    desired motion) along the trajectories."""
    return np.max([np.abs(model.inverse_dynamics(tr.q, tr.qd, tr.qdd)).max(axis=0) for tr in trajectories], axis=0)


@dataclass(frozen=True)
class GainSchedule:
    """PD gains along a planned motion: scheduled_gains() at knots every GAIN_PERIOD of the
    plan, linear in between, held before the first and after the last knot; and the low-pass of
    the errors they act on (per joint, for the highest bandwidth the schedule gives it; zero, no
    filter, where the sensors are exact)."""
    t: np.ndarray           # (K,) knot times (s)
    kp: np.ndarray          # (K, n) N m/rad
    kd: np.ndarray          # (K, n) N m s/rad
    error_lowpass: np.ndarray | None = None   # (n,) one-pole coefficient, error_lowpass()

    @classmethod
    def along(cls, model, traj: Trajectory, period: float = GAIN_PERIOD, sensors: Sensors | None = None,
              torque_scale=None) -> "GainSchedule":
        duration = traj.t[-1] - traj.t[0]
        dt = traj.t[1] - traj.t[0]
        t = np.linspace(0.0, duration, max(2, int(np.ceil(duration / period - 1e-9)) + 1))
        rows = np.clip(np.rint(t / dt).astype(int), 0, len(traj.t) - 1)
        gains = [scheduled_gains(model, traj.q[k], sensors, torque_scale) for k in rows]
        kp, kd = np.array([g[0] for g in gains]), np.array([g[1] for g in gains])
        lowpass = np.zeros(model.nv)
        if sensors is not None and sensors.quantised:
            lowpass = error_lowpass((2 * kp / kd).max(axis=0), dt)     # kp / kd = w / 2
        return cls(t=traj.t[rows] - traj.t[0], kp=kp, kd=kd, error_lowpass=lowpass)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        k = int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2))
        s = float(np.clip((t - self.t[k]) / (self.t[k + 1] - self.t[k]), 0.0, 1.0))
        return (self.kp[k] + s * (self.kp[k + 1] - self.kp[k]),
                self.kd[k] + s * (self.kd[k + 1] - self.kd[k]))


@dataclass(frozen=True)
class Segment:
    """One stretch of a run: a trajectory sampled every control period and its gains."""
    name: str
    traj: Trajectory
    gains: GainSchedule


def plan_gains(model, motion: Trajectory, sensors: Sensors | None = None) -> tuple[GainSchedule, GainSchedule]:
    """The gain schedules of homing and of the motion. Homing's is planned along the move from the
    model's rest pose (where an arm powers up): the measured start of a run is not known in
    advance, and the firmware cannot compute gains on line. With the joints' `sensors` the gains
    are bounded by their resolution against each joint's torque scale over both (scheduled_gains)."""
    rest_move = homing(model.neutral_q(), motion.q[0], HOME_DURATION, motion.t[1] - motion.t[0])
    scale = planned_torque_scale(model, rest_move, motion) if sensors is not None else None
    return (GainSchedule.along(model, rest_move, sensors=sensors, torque_scale=scale),
            GainSchedule.along(model, motion, sensors=sensors, torque_scale=scale))


def plan_run(model, motion: Trajectory, q_start, home_duration: float = HOME_DURATION,
             sensors: Sensors | None = None) -> tuple[Segment, Segment]:
    """Homing from the measured q_start to the motion's start, then the motion, with their gains."""
    home_gains, motion_gains = plan_gains(model, motion, sensors)
    home = homing(q_start, motion.q[0], home_duration, motion.t[1] - motion.t[0])
    return Segment("home", home, home_gains), Segment("motion", motion, motion_gains)
