"""What the loop follows besides the motion: a homing move to the motion's start and PD gains
scheduled along the plan. The host loop and the firmware (whose tables `servodyn codegen` writes
from these) use the same schedules, since the firmware cannot afford the mass matrix inverse at
run time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .timing import BANDWIDTH, GAIN_PERIOD, HOME_DURATION, MAX_BANDWIDTH, MIN_STIFFNESS
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


def scheduled_gains(model, q) -> tuple[np.ndarray, np.ndarray]:
    """PD gains for pose q: each joint gets the bandwidth that gives it MIN_STIFFNESS on its own
    effective inertia, kept between BANDWIDTH and MAX_BANDWIDTH. That inertia varies with the pose
    (shoulder rotation's by 100x between a straight and a bent elbow), so fixed gains are either
    unstable bent or too weak straight: the loop re-schedules them every time_step from the
    desired pose. Light distal joints get the higher bandwidth that stiffness against friction needs."""
    # the inertia a joint sees with the others free, 1 / (M^-1)_ii <= M_ii: gains on M_ii would
    # overdrive a light joint whose neighbours move with it
    inertia = 1.0 / np.diag(np.linalg.inv(model.mass_matrix(q)))
    bandwidth = np.clip(np.sqrt(MIN_STIFFNESS / inertia), BANDWIDTH, MAX_BANDWIDTH)
    return inertia * bandwidth**2, 2 * inertia * bandwidth


@dataclass(frozen=True)
class GainSchedule:
    """PD gains along a planned motion: scheduled_gains() at knots every GAIN_PERIOD of the
    plan, linear in between, held before the first and after the last knot."""
    t: np.ndarray           # (K,) knot times (s)
    kp: np.ndarray          # (K, n) N m/rad
    kd: np.ndarray          # (K, n) N m s/rad

    @classmethod
    def along(cls, model, traj: Trajectory, period: float = GAIN_PERIOD) -> "GainSchedule":
        duration = traj.t[-1] - traj.t[0]
        t = np.linspace(0.0, duration, max(2, int(np.ceil(duration / period - 1e-9)) + 1))
        rows = np.clip(np.rint(t / (traj.t[1] - traj.t[0])).astype(int), 0, len(traj.t) - 1)
        gains = [scheduled_gains(model, traj.q[k]) for k in rows]
        return cls(t=traj.t[rows] - traj.t[0], kp=np.array([g[0] for g in gains]),
                   kd=np.array([g[1] for g in gains]))

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


def plan_gains(model, motion: Trajectory) -> tuple[GainSchedule, GainSchedule]:
    """The gain schedules of homing and of the motion. Homing's is planned along the move from the
    model's rest pose (where an arm powers up): the measured start of a run is not known in
    advance, and the firmware cannot compute gains on line."""
    rest_move = homing(model.neutral_q(), motion.q[0], HOME_DURATION, motion.t[1] - motion.t[0])
    return GainSchedule.along(model, rest_move), GainSchedule.along(model, motion)


def plan_run(model, motion: Trajectory, q_start, home_duration: float = HOME_DURATION) -> tuple[Segment, Segment]:
    """Homing from the measured q_start to the motion's start, then the motion, with their gains."""
    home_gains, motion_gains = plan_gains(model, motion)
    home = homing(q_start, motion.q[0], home_duration, motion.t[1] - motion.t[0])
    return Segment("home", home, home_gains), Segment("motion", motion, motion_gains)
