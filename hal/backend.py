"""What each kind of bus is, apart from the bus itself: per backend a static description (its
servo catalogue, the configuration keys and options it takes, one tick's time on its wire, the
torque range its commands reach, the resolution of what its servos report) that the configuration, the
validator and the gain planning read without opening a
port or importing a driver. The bus (hal.bus.ServoBus) opens, reads, writes and stops.

    backend("dynamixel").wire_time(joints, bus)    # a Backend subclass, imported on first use
    backend("can").bus_class()                     # its ServoBus, imported on first use
"""

from __future__ import annotations

import importlib

import numpy as np

from ..control.schedule import Sensors
from .errors import ServoInitializationError

BACKENDS = {   # kind -> "module:class" of its description, imported on first use
    "dynamixel": "servodyn.hal.dynamixel.spec:Dynamixel",
    "loopback": "servodyn.hal.backend:Loopback",
    "can": "servodyn.hal.can.spec:Can",
    "feetech": "servodyn.hal.feetech.spec:Feetech",
}


class Backend:
    """A kind of bus, described: class attributes and class methods only."""

    kind: str = ""
    servos: dict | None = None            # name -> ServoSpec this backend drives (None: any)
    bauds: tuple[int, ...] | None = None  # the rates the bus accepts (None: any positive)
    default_baud: int = 1_000_000
    protocols: tuple[float, ...] | None = None   # the protocol versions it speaks (None: any)
    max_id: int = 255
    joint_keys: frozenset[str] = frozenset()   # configuration keys of this backend's own
    port_key, baud_key = "port", "baud"        # what its [bus] table calls the port and the rate
    device_key = "servo"                       # what a [[joint]] calls its device's model
    bus_keys: frozenset[str] = frozenset()     # [bus] keys of this backend's own
    torque_through_pwm: bool = False           # drives servos without current control by a PWM duty
    # LeRobot's calibration file describes this bus's joints as the host reads them (homing offsets,
    # ranges, drive modes): `calibrate --from-lerobot` imports it (on LeRobot's Dynamixel buses the
    # drive mode lives in the servo, which servodyn's setup clears)
    lerobot_calibration: bool = False

    bus: str = ""                              # "module:class" of its ServoBus
    bringup: str = ""                          # "module:class" of its bring-up (hal.bringup.BringUp), if any

    @classmethod
    def bus_class(cls):
        """The ServoBus of this kind, imported on first use."""
        module_name, class_name = cls.bus.split(":")
        try:
            return getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError) as err:
            raise ServoInitializationError(f"bus kind {cls.kind!r}: cannot load {cls.bus} ({err})") from err

    @classmethod
    def new_bus(cls) -> dict:
        """The [bus] table a new configuration of this kind starts from (servodyn size writes it):
        the port found when the bus opens ('auto') at the default rate."""
        return {"kind": cls.kind, cls.port_key: "auto", cls.baud_key: cls.default_baud}

    @classmethod
    def bus_options(cls, checker) -> dict:
        """This backend's own keys of a [bus] table, checked (checker: hal.config's)."""
        return {}

    @classmethod
    def joint_options(cls, checker, servo) -> dict:
        """This backend's own keys of a [[joint]] table, checked (checker: hal.config's)."""
        return {}

    @classmethod
    def catalogue(cls, bus) -> dict | None:
        """The servo models a joint on `bus` (hal.config.BusConfig) may name: its catalogue, and
        any the kind drives on one of its buses alone (check_joint says which)."""
        return cls.servos

    @classmethod
    def check_joint(cls, checker, servo, bus) -> None:
        """A servo this kind drives but not on this bus (hal.config.BusConfig), refused by checker.fail."""

    @classmethod
    def max_current(cls, servo, options: dict) -> tuple[float, str]:
        """The largest current limit (A) a joint may configure, and how it follows."""
        return servo.max_current, f"{servo.max_current:g} A"

    @classmethod
    def wire_time(cls, joints, bus) -> tuple[float, str]:
        """Seconds one tick's transactions occupy the wire of `bus` (hal.config.BusConfig) for
        these joints, and what they are (the offline validator's bus check)."""
        return 0.0, "no wire"

    @classmethod
    def command_range(cls, joint) -> tuple[float, float]:
        """(largest joint torque the wire can command, its quantization step), N m."""
        return float("inf"), 0.0

    @classmethod
    def sensor_steps(cls, joint) -> tuple[float, float]:
        """(position, velocity) one count of what the servo reports is worth at the joint, rad and
        rad/s; 0 where the measurement is exact (what the gains are planned against)."""
        return 0.0, 0.0


class Loopback(Backend):
    """No servos: the model alone behind the HAL (hal.loopback)."""
    kind = "loopback"
    bus = "servodyn.hal.loopback:LoopbackBus"


def backend(kind: str) -> type[Backend]:
    """The description of a bus kind, imported on first use."""
    if kind not in BACKENDS:
        raise ServoInitializationError(f"no backend for bus kind {kind!r} (known: {', '.join(BACKENDS)})")
    module_name, class_name = BACKENDS[kind].split(":")
    try:
        return getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as err:
        raise ServoInitializationError(f"bus kind {kind!r}: cannot load {BACKENDS[kind]} ({err})") from err


def joint_sensors(config) -> Sensors:
    """The resolution of every joint's measurement of a configuration (hal.config.RobotConfig),
    in model dof order, from its backend."""
    steps = np.array([backend(config.buses[j.bus].kind).sensor_steps(j) for j in config.joints], dtype=float)
    return Sensors(position_step=steps[:, 0], velocity_step=steps[:, 1])


def servo_catalogue(kind: str | None) -> dict:
    """The servo models a bus kind drives, by name (None, or a kind without a catalogue of its
    own such as loopback: every backend's)."""
    servos = backend(kind).servos if kind is not None else None
    if servos is not None:
        return dict(servos)
    every = {}
    for other in BACKENDS:
        every.update(backend(other).servos or {})
    return every
