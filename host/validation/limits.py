"""Every limit of a robot configuration that the checks compare with, at one supply voltage."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..control.timing import SMALL_TIME_STEP
from ..hal.backend import backend
from ..hal.motor import drive_motor, duty_for_torque


@dataclass
class Limits:
    """Every per-joint limit the checks compare with, at one supply voltage (arrays per joint)."""
    lower: np.ndarray
    upper: np.ndarray
    speed: np.ndarray            # rad/s at the joint
    stall_torque: np.ndarray     # N m at the horn, at the supply voltage
    no_load_speed: np.ndarray    # rad/s at the horn, at the supply voltage
    gear: np.ndarray             # horn turns per joint turn
    torque_constant: np.ndarray  # N m / A at the horn: the configured one x its identified scale
    current: np.ndarray          # A
    no_load_current: np.ndarray  # A
    resistance: np.ndarray       # Ω at 25 °C
    thermal_resistance: np.ndarray
    thermal_time_constant: np.ndarray
    temperature: np.ndarray      # °C
    command: np.ndarray          # N m at the joint
    command_step: np.ndarray     # N m
    voltage: float
    supply_current: float | None
    wire: list = field(default_factory=list)   # (bus name, seconds per tick, description)
    period: float = SMALL_TIME_STEP            # s: the configuration's control period, the sampling
    friction_coulomb: np.ndarray | None = None   # N m at the joint (the configuration's; None: none)
    friction_viscous: np.ndarray | None = None   # N m s/rad at the joint
    pwm: np.ndarray | None = None                # per joint: driven in PWM mode (its duty, not its current, checked)
    servos: list = field(default_factory=list)   # the joints' servos (ServoSpec)

    def duty(self, tau: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """(N, n) the duty of the supply each joint in PWM mode needs for joint torques `tau` at joint
        speeds `qd`, back-EMF included (hal.motor.duty_for_torque: the equations the HAL turns the
        controller's torque into Goal PWM with, and the simulated servo its Goal PWM into torque); 0
        for the others. Beyond ±1 the servo's PWM Limit saturates."""
        out = np.zeros(np.shape(tau))
        for j in np.flatnonzero(self.pwm) if self.pwm is not None else ():
            out[:, j] = duty_for_torque(self.servos[j], tau[:, j] / self.gear[j], self.voltage, qd[:, j] * self.gear[j],
                                        torque_constant=self.torque_constant[j])
        return out

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """The joints' friction torque (N m) against their speeds: F_c·sign(q̇) + F_v·q̇, what the
        servos must give on top of the rigid-body torque."""
        if self.friction_coulomb is None:
            return np.zeros_like(qd)
        return self.friction_coulomb * np.sign(qd) + self.friction_viscous * qd

    @classmethod
    def of(cls, config, voltage: float) -> "Limits":
        joints = config.joints
        servos = [j.servo for j in joints]
        command = [backend(config.buses[j.bus].kind).command_range(j) for j in joints]
        wire = []
        for name, bus in config.buses.items():
            seconds, what = backend(bus.kind).wire_time(config.joints_on(name), bus)
            wire.append((name, seconds, what))
        arr = lambda values: np.array(list(values), dtype=float)
        gear = arr(j.gear_ratio for j in joints)
        # the torque-speed envelope from the motor model the simulated servos run (hal.motor): at this
        # supply its stall torque and no-load speed are the data sheet's
        motors = [drive_motor(s, voltage) for s in servos]
        # driven through PWM: a joint configured so, and any whose servo has no current control
        pwm = np.array([j.options.get("drive", "current" if j.servo.current_control else "pwm") == "pwm"
                        for j in joints], dtype=bool)
        no_load = arr(m.no_load_speed(voltage) for m in motors)
        return cls(lower=arr(j.position_limits[0] for j in joints), upper=arr(j.position_limits[1] for j in joints),
                   speed=np.minimum(arr(j.velocity_limit for j in joints), no_load / gear),
                   stall_torque=arr(m.stall_torque(voltage) for m in motors), no_load_speed=no_load, gear=gear,
                   # judged in the data sheet's world, as the envelope: a servo whose torque constant is an
                   # identified motor's (a Feetech's) is counted in the data sheet's, its configured scale kept
                   torque_constant=arr(j.torque_constant * s.datasheet_torque_constant / s.torque_constant
                                       for j, s in zip(joints, servos)),
                   current=arr(j.current_limit for j in joints),
                   no_load_current=arr(s.no_load_current for s in servos),
                   resistance=arr(s.winding_resistance for s in servos),
                   thermal_resistance=arr(j.thermal_resistance for j in joints),
                   thermal_time_constant=arr(j.thermal_time_constant for j in joints),
                   temperature=arr(s.temperature_limit for s in servos),
                   # a joint in PWM mode: Goal PWM's ±100 % at this supply commands at most its stall torque
                   command=np.where(pwm, gear * arr(m.stall_torque(voltage) for m in motors), arr(c[0] for c in command)),
                   command_step=arr(c[1] for c in command), pwm=pwm, servos=servos,
                   friction_coulomb=arr(j.friction_coulomb for j in joints),
                   friction_viscous=arr(j.friction_viscous for j in joints),
                   voltage=voltage, supply_current=config.supply.current_limit if config.supply else None,
                   wire=wire, period=config.control_period)
