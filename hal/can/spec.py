"""The CAN bus of MIT-mode motors described (hal.backend): its motors, bit rates, ids,
configuration keys (dialect, reply id, the frame's ranges), one tick's wire time and the torque
range of the frame's torque field."""

from __future__ import annotations

import re

from ..backend import Backend
from . import frames
from .dialects import DIALECTS
from .motors import MOTORS

BITRATES = (125_000, 250_000, 500_000, 1_000_000)
MAX_ID = 0x7FE                  # 11-bit ids; 0x7FF carries Damiao's register frames
FRAME_BITS = (111, 135)         # an 8-byte standard data frame, without and with the worst stuffing
DEFAULT_INTERFACE = "slcan"     # python-can's interface when the configuration names none
# the serial number (SLCAN `N`) of the simulated adapter says the clock its simulator serves on: a real
# adapter has its own, so a swing on a pseudo-terminal learns its plant's clock this way (served_clock)
SIMULATOR_SERIALS = {"lockstep": "SDLS", "realtime": "SDRT"}


SOCKETCAN_NAME = re.compile(r"^v?can\d+$")     # a Linux network interface: can0, vcan0


def interface_for(channel: str | None, configured: str | None) -> str:
    """python-can's interface for a channel: a SocketCAN link's name (can0, vcan0) means socketcan and
    a device path (/dev/ttyACM0) slcan, whatever the configuration's default; any other channel
    (a gs_usb or PCAN channel, a virtual one) keeps the configured interface."""
    if channel and SOCKETCAN_NAME.match(channel):
        return "socketcan"
    if channel and channel.startswith("/dev/"):
        return "slcan"
    return configured or DEFAULT_INTERFACE


class Can(Backend):
    kind = "can"
    bus = "servodyn.hal.can.backend:CanBus"
    bringup = "servodyn.hal.can.session:CanBringUp"
    servos = MOTORS
    bauds = BITRATES
    default_baud = 1_000_000
    max_id = MAX_ID
    port_key, baud_key = "channel", "bitrate"
    device_key = "motor"
    bus_keys = frozenset({"interface"})
    joint_keys = frozenset({"dialect", "feedback_id", "p_max", "v_max", "t_max", "kp_max", "kd_max"})

    @classmethod
    def new_bus(cls) -> dict:
        return {"kind": cls.kind, "interface": DEFAULT_INTERFACE, **super().new_bus()}

    @classmethod
    def bus_options(cls, checker) -> dict:
        return {"interface": checker.get("interface", "str", DEFAULT_INTERFACE)}

    @classmethod
    def joint_options(cls, checker, servo) -> dict:
        dialect = checker.get("dialect", "str", servo.dialect)
        if dialect not in DIALECTS:
            checker.fail("dialect", f"must be one of {', '.join(DIALECTS)}, got {dialect!r}")
        can_id = checker.get("id", "int")
        feedback_id = checker.get("feedback_id", "int", DIALECTS[dialect].feedback_id(can_id))
        if not 0 <= feedback_id <= MAX_ID or (dialect == "damiao" and feedback_id in (0, can_id)):
            checker.fail("feedback_id", f"0x{feedback_id:X} cannot be a {dialect} motor's reply id "
                                        f"(0..0x{MAX_ID:X}; Damiao: not 0, not the command id)")
        default = servo.ranges
        ranges = {}
        for key in ("p_max", "v_max", "t_max", "kp_max", "kd_max"):
            ranges[key] = checker.positive(key, getattr(default, key))
            if not frames.RANGE_MIN <= ranges[key] <= frames.RANGE_MAX:
                checker.fail(key, f"{ranges[key]:g} is outside the MIT frame codec's ranges "
                                  f"({frames.RANGE_MIN:g} to {frames.RANGE_MAX:g})")
        return {"dialect": dialect, "feedback_id": feedback_id, "ranges": frames.Ranges(**ranges)}

    @classmethod
    def wire_time(cls, joints, bus) -> tuple[float, str]:
        """One command and one reply per motor, 8-byte frames at their worst bit stuffing."""
        bits = 2 * len(joints) * FRAME_BITS[1]
        return bits / bus.baud, f"{2 * len(joints)} frames x {FRAME_BITS[1]} bits at {bus.baud} bit/s"

    @classmethod
    def command_range(cls, joint) -> tuple[float, float]:
        """The frame's torque field: ±t_max at the motor, 12 bits."""
        ranges = joint.options["ranges"]
        return ranges.t_max * joint.gear_ratio, ranges.torque_step * joint.gear_ratio

    @classmethod
    def sensor_steps(cls, joint) -> tuple[float, float]:
        """The MIT reply's position (16 bits over ±p_max) and velocity (12 bits over ±v_max) steps,
        over the joint's gear."""
        ranges = joint.options["ranges"]
        return 2 * ranges.p_max / 65535 / joint.gear_ratio, 2 * ranges.v_max / 4095 / joint.gear_ratio
