"""The hardware abstraction layer: servo buses in SI units, robot configurations, and the
backends that speak each bus's wire protocol (Dynamixel Protocol 2.0 in `dynamixel`, MIT-mode
motors on CAN in `can`; `loopback` for runs without servos), each described for the
configuration and the validator (`backend`) and with its bring-up (`dynamixel.bringup`,
`can.bringup`); the machine's serial ports in `ports`.

    from servodyn.hal import load_config, make_bus, JointCommand
"""

from .backend import BACKENDS
from .bus import BusStats, JointCommand, JointState, ServoBus, make_bus
from .config import RobotConfig, load_config
from .errors import (ConfigError, HalError, ProtocolError, ServoError, ServoHardwareError,
                     ServoInitializationError, ServoLimitError, ServoOperationError, ServoTimeoutError,
                     BusStallError)

__all__ = ["BACKENDS", "BusStats", "ConfigError", "HalError", "JointCommand", "JointState", "ProtocolError",
           "RobotConfig", "ServoBus", "ServoError", "ServoHardwareError", "ServoInitializationError",
           "ServoLimitError", "ServoOperationError", "ServoTimeoutError", "BusStallError", "load_config", "make_bus"]
