"""What every servo's data sheet says, in SI: the fields the configuration, the HAL and the
simulator need whatever wire the servo speaks. A backend's catalogue subclasses `ServoSpec`
with its own registers and units (`hal/dynamixel/control_table.py`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

RPM = 2.0 * math.pi / 60.0          # rad/s per rpm


@dataclass(frozen=True, kw_only=True)
class ServoSpec:
    """A servo model at its nominal supply voltage; torque and speed at the horn (its output)."""
    name: str
    kind: str                     # the bus kind that speaks to it
    gear_ratio: float             # the servo's internal reduction (the horn is its output)
    stall_torque: float           # N m
    stall_current: float          # A
    no_load_speed_rpm: float      # rpm
    nominal_voltage: float = 12.0  # V

    @property
    def torque_constant(self) -> float:
        """Default N m per A at the horn: stall torque / stall current (calibrate per joint)."""
        return self.stall_torque / self.stall_current

    @property
    def no_load_speed(self) -> float:
        """rad/s at the horn."""
        return self.no_load_speed_rpm * RPM

    @property
    def max_current(self) -> float:
        """A: the largest current limit the servo accepts (its register's range)."""
        return self.stall_current
