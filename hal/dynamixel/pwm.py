"""Torque through PWM: the joints a Dynamixel bus drives in PWM Control Mode (Operating Mode 16).

A servo without current control (XL430-W250, XC430-W240), or one configured `drive = "pwm"` (the
XL330 and XC330, whose current loops regulate the supply's current rather than the motor's), gets the
controller's joint torque as a duty of its supply through hal.motor's DC motor:

    τ_h = d·τ / G      ω = d·G·q̇      duty = (τ_h / k_t · R(T) + k_e·ω) / V      Goal PWM = duty · 885

with V the servo's Present Input Voltage and T its Present Temperature (both read at a low rate, in the
same read; the configured supply until the first), ω the measured speed (the back-EMF), and the duty
capped at PWM Limit's ±100 % (a capped joint counts as limiting). No current limit acts in PWM mode.
"""

from __future__ import annotations

import numpy as np

from ..motor import duty_for_torque
from ..thermal import AMBIENT
from .control_table import PWM_FULL

PWM, CURRENT = "pwm", "current"      # a Dynamixel joint's `drive`
DRIVES = (CURRENT, PWM)


def pwm_driven(joint) -> bool:
    """Whether a (hal.config) joint is driven in PWM Control Mode."""
    return joint.options.get("drive") == PWM


def drive_of(checker, servo) -> str:
    """A [[joint]]'s `drive`, checked: 'current' (Current Control Mode) where the servo has it, else
    'pwm' (the default for a servo without current control)."""
    drive = checker.get("drive", "str", CURRENT if servo.current_control else PWM)
    if drive not in DRIVES:
        checker.fail("drive", f"{drive!r}: one of {', '.join(DRIVES)}")
    if drive == CURRENT and not servo.current_control:
        checker.fail("drive", f"{servo.name} has no current control mode: drive = \"pwm\" drives it by its "
                              "torque through PWM")
    return drive


class PwmDrive:
    """The joints of one bus in PWM mode: their duty for the controller's torque, tick by tick."""

    def __init__(self, joints, supply: float | None):
        self.index = np.array([k for k, j in enumerate(joints) if pwm_driven(j)], dtype=np.intp)
        chosen = [joints[k] for k in self.index]
        self.servos = [j.servo for j in chosen]
        self.sense = np.array([j.direction * j.gear_ratio for j in chosen], dtype=float)
        self.torque_constant = np.array([j.torque_constant for j in chosen], dtype=float)
        # V: the configured supply (each servo's nominal voltage without one) until Present Input Voltage is read
        self.supply = np.array([supply or s.nominal_voltage for s in self.servos], dtype=float)

    def __len__(self) -> int:
        return len(self.index)

    def measured(self, voltage: np.ndarray) -> None:
        """Present Input Voltage (V, every joint of the bus) as last read."""
        self.supply = np.asarray(voltage, dtype=float)[self.index]

    def duty(self, tau, qd, temperature) -> np.ndarray:
        """The duty (uncapped, the servo's sense) for joint torques `tau` at joint speeds `qd` (every
        joint of the bus) with the windings at `temperature` (°C; nan: not read yet, 25 °C)."""
        k = self.index
        horn_torque = np.asarray(tau, dtype=float)[k] / self.sense
        horn_speed = np.asarray(qd, dtype=float)[k] * self.sense
        heat = np.nan_to_num(np.asarray(temperature, dtype=float)[k], nan=AMBIENT)
        return np.array([duty_for_torque(s, t, v, w, c, kt) for s, t, v, w, c, kt in
                         zip(self.servos, horn_torque, self.supply, horn_speed, heat, self.torque_constant)])

    def goal_pwm(self, tau, qd, temperature) -> tuple[np.ndarray, np.ndarray]:
        """Goal PWM units for the joints in PWM mode, and which were capped at ±PWM Limit (limiting)."""
        units = np.rint(self.duty(tau, qd, temperature) * PWM_FULL)
        capped = np.clip(units, -PWM_FULL, PWM_FULL)
        return capped.astype(np.int64), capped != units
