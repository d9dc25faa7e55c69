"""The Feetech STS bus described (hal.backend): its servos, rates, ids, one tick's wire time, the
torque range of its PWM command and the resolution of what its servos report.

STS servos have no current loop: the backend drives every joint in Operating_Mode 2 (open-loop
PWM), its torque turned into a duty through the servo's motor model (FeetechSpec.motor, hal.motor)."""

from __future__ import annotations

from ..bus import BITS_PER_BYTE

from ..backend import Backend
from . import protocol
from .table import BAUD_RATES, DEFAULT_BAUD, DUTY_FULL, PRESENT_ADDRESS, PRESENT_LENGTH, SERVOS, STEP

STATUS_OVERHEAD = 6     # FF FF ID LEN ERR .. CHK


def joint_duty(tau, qd, joint, voltage: float):
    """The duty (fraction, unclipped) that gives joint torque `tau` at joint speed `qd` on a joint
    (hal.config.JointConfig) whose servo's motor model is output-referred: the joint's gear G
    multiplies its kt and ke (duty = (τ/(kt·G)·R + ke·G·q̇)/V). The one place a torque becomes a duty."""
    motor, gear = joint.servo.motor, joint.gear_ratio
    return motor.duty_for_current(tau / (gear * motor.torque_constant), voltage, gear * qd)


class Feetech(Backend):
    kind = "feetech"
    bus = "servodyn.hal.feetech.backend:FeetechBus"
    bringup = "servodyn.hal.feetech.session:FeetechBringUp"
    lerobot_calibration = True
    servos = SERVOS
    bauds = BAUD_RATES
    default_baud = DEFAULT_BAUD
    max_id = protocol.MAX_ID
    torque_through_pwm = True

    @classmethod
    def wire_time(cls, joints, bus) -> tuple[float, str]:
        """The tick's SYNC READ of Present Position .. Present Current (instruction and every reply)
        and its SYNC WRITE of the PWM goal."""
        ids = [j.id for j in joints]
        read = len(protocol.sync_read(PRESENT_ADDRESS, PRESENT_LENGTH, ids))
        reply = len(ids) * (STATUS_OVERHEAD + PRESENT_LENGTH)
        write = len(protocol.sync_write(44, 2, {i: b"\0\0" for i in ids}))
        total = read + reply + write
        return total * BITS_PER_BYTE / bus.baud, f"{read} + {reply} + {write} = {total} B at {bus.baud} baud"

    @classmethod
    def command_range(cls, joint) -> tuple[float, float]:
        """Full duty at the servo's nominal voltage, held (ω = 0), and one 0.1 % step of it."""
        voltage = joint.servo.nominal_voltage
        full = 1.0 / joint_duty(1.0, 0.0, joint, voltage)
        return full, full / DUTY_FULL

    @classmethod
    def sensor_steps(cls, joint) -> tuple[float, float]:
        """Present Position's step (4096 a turn) and Present Velocity's (1 step/s), over the gear."""
        return STEP / joint.gear_ratio, STEP / joint.gear_ratio
