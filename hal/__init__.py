"""The hardware abstraction layer: servo buses in SI units, robot configurations, and the
backends that speak each bus's wire protocol (Dynamixel; loopback for tests without servos).

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
