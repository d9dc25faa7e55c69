"""Joint (SI) ↔ Dynamixel register units, vectorised over joints.

For each joint, with direction d = ±1, gear ratio G (servo horn turns per joint turn) and
zero offset θ0 (the horn angle at q = 0):

    horn angle  θ = d·G·q + θ0               Goal / Present Position = θ · ticks_per_rev / 2π
    horn speed  ω = d·G·q̇                    Goal / Present Velocity = ω · 60 / 2π / velocity_unit
    horn torque τ_h = d·τ / G                motor current i = τ_h / kt
                                             Goal / Present Current = i / current_unit

Values going to a servo are rounded to its integer register units; values coming back are
floats. Arrays broadcast over a leading batch axis: shape (..., n) for n joints. The motor
current reported at the API (`current`, `torque`) is signed in the joint's sense.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..servos import RPM

TWO_PI = 2.0 * np.pi


def current_unit(joint) -> float:
    """A (hal.config) joint's A per Goal / Present Current unit: its configuration's, else its servo's."""
    return joint.options.get("current_unit", joint.servo.current_unit)


@dataclass(frozen=True)
class ServoMap:
    """Conversion constants of n joints, each an (n,) float array."""
    direction: np.ndarray           # ±1: servo positive = joint positive (+1) or negative (-1)
    zero_offset: np.ndarray         # rad: horn angle at q = 0
    gear_ratio: np.ndarray          # horn turns per joint turn (1 = direct drive)
    torque_constant: np.ndarray     # N m per A at the horn
    current_unit: np.ndarray        # A per current register unit
    ticks_per_rev: np.ndarray       # position register units per horn turn
    velocity_unit: np.ndarray       # rpm per velocity register unit

    def __post_init__(self):
        fields = {k: np.array(v, dtype=float, ndmin=1) for k, v in vars(self).items()}
        shapes = {v.shape for v in fields.values()}
        if len(shapes) != 1 or len(shapes.pop()) != 1:
            raise ValueError("ServoMap: every field must be a 1-d array of the same length")
        for key, value in fields.items():
            value.setflags(write=False)
            object.__setattr__(self, key, value)

    @classmethod
    def from_joints(cls, joints) -> "ServoMap":
        """From the joint configurations (hal.config.JointConfig) of Dynamixel servos."""
        return cls(direction=[j.direction for j in joints],
                   zero_offset=[j.zero_offset for j in joints],
                   gear_ratio=[j.gear_ratio for j in joints],
                   torque_constant=[j.torque_constant for j in joints],
                   current_unit=[current_unit(j) for j in joints],
                   ticks_per_rev=[j.servo.ticks_per_rev for j in joints],
                   velocity_unit=[j.servo.velocity_unit for j in joints])

    @property
    def n(self) -> int:
        return len(self.direction)

    @cached_property
    def _sense(self) -> np.ndarray:
        """direction · gear ratio, per joint (the product every conversion divides by)."""
        return self.direction * self.gear_ratio

    @cached_property
    def _joint_per_amp(self) -> np.ndarray:
        """gear ratio · torque constant: N m of joint torque per A."""
        return self.gear_ratio * self.torque_constant

    def state_from_units(self, position, velocity, current) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, motor current, joint torque) of one reading of Present Position, Velocity and
        Current: from_ticks, from_velocity_units, current_from_units and from_current_units in
        one go, the same operations in the same order (so the same numbers), for the tick."""
        q = np.multiply(position, TWO_PI, dtype=float)
        q /= self.ticks_per_rev
        q -= self.zero_offset
        q /= self._sense
        qd = np.multiply(velocity, RPM, dtype=float)
        qd *= self.velocity_unit
        qd /= self._sense
        amps = np.multiply(self.direction, current)
        amps *= self.current_unit
        return q, qd, amps, amps * self.gear_ratio * self.torque_constant

    # position
    def to_ticks(self, q) -> np.ndarray:
        horn = self.direction * self.gear_ratio * np.asarray(q, dtype=float) + self.zero_offset
        return np.rint(horn * self.ticks_per_rev / TWO_PI).astype(np.int64)

    def from_ticks(self, ticks) -> np.ndarray:
        horn = np.asarray(ticks, dtype=float) * TWO_PI / self.ticks_per_rev
        return (horn - self.zero_offset) / (self.direction * self.gear_ratio)

    # velocity
    def to_velocity_units(self, qd) -> np.ndarray:
        horn = self.direction * self.gear_ratio * np.asarray(qd, dtype=float)
        return np.rint(horn / (RPM * self.velocity_unit)).astype(np.int64)

    def from_velocity_units(self, units) -> np.ndarray:
        horn = np.asarray(units, dtype=float) * RPM * self.velocity_unit
        return horn / (self.direction * self.gear_ratio)

    # torque and current
    def current(self, tau) -> np.ndarray:
        """Motor current (A, joint sense) that gives joint torque tau (N m)."""
        return np.asarray(tau, dtype=float) / (self.gear_ratio * self.torque_constant)

    def torque(self, current) -> np.ndarray:
        """Joint torque (N m) of a motor current (A, joint sense)."""
        return np.asarray(current, dtype=float) * self.gear_ratio * self.torque_constant

    def to_current_units(self, tau) -> np.ndarray:
        return np.rint(self.direction * self.current(tau) / self.current_unit).astype(np.int64)

    def goal_current_units(self, tau, current_limit) -> tuple[np.ndarray, np.ndarray]:
        """Goal Current units for joint torques tau, the motor current clamped at current_limit
        (A, per joint); and which joints were clamped (limiting)."""
        wanted = np.asarray(tau, dtype=float) / self._joint_per_amp          # self.current(tau)
        limit = np.asarray(current_limit, dtype=float)
        current = np.minimum(np.maximum(wanted, -limit), limit)             # np.clip, finite values
        units = np.multiply(self.direction, current)
        units /= self.current_unit
        return np.rint(units).astype(np.int64), current != wanted

    def from_current_units(self, units) -> np.ndarray:
        """Joint torque (N m) of a Present Current reading."""
        return self.torque(self.direction * np.asarray(units, dtype=float) * self.current_unit)

    def current_from_units(self, units) -> np.ndarray:
        """Motor current (A, joint sense) of a Present Current reading."""
        return self.direction * np.asarray(units, dtype=float) * self.current_unit
