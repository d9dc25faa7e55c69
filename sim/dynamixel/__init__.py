"""Simulated DYNAMIXEL X-series servos behind the real Protocol 2.0 wire format."""

from .control_table import MODELS, XM430_W350, XM540_W270, HardwareError, Item, Model, OperatingMode
from .device import Exchange, Reply, VirtualBus
from .drive import Mechanics, PositionPid
from .servo import Servo

__all__ = ["MODELS", "XM430_W350", "XM540_W270", "Exchange", "HardwareError", "Item", "Mechanics", "Model",
           "OperatingMode", "PositionPid", "Reply", "Servo", "VirtualBus"]
