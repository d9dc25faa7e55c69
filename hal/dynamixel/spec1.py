"""A Dynamixel bus on Protocol 1.0 described (hal.dynamixel.spec dispatches here by the bus's
`protocol` or the joint's servo): which servos it takes, its rates, one tick's wire time, the
torque range of its commands and the resolution of what its servos report.

A tick on 1.0: one BULK READ (MX) of each servo's span (table1.present_length), or one READ per
servo where a servo of the bus takes no BULK READ (AX-12A), and one SYNC WRITE per goal register
(Goal Torque(71) of the joints in torque mode, Goal Position(30) of the joints driven through their
position loop)."""

from __future__ import annotations

from ..bus import BITS_PER_BYTE

from . import protocol1
from .table1 import (BAUD_RATES, CURRENT_UNIT, GOAL_TORQUE_MAX, SERVOS1, Dynamixel1Spec, is_protocol1,
                     present_length, speed_rad)



def check_joint(checker, servo, bus) -> None:
    """A servo on a bus of the other protocol: one line naming the fix."""
    if bus.protocol == 1.0 and not is_protocol1(servo):
        checker.fail("servo", f"{servo.name} is an X-series servo, driven on Protocol 2.0 only (servodyn has its "
                              f"2.0 control table), but bus '{bus.name}' has protocol = 1.0: set protocol = 2.0 "
                              f"or choose one of {', '.join(SERVOS1)}")
    if bus.protocol != 1.0 and is_protocol1(servo):
        checker.fail("servo", f"{servo.name} speaks Protocol 1.0 (its 1.0 firmware's control table) but bus "
                              f"'{bus.name}' has protocol = {bus.protocol:.1f}: set protocol = 1.0 on it")


def joint_options(checker, servo) -> dict:
    """A 1.0 servo takes neither `drive` nor `current_unit`: how it is driven and its units follow
    from its model (table1)."""
    for key in ("drive", "current_unit"):
        if key in checker.table:
            how = "torque control mode, 4.5 mA a unit" if servo.torque_mode else "its position loop (no current loop)"
            checker.fail(key, f"does not apply to the {servo.name} on Protocol 1.0 (driven by {how}): leave it out")
    return {}


def check_baud(checker, protocol: float, baud: int) -> None:
    if protocol == 1.0 and baud not in BAUD_RATES:
        checker.fail("baud", f"{baud} is not a Protocol 1.0 rate (Baud Rate(4): "
                             f"{', '.join(map(str, BAUD_RATES))})")


def sequential(joints) -> bool:
    """The tick reads servo by servo (a servo of the bus takes no BULK READ)."""
    return not all(j.servo.bulk_read for j in joints)


def tick_bytes(joints) -> tuple[int, int, int]:
    """(instruction bytes, reply bytes, goal-write bytes) of one tick on a 1.0 bus."""
    spans = [(j.id, 36, present_length(j.servo)) for j in joints]
    if sequential(joints):
        read = sum(len(protocol1.read(i, a, n)) for i, a, n in spans)
    else:
        read = len(protocol1.bulk_read(spans))
    reply = sum(protocol1.STATUS_OVERHEAD + n for _, _, n in spans)
    torque = {j.id: b"\0\0" for j in joints if j.servo.torque_mode}
    position = {j.id: b"\0\0" for j in joints if not j.servo.torque_mode}
    write = sum(len(protocol1.sync_write(30, 2, group)) for group in (torque, position) if group)
    return read, reply, write


def wire_time(joints, bus) -> tuple[float, str]:
    read, reply, write = tick_bytes(joints)
    total = read + reply + write
    how = "READ per servo" if sequential(joints) else "BULK READ"
    return total * BITS_PER_BYTE / bus.baud, f"{read} + {reply} + {write} = {total} B at {bus.baud} baud ({how})"


def command_range(joint) -> tuple[float, float]:
    """Torque mode: Goal Torque's ±1023 x 4.5 mA through the joint's k_t; the position loop: the
    motor's stall torque at the nominal voltage and the duty of one position unit of error."""
    servo: Dynamixel1Spec = joint.servo
    if servo.torque_mode:
        per_unit = CURRENT_UNIT * joint.torque_constant * joint.gear_ratio
        return GOAL_TORQUE_MAX * per_unit, per_unit
    stall = servo.motor_model.stall_torque(servo.nominal_voltage) * joint.gear_ratio
    return stall, stall * servo.duty_per_tick(32)


def sensor_steps(joint) -> tuple[float, float]:
    servo: Dynamixel1Spec = joint.servo
    return servo.step / joint.gear_ratio, speed_rad(servo) / joint.gear_ratio
