"""The plant: the configured arm's physics, whatever wire its servos speak.

The arm moves by the C core's direct dynamics (Armstrong-Green + RK4 at small_time_step). Each
joint is driven by a `Drive` — a simulated servo or motor seen from its shaft: every step the
plant tells each drive where its horn is (`set_present`), asks it for the motor current to hold
over the step (`output_current`) and for the torque at the horn that current gives
(`output_torque`), then integrates the joint torques. A Dynamixel servo is one kind of drive; a
CAN motor model is another, and slots in without touching this file.

The horn of joint k turns by direction·gear·q + zero_offset (hal.config's JointConfig).

Each joint stops at the model's limits, its mechanical range: past one, a critically damped spring
of time constant STOP_TIME_CONSTANT on the joint's own inertia pushes it back (MuJoCo's soft
limits), so an arm left with torque off hangs on its stops as the real one does instead of folding
through them (the replicas' elbows sagged 0.05-0.1 rad past full extension in 5 s).
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np

from servodyn.control.timing import SMALL_TIME_STEP

STOP_TIME_CONSTANT = 0.01     # s: a joint's stop as a spring-damper (natural frequency 100 rad/s:
                              # 0.1 rad a step at 1 ms, well inside RK4's stable range)


class Drive(Protocol):
    """What the plant needs of an actuator, in SI at its horn."""

    def set_present(self, position: float, velocity: float, current: float) -> None: ...

    def output_current(self, position: float, velocity: float, dt: float) -> float: ...

    def output_torque(self, current: float, velocity: float) -> float: ...


class Plant:
    """A model driven through its joints' drives; q and qd in the model's dof order."""

    def __init__(self, model, joints: Sequence, drives: Sequence[Drive], *,
                 small_time_step: float = SMALL_TIME_STEP, q0=None, integrator: str = "rk4"):
        if [j.dof for j in joints] != list(model.dof_names) or len(drives) != len(joints):
            raise ValueError("Plant: one joint and one drive per dof of the model, in its dof order")
        self.model, self.drives = model, list(drives)
        self.small_time_step, self.integrator = small_time_step, integrator
        self.direction = np.array([j.direction for j in joints], dtype=float)
        self.gear_ratio = np.array([j.gear_ratio for j in joints], dtype=float)
        self.zero_offset = np.array([j.zero_offset for j in joints], dtype=float)
        self._scale = self.direction * self.gear_ratio
        self.q = model.neutral_q() if q0 is None else np.array(q0, dtype=float)
        self.qd = np.zeros(model.nv)
        self.current = np.zeros(model.nv)          # A at each drive, over the last step
        self.time = 0.0
        # the stops: the model's limits, each dof's inertia where the arm starts (the spring's time
        # constant is close to STOP_TIME_CONSTANT wherever the arm is); a stop can be broken (stops)
        self.lower, self.upper = np.array(model.lower, dtype=float), np.array(model.upper, dtype=float)
        self._stop_inertia = np.diag(model.mass_matrix(self.q)).copy()
        self.stops = np.ones(model.nv, dtype=bool)
        self.publish()

    def horn(self, q, qd) -> tuple[np.ndarray, np.ndarray]:
        """Each drive's horn angle and speed for the joint state."""
        scale = self._scale
        return scale * q + self.zero_offset, scale * qd

    def publish(self) -> None:
        """Tell every drive where its horn is."""
        position, velocity = self.horn(self.q, self.qd)
        for drive, p, v, i in zip(self.drives, position.tolist(), velocity.tolist(), self.current.tolist()):
            drive.set_present(p, v, i)

    def advance(self, duration: float) -> None:
        """Run for `duration` seconds in small_time_step steps; each drive is sampled once per
        step (its current held over it)."""
        steps = max(1, int(round(duration / self.small_time_step)))
        scale = self._scale
        horn_torque = np.empty(len(self.drives))
        for _ in range(steps):
            position, velocity = self.horn(self.q, self.qd)
            for k, (drive, p, v) in enumerate(zip(self.drives, position.tolist(), velocity.tolist())):
                self.current[k] = current = float(drive.output_current(p, v, self.small_time_step))
                horn_torque[k] = drive.output_torque(current, v)
            self.q, self.qd = self.model.step(self.q, self.qd, scale * horn_torque + self.stop_torque(),
                                              self.small_time_step, self.integrator)
            self.time += self.small_time_step
            self.publish()


    def push(self, k: int, angle: float) -> None:
        """An external push puts joint k at `angle`, past its stop if need be: that stop gives from
        then on (a fault, sim/arm.py's "pushed")."""
        self.q[k] = angle
        self.stops[k] = False

    def stop_torque(self) -> np.ndarray:
        """The joints' stops at (q, qd): zero inside the limits; past one, the spring-damper's torque,
        which only ever pushes back (it never holds a joint that is leaving its stop)."""
        q, qd = self.q, self.qd
        past = np.minimum(q - self.lower, 0.0) + np.maximum(q - self.upper, 0.0)
        if not past.any():
            return np.zeros_like(q)
        w = 1.0 / STOP_TIME_CONSTANT
        push = -self._stop_inertia * (w * w * past + 2.0 * w * qd)
        push = np.where(past > 0, np.minimum(push, 0.0), np.maximum(push, 0.0))    # back, never on
        return np.where((past != 0) & self.stops, push, 0.0)


class PlantView:
    """The plant's clock and state, read through whatever holds a `plant` (a simulated arm or robot)."""

    plant: Plant

    @property
    def time(self) -> float:
        return self.plant.time

    @property
    def q(self):
        return self.plant.q

    @property
    def qd(self):
        return self.plant.qd
