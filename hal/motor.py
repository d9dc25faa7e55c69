"""A servo's motor at the voltage level, written once for the simulator, the validator, identification
and the loop: a DC motor behind its gear, every figure referred to the horn (the output).

    duty × supply (the measured input voltage where known, else the configured supply; a source
    resistance R_s makes it sag with the current drawn) drives the winding (resistance R, warming
    with copper's α) against the back-EMF k_e·ω:

        I = (d·V − k_e·ω) / (R(T) + d²·R_s)        τ_m = k_t·I

    (the supply sees d·I, so V_bus = V − R_s·d·I; the d² term is that sag solved in closed form).
    BAM's DC-motor model is this with k_e = k_t and R_s = 0: τ = k_t·(d·V − k_t·ω)/R.

    A drive with a current loop tracks its goal only as far as ±max_duty of the supply, less the
    back-EMF, lets it (`current_loop`), so the torque–speed envelope emerges from the same line.
    Torque off: the bridge is open, no current flows, the motor coasts (τ_m = 0, no back-EMF braking).

    Gearbox friction: Coulomb F_c, Stribeck F_s·exp(−|ω/ω_s|^shape) and viscous F_v·|ω| make a budget
    (and a share of the torque the motor transmits, the gear's load-dependent loss) make a budget
    that opposes motion and, at rest, holds up to the whole budget (`friction`); the rotor's inertia
    seen at the horn, the armature, adds to the load's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from .thermal import AMBIENT, COPPER_ALPHA


@dataclass(frozen=True)
class MotorModel:
    """One servo's motor, drive and gearbox at the horn. Units: N·m/A (= V·s/rad), Ω, kg·m², N·m,
    N·m·s/rad, rad/s; `back_emf_constant` None: equal to the torque constant (one-constant motor)."""
    torque_constant: float            # k_t, N·m per A at the horn
    resistance: float                 # R at 25 °C, Ω: winding and bridge
    armature: float = 0.0             # kg·m²: the rotor's inertia seen at the horn
    friction_coulomb: float = 0.0     # N·m
    friction_viscous: float = 0.0     # N·m·s/rad
    friction_load: float = 0.0        # N·m of friction per N·m the motor transmits (gear losses)
    friction_stribeck: float = 0.0    # N·m more at rest than sliding
    stribeck_velocity: float = 0.1    # rad/s
    stribeck_shape: float = 2.0       # the exponent of |ω/ω_s|
    back_emf_constant: float | None = None   # k_e, V·s/rad at the horn
    max_duty: float = 1.0             # the largest duty the bridge gives (PWM Limit's 100 %)
    source_resistance: float = 0.0    # Ω between the supply and the servo

    @property
    def ke(self) -> float:
        return self.torque_constant if self.back_emf_constant is None else self.back_emf_constant

    def with_(self, **changes) -> MotorModel:
        return replace(self, **changes)

    def resistance_at(self, temperature=AMBIENT):
        """R at a winding temperature (°C): copper's resistance rises by α per degree."""
        return self.resistance * (1.0 + COPPER_ALPHA * (temperature - AMBIENT))

    def current(self, duty, supply, velocity, temperature=AMBIENT, resistance=None):
        """A through the winding for a duty (−1..1) of `supply` volts at horn speed `velocity`
        (`resistance`: R at the winding's temperature, when the caller has it already)."""
        r = self.resistance_at(temperature) if resistance is None else resistance
        sag = duty * duty * self.source_resistance if self.source_resistance else 0.0
        return (duty * supply - self.ke * velocity) / (r + sag)

    def torque(self, duty, supply, velocity, temperature=AMBIENT, resistance=None):
        """N·m at the horn the motor gives (friction aside) for a duty of the supply (PWM drive)."""
        return self.torque_constant * self.current(duty, supply, velocity, temperature, resistance)

    def duty_for_current(self, amps, supply, velocity, temperature=AMBIENT):
        """The duty that drives `amps` through the winding at `velocity` (R_s neglected), uncapped."""
        return (amps * self.resistance_at(temperature) + self.ke * velocity) / supply

    def current_loop(self, goal, supply, velocity, temperature=AMBIENT, duty_cap=None):
        """A drive's current loop: the current (A) it reaches for a goal (A), as far as ±duty_cap of
        the supply less the back-EMF allows, and the duty it uses; (amps, duty)."""
        cap = self.max_duty if duty_cap is None else duty_cap
        r = self.resistance_at(temperature)
        emf = self.ke * velocity
        high = (cap * supply - emf) / r
        low = (-cap * supply - emf) / r
        amps = np.clip(goal, low, high) if isinstance(goal, np.ndarray) else min(max(goal, low), high)
        return amps, (amps * r + emf) / supply

    def torque_limits(self, supply, velocity, temperature=AMBIENT, current_limit=math.inf):
        """The horn torque range (N·m, friction aside) at `velocity`: full duty either way, and a
        drive's current limit where it has one. The torque–speed envelope, from the same line."""
        r = self.resistance_at(temperature)
        emf = self.ke * velocity
        high = np.minimum((self.max_duty * supply - emf) / r, current_limit)
        low = np.maximum((-self.max_duty * supply - emf) / r, -current_limit)
        return self.torque_constant * low, self.torque_constant * high

    def stall_torque(self, supply, temperature=AMBIENT) -> float:
        return self.torque_constant * self.max_duty * supply / self.resistance_at(temperature)

    def no_load_speed(self, supply) -> float:
        """rad/s at full duty with no torque (friction aside)."""
        return self.max_duty * supply / self.ke

    def friction_budget(self, velocity, motor_torque=0.0):
        """The most friction can oppose at `velocity` (N·m ≥ 0): Coulomb + Stribeck + viscous, and
        the gear's load-dependent share of the torque the motor transmits."""
        speed = np.abs(velocity)
        stribeck = self.friction_stribeck * np.exp(-(speed / self.stribeck_velocity) ** self.stribeck_shape)
        return (self.friction_coulomb + stribeck + self.friction_viscous * speed
                + self.friction_load * np.abs(motor_torque))

    def friction(self, velocity, torque, inertia, dt, motor_torque=0.0):
        """The friction torque (N·m) on a joint of `inertia` (kg·m², armature included) moving at
        `velocity` under `torque` (all else), over one explicit step `dt`: it opposes the torque that
        would stop the joint within the step, up to the budget, so it holds at rest without chatter."""
        return stopping_friction(inertia * velocity / dt + torque, self.friction_budget(velocity, motor_torque))

    @classmethod
    def from_datasheet(cls, spec, voltage: float | None = None, armature: float = 0.0, **friction) -> MotorModel:
        """The estimate from a data sheet (a ServoSpec): k_t = τ_stall / I_stall of the nominal row (gear
        losses at stall included); at the nominal voltage R = V_nom / I_stall and k_e = V_nom / ω₀; at
        another supply V, R = k_t·V / τ_stall(V) and k_e = V / ω₀(V) from the data sheet's rows
        (ServoSpec.stall_torque_at, no_load_speed_at), so that the envelope at V is the data sheet's:
        stall torque τ_stall(V), no-load speed ω₀(V), the line between them."""
        kt = spec.datasheet_torque_constant
        if voltage is None or voltage == spec.nominal_voltage:
            r, ke = spec.nominal_voltage / spec.stall_current, spec.nominal_voltage / spec.no_load_speed
        else:
            r, ke = kt * voltage / spec.stall_torque_at(voltage), voltage / spec.no_load_speed_at(voltage)
        return cls(torque_constant=kt, resistance=r, back_emf_constant=ke, armature=armature, **friction)


@lru_cache(maxsize=256)
def drive_motor(spec, supply: float) -> MotorModel:
    """The motor a servo's drive runs at `supply` volts, as the simulated servo, the HAL's torque through
    PWM and the validator all count on it: the data sheet's estimate at that voltage (from_datasheet), so
    the three agree by construction."""
    return MotorModel.from_datasheet(spec, supply)


def duty_for_torque(spec, torque, supply, velocity, temperature=AMBIENT, torque_constant=None):
    """The duty (uncapped; ±max_duty is the most the bridge gives) that makes `torque` N·m at the horn
    of a `spec` servo turning at `velocity` rad/s on `supply` volts: I = τ / k_t through R(T), plus the
    back-EMF k_e·ω, over the supply. `torque_constant`: the configuration's k_t (default the model's)."""
    motor = drive_motor(spec, float(supply))
    kt = motor.torque_constant if torque_constant is None else torque_constant
    return motor.duty_for_current(np.asarray(torque) / kt, supply, velocity, temperature)


def stopping_friction(stop_torque, budget):
    """−sign(τ_stop)·min(|τ_stop|, budget): friction that opposes the torque stopping the joint."""
    if isinstance(stop_torque, np.ndarray) or isinstance(budget, np.ndarray):
        return -np.sign(stop_torque) * np.minimum(np.abs(stop_torque), budget)
    return -math.copysign(min(abs(stop_torque), budget), stop_torque) if stop_torque else 0.0
