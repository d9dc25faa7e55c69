"""Simulated DYNAMIXEL X-series servos behind the real Protocol 2.0 wire format: each servo's
control table (`servo`) and physics (`drive`), their per-tick work for a whole chain at once
(`chain`, in C where it can), and the bus that answers the host's packets (`wire`).
The servo models and their control tables are the HAL's (`servodyn.hal.dynamixel.control_table`)."""

from servodyn.hal.dynamixel.control_table import (MODELS, SERVOS, XH430_W350, XH540_W270, XM430_W350, XM540_W270,
                                                  HardwareError, Item, DynamixelSpec, OperatingMode)

from .chain import ServoChain
from .wire import Exchange, Reply, DynamixelWire
from .drive import Mechanics, PositionPid
from .servo import Servo

__all__ = ["MODELS", "SERVOS", "XH430_W350", "XH540_W270", "XM430_W350", "XM540_W270", "Exchange", "HardwareError",
           "Item", "Mechanics", "DynamixelSpec", "OperatingMode", "PositionPid", "Reply", "Servo", "ServoChain", "DynamixelWire"]
