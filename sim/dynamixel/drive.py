"""The physical side of a simulated servo, each law written once: its position PID (e-manual gain
scaling), its motor and drive (`Motor`: hal.motor's model; PWM or a current demand → motor current
and PWM at the supply and the shaft's speed) and its output torque with friction (`Mechanics`). The servo
(servo.py) reads its registers and hands the numbers here; nothing else computes them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from servodyn.hal.dynamixel.control_table import PWM_FULL
from servodyn.hal.motor import drive_motor

if TYPE_CHECKING:
    from servodyn.hal.dynamixel.control_table import DynamixelSpec

# The e-manual gives the gains' scaling (KP = P/128, KI = I/65536, KD = D/16) but not the firmware's
# sample time; the I and D terms here count in samples of this period. P's divisor is the catalogue's
# (DynamixelSpec.p_gain_divisor: 256 measured on a real XL330, the e-manual's 128 elsewhere).
CONTROL_PERIOD = 1e-3


def clamp(value, low, high):
    """max(low, min(high, value)) exactly as Python's min and max give it (the first of equals; a
    NaN gives `high`), without their calls' cost (each a microsecond on the simulator's hottest path)."""
    value = value if value < high else high
    return value if value > low else low


@dataclass
class PositionPid:
    """Position PID in table units: error in ticks → PWM units (Position Control Mode) or current
    units (Current-based Position Control Mode). D acts on the measured speed, not the error.
    `p_divisor`: KP = P / p_divisor (the catalogue's DynamixelSpec.p_gain_divisor)."""
    p_divisor: int = 128
    integral: float = 0.0      # ticks × samples

    def reset(self) -> None:
        self.integral = 0.0

    def step(self, error: float, ticks_per_second: float, dt: float,
             gains: tuple[int, int, int], cap: float) -> float:
        p_gain, i_gain, d_gain = gains
        kp, ki, kd = p_gain / self.p_divisor, i_gain / 65536, d_gain / 16
        self.integral += error * dt / CONTROL_PERIOD
        # anti-windup: the integral term alone never exceeds the output cap
        bound = cap / ki if ki else 0.0
        self.integral = clamp(self.integral, -bound, bound)
        out = kp * error + ki * self.integral - kd * ticks_per_second * CONTROL_PERIOD
        return clamp(out, -cap, cap)


@dataclass
class VelocityPi:
    """Velocity Control Mode's PI in table units: error in velocity units (0.229 rpm) → PWM units,
    KvP = P/128 and KvI = I/65536 (e-manual), the integral counted in CONTROL_PERIOD samples."""
    integral: float = 0.0      # velocity units × samples

    def reset(self) -> None:
        self.integral = 0.0

    def step(self, error: float, dt: float, gains: tuple[int, int], cap: float) -> float:
        p_gain, i_gain = gains
        kp, ki = p_gain / 128, i_gain / 65536
        self.integral += error * dt / CONTROL_PERIOD
        bound = cap / ki if ki else 0.0
        self.integral = clamp(self.integral, -bound, bound)
        return clamp(kp * error + ki * self.integral, -cap, cap)


_motor_at = drive_motor


@dataclass(frozen=True)
class Motor:
    """The motor and its drive electronics: hal.motor's voltage-level model of the servo's data sheet
    at the supply it reads (Present Input Voltage: the data sheet's stall torque and no-load speed at
    that voltage), fed a PWM duty of the supply, or its current loop. Speeds are the shaft's in the
    motor's own sign (rad/s at the output), currents in A, PWM in table units of ``pwm_full``."""
    spec: DynamixelSpec
    current_unit: float       # A per Goal Current unit
    pwm_full: int = PWM_FULL  # the PWM that is 100 % duty

    @classmethod
    def of(cls, model: DynamixelSpec) -> Motor:
        return cls(model, model.current_unit)

    def pwm_driven(self, pwm: float, supply: float, velocity: float) -> float:
        """The current (A) a PWM drives at `supply` volts and shaft speed `velocity`: the duty's share
        of the supply less the back-EMF, over the winding (Position Control Mode)."""
        return _motor_at(self.spec, supply).current(pwm / self.pwm_full, supply, velocity)

    def current_driven(self, units: float, pwm_cap: float, supply: float, velocity: float) -> tuple[float, float]:
        """The current loop: the current (A) and PWM for a demand of `units` Goal Current units, as far
        as the PWM cap, the supply (V) and the back-EMF at `velocity` let it reach; (amps, pwm)."""
        amps, duty = _motor_at(self.spec, supply).current_loop(units * self.current_unit, supply, velocity,
                                                               duty_cap=pwm_cap / self.pwm_full)
        return amps, duty * self.pwm_full


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
        return cls(model.datasheet_torque_constant, **overrides)

    @classmethod
    def of_motor(cls, motor) -> Mechanics:
        """A servo whose motor is identified (hal.motor.MotorModel: its k_t and friction at the horn)."""
        return cls(motor.torque_constant, viscous_friction=motor.friction_viscous,
                   coulomb_friction=motor.friction_coulomb)

    def torque(self, current: float, velocity: float) -> float:
        friction = (self.viscous_friction * velocity
                    + self.coulomb_friction * math.tanh(velocity / self.coulomb_velocity))
        return current * self.torque_constant * self.gear_efficiency - friction
