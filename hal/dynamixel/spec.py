"""The Dynamixel X-series bus described (hal.backend): its servos, rates, ids, configuration keys,
one tick's wire time and the torque range of Goal Current (of Goal PWM for a joint in PWM mode)."""

from __future__ import annotations

import math

from ..backend import Backend
from ..bus import BITS_PER_BYTE
from ..servos import RPM
from . import instructions
from ..motor import drive_motor
from .control_table import (ADDR_GOAL_CURRENT, ADDR_PRESENT, BAUD_RATES, PRESENT_WITH_TEMPERATURE_LENGTH, PWM_FULL,
                            SERVOS)
from .pwm import drive_of, pwm_driven
from .protocol import MAX_ID
from .units import current_unit
from . import spec1
from .table1 import SERVOS1, is_protocol1



def wire_seconds(nbytes: int, baud: int) -> float:
    """Seconds `nbytes` take on the wire at `baud`, stuffing aside."""
    return nbytes * BITS_PER_BYTE / baud


class Dynamixel(Backend):
    kind = "dynamixel"
    bus = "servodyn.hal.dynamixel.backend1:dynamixel_bus"     # DynamixelBus, or Dynamixel1Bus on protocol 1.0
    bringup = "servodyn.hal.dynamixel.session:DynamixelBringUp"
    servos = SERVOS             # the X-series, on 2.0: what sizing picks from
    bauds = BAUD_RATES          # a 1.0 bus takes those of them Baud Rate(4) has too (bus_options)
    default_baud = 4_000_000
    protocols = (2.0, 1.0)      # the first is the default
    max_id = MAX_ID
    joint_keys = frozenset({"current_unit", "drive"})
    torque_through_pwm = True    # a servo without current control is driven by its torque through PWM (pwm.py)

    @classmethod
    def new_bus(cls) -> dict:
        return {**super().new_bus(), "protocol": cls.protocols[0]}

    @classmethod
    def bus_options(cls, checker) -> dict:
        protocol, baud = checker.get("protocol", "float", cls.protocols[0]), checker.get("baud", "int", cls.default_baud)
        spec1.check_baud(checker, protocol, baud)
        return {}

    @classmethod
    def catalogue(cls, bus) -> dict:
        """The X-series and the 1.0 servos (hal/dynamixel/table1.py: AX and MX on a protocol = 1.0 bus)."""
        return {**SERVOS, **SERVOS1}

    @classmethod
    def check_joint(cls, checker, servo, bus) -> None:
        spec1.check_joint(checker, servo, bus)

    @classmethod
    def joint_options(cls, checker, servo) -> dict:
        if is_protocol1(servo):
            return spec1.joint_options(checker, servo)
        return {"current_unit": checker.positive("current_unit", servo.current_unit), "drive": drive_of(checker, servo)}

    @classmethod
    def max_current(cls, servo, options: dict) -> tuple[float, str]:
        if is_protocol1(servo):
            return servo.max_current, (f"Goal Torque's 1023 x 4.5 mA" if servo.torque_mode else
                                       "its stall current (no current loop)")
        if options["drive"] == "pwm":       # no current limit acts in PWM mode: the data sheet's stall currents
            highest = max(servo.stall_current, *(row[2] for row in servo.ratings))
            return highest, f"its highest stall current (PWM mode limits no current), {highest:g} A"
        unit = options["current_unit"]
        return servo.current_limit_max * unit, f"{servo.current_limit_max} x {unit:g} A"

    @classmethod
    def wire_time(cls, joints, bus) -> tuple[float, str]:
        """The worst tick's fast sync read (instruction and reply) and Goal Current sync write on
        the wire (wire_seconds). The worst tick is the one in TEMPERATURE_EVERY whose read runs on
        to Present Temperature."""
        if any(is_protocol1(j.servo) for j in joints):
            return spec1.wire_time(joints, bus)
        ids = [j.id for j in joints]
        read = len(instructions.fast_sync_read(ADDR_PRESENT, PRESENT_WITH_TEMPERATURE_LENGTH, ids).encode())
        reply = instructions.fast_reply_size([PRESENT_WITH_TEMPERATURE_LENGTH] * len(ids))
        if any(pwm_driven(j) for j in joints):      # a bulk write: Goal PWM or Goal Current per servo
            write = len(instructions.bulk_write([(i, ADDR_GOAL_CURRENT, b"\0\0") for i in ids]).encode())
        else:
            write = len(instructions.sync_write(ADDR_GOAL_CURRENT, 2, {i: b"\0\0" for i in ids}).encode())
        total = read + reply + write
        return wire_seconds(total, bus.baud), f"{read} + {reply} + {write} = {total} B at {bus.baud} baud"

    @classmethod
    def command_range(cls, joint) -> tuple[float, float]:
        """Goal Current is clamped to ±Current Limit(38), in whole current units; Goal PWM (PWM mode) to
        ±PWM Limit(36): at most the stall torque at the servo's highest rated supply, in 1/885 of it."""
        if is_protocol1(joint.servo):
            return spec1.command_range(joint)
        if pwm_driven(joint):
            servo = joint.servo
            volts = max(servo.nominal_voltage, *(row[0] for row in servo.ratings))
            stall = drive_motor(servo, volts).stall_torque(volts) * joint.gear_ratio
            return stall, stall / PWM_FULL
        unit = current_unit(joint)
        per_unit = unit * joint.torque_constant * joint.gear_ratio
        return round(joint.current_limit / unit) * per_unit, per_unit

    @classmethod
    def sensor_steps(cls, joint) -> tuple[float, float]:
        """Present Position's tick (a turn of the horn over ticks_per_rev) and Present Velocity's
        unit (velocity_unit rpm), over the joint's gear."""
        if is_protocol1(joint.servo):
            return spec1.sensor_steps(joint)
        servo = joint.servo
        return 2 * math.pi / servo.ticks_per_rev / joint.gear_ratio, servo.velocity_unit * RPM / joint.gear_ratio
