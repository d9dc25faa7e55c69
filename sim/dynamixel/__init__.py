"""Simulated DYNAMIXEL X-series servos behind the real Protocol 2.0 wire format, in Python alone:

- `servo`: one servo (`Servo`): its control table, a device of the bench, the bus watchdog and
  Realtime Tick, heat and hardware errors, and the side the plant steps (its Present registers,
  the operating mode's demand each step);
- `instructions`: the instructions that act on one servo and the e-manual's write rules (a part
  of `Servo`);
- `drive`: the physical laws, each written once: the position PID, the motor and its drive
  (`Motor`: PWM or a current demand → motor current and PWM, at the supply and the back-EMF),
  the output torque with friction (`Mechanics`);
- `chain`: the servos of one bus as the plant's drive chain and the bus's clock (`ServoChain`);
- `wire`: the bus answering the host's bytes (`DynamixelWire`): framing, line speed, dispatch;
- `replies`: what goes back on the wire: status replies, collisions, fast read replies.

The servo models and their control tables are the HAL's (`servodyn.hal.dynamixel.control_table`)."""

from servodyn.hal.dynamixel.control_table import (MODELS, SERVOS, XH430_W350, XH540_W270, XM430_W350, XM540_W270,
                                                  HardwareError, Item, DynamixelSpec, OperatingMode)

from .chain import ServoChain
from .drive import Mechanics, Motor, PositionPid
from .replies import Exchange, Reply
from .servo import Servo
from .wire import DynamixelWire

__all__ = ["MODELS", "SERVOS", "XH430_W350", "XH540_W270", "XM430_W350", "XM540_W270", "Exchange", "HardwareError",
           "Item", "Mechanics", "Motor", "DynamixelSpec", "OperatingMode", "PositionPid", "Reply", "Servo",
           "ServoChain", "DynamixelWire"]
