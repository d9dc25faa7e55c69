"""The physical side of a simulated servo: its position PID (e-manual gain scaling) and the
current → output torque relation with friction."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from servodyn.hal.dynamixel.control_table import DynamixelSpec

# The e-manual gives the gains' scaling (KP = P/128, KI = I/65536, KD = D/16) but not the firmware's
# sample time; the I and D terms here count in samples of this period.
CONTROL_PERIOD = 1e-3


@dataclass
class PositionPid:
    """Position PID in table units: error in ticks → PWM units (Position Control Mode) or current
    units (Current-based Position Control Mode). D acts on the measured speed, not the error."""
    integral: float = 0.0      # ticks × samples

    def reset(self) -> None:
        self.integral = 0.0

    def step(self, error: float, ticks_per_second: float, dt: float,
             gains: tuple[int, int, int], cap: float) -> float:
        p_gain, i_gain, d_gain = gains
        kp, ki, kd = p_gain / 128, i_gain / 65536, d_gain / 16
        self.integral += error * dt / CONTROL_PERIOD
        # anti-windup: the integral term alone never exceeds the output cap
        bound = cap / ki if ki else 0.0
        self.integral = max(-bound, min(bound, self.integral))
        out = kp * error + ki * self.integral - kd * ticks_per_second * CONTROL_PERIOD
        return max(-cap, min(cap, out))


@dataclass(frozen=True)
class Mechanics:
    """Output torque = current × torque_constant × gear_efficiency − viscous − Coulomb friction.

    The default torque constant is the datasheet's stall torque over stall current at 12 V, which
    already includes the gear losses (so gear_efficiency defaults to 1). The Coulomb step is smoothed
    by tanh(velocity / coulomb_velocity) so that a fixed-step integrator does not chatter at rest.
    """
    torque_constant: float             # N·m/A at the output shaft
    gear_efficiency: float = 1.0
    viscous_friction: float = 0.01     # N·m·s/rad
    coulomb_friction: float = 0.02     # N·m
    coulomb_velocity: float = 0.01     # rad/s

    @classmethod
    def of(cls, model: DynamixelSpec, **overrides: float) -> Mechanics:
        return cls(model.stall_torque / model.stall_current, **overrides)

    def torque(self, current: float, velocity: float) -> float:
        friction = (self.viscous_friction * velocity
                    + self.coulomb_friction * math.tanh(velocity / self.coulomb_velocity))
        return current * self.torque_constant * self.gear_efficiency - friction
