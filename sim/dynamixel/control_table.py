"""X-series control tables (Protocol 2.0) and the figures of the modelled servos.

From the ROBOTIS e-manual pages of the XM430-W350 and XM540-W270 (addresses, sizes, access,
defaults, ranges) and the X-series performance table (stall torque and current, no-load speed).
Addresses 0..146 are modelled; indirect addresses, external ports and backups are not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

EEPROM_END = 64                # addresses below are EEPROM, writable only with torque off
TABLE_SIZE = 147               # up to Present Temperature(146)
TICKS_PER_REV = 4096           # position unit: 0.088°
VELOCITY_UNIT = 0.229 * 2 * math.pi / 60   # rad/s per unit (0.229 rpm)
PWM_FULL = 885                 # Goal/Present PWM unit is 0.113 %: 885 = 100 %
GOAL_POSITION_SPAN = 1_048_575  # ±256 rev: Goal Position range outside Position Control Mode


class OperatingMode(IntEnum):
    """The modes the simulated drive implements (1 velocity, 4 extended position and 16 PWM exist
    on the real servo but are refused here with a data range error)."""
    CURRENT = 0
    POSITION = 3
    CURRENT_POSITION = 5


class HardwareError(IntEnum):
    """Bits of Hardware Error Status(70) and Shutdown(63)."""
    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20


@dataclass(frozen=True)
class Item:
    """One control-table item. A value outside ``low..high``, ``choices`` or ``mask`` is a data range
    error; outside ±(the item named by ``limit``) a data limit error. ``default`` None: set at
    start-up from other items or the present state."""
    name: str
    address: int
    size: int
    default: int | None = 0
    writable: bool = True
    signed: bool = False
    low: int | None = None
    high: int | None = None
    choices: frozenset[int] | None = None
    mask: int | None = None
    limit: str | None = None

    @property
    def eeprom(self) -> bool:
        return self.address < EEPROM_END


def _ro(name: str, address: int, size: int, default: int | None = None, signed: bool = False) -> Item:
    return Item(name, address, size, default, writable=False, signed=signed)


def _gain(name: str, address: int, default: int) -> Item:
    return Item(name, address, 2, default, low=0, high=16383)


@dataclass(frozen=True)
class Model:
    """One servo model: its control table and the figures the drive model needs."""
    name: str
    number: int
    current_limit: int          # maximum and default of Current Limit(38), 2.69 mA units
    velocity_limit: int         # default of Velocity Limit(44)
    stall_torque: float         # N·m at the output, at nominal voltage
    stall_current: float        # A, at nominal voltage
    no_load_speed_rpm: float    # at nominal voltage
    nominal_voltage: float = 12.0
    current_unit: float = 2.69e-3   # A per Goal/Present Current unit
    firmware: int = 46          # fast sync/bulk read need X430/540 firmware 45 or later

    @property
    def no_load_speed(self) -> float:
        return self.no_load_speed_rpm * 2 * math.pi / 60

    def items(self) -> tuple[Item, ...]:
        return (
            # EEPROM
            _ro("model_number", 0, 2, self.number),
            _ro("model_information", 2, 4, 0),
            _ro("firmware_version", 6, 1, self.firmware),
            Item("id", 7, 1, 1, low=0, high=252),
            Item("baud_rate", 8, 1, 1, low=0, high=7),
            Item("return_delay_time", 9, 1, 250, low=0, high=254),
            Item("drive_mode", 10, 1, 0, mask=0x05),      # bit 0 reverse, bit 2 time-based profile
            Item("operating_mode", 11, 1, OperatingMode.POSITION, choices=frozenset(OperatingMode)),
            Item("secondary_id", 12, 1, 255, choices=frozenset([*range(253), 255])),
            Item("protocol_type", 13, 1, 2, low=2, high=2),  # Protocol 1.0 is not simulated
            Item("homing_offset", 20, 4, 0, signed=True, low=-1_044_479, high=1_044_479),
            Item("moving_threshold", 24, 4, 10, low=0, high=1023),
            Item("temperature_limit", 31, 1, 80, low=0, high=100),
            Item("max_voltage_limit", 32, 2, 160, low=95, high=160),
            Item("min_voltage_limit", 34, 2, 95, low=95, high=160),
            Item("pwm_limit", 36, 2, PWM_FULL, low=0, high=PWM_FULL),
            Item("current_limit", 38, 2, self.current_limit, low=0, high=self.current_limit),
            Item("velocity_limit", 44, 4, self.velocity_limit, low=0, high=1023),
            Item("max_position_limit", 48, 4, TICKS_PER_REV - 1, low=0, high=TICKS_PER_REV - 1),
            Item("min_position_limit", 52, 4, 0, low=0, high=TICKS_PER_REV - 1),
            Item("shutdown", 63, 1, 0x34, mask=sum(HardwareError)),
            # RAM
            Item("torque_enable", 64, 1, 0, low=0, high=1),
            Item("led", 65, 1, 0, low=0, high=1),
            Item("status_return_level", 68, 1, 2, low=0, high=2),
            _ro("registered_instruction", 69, 1, 0),
            _ro("hardware_error_status", 70, 1, 0),
            _gain("velocity_i_gain", 76, 1920),
            _gain("velocity_p_gain", 78, 100),
            _gain("position_d_gain", 80, 0),
            _gain("position_i_gain", 82, 0),
            _gain("position_p_gain", 84, 800),
            _gain("feedforward_2nd_gain", 88, 0),
            _gain("feedforward_1st_gain", 90, 0),
            Item("bus_watchdog", 98, 1, 0, signed=True, low=0, high=127),  # -1: tripped
            Item("goal_pwm", 100, 2, None, signed=True, limit="pwm_limit"),
            Item("goal_current", 102, 2, None, signed=True, limit="current_limit"),
            Item("goal_velocity", 104, 4, 0, signed=True, limit="velocity_limit"),
            Item("profile_acceleration", 108, 4, 0, low=0, high=32767),
            Item("profile_velocity", 112, 4, 0, low=0, high=32767),
            Item("goal_position", 116, 4, None, signed=True),   # range depends on the mode
            _ro("realtime_tick", 120, 2),
            _ro("moving", 122, 1),
            _ro("moving_status", 123, 1, 0),
            _ro("present_pwm", 124, 2, signed=True),
            _ro("present_current", 126, 2, signed=True),
            _ro("present_velocity", 128, 4, signed=True),
            _ro("present_position", 132, 4, signed=True),
            _ro("velocity_trajectory", 136, 4, signed=True),
            _ro("position_trajectory", 140, 4, signed=True),
            _ro("present_input_voltage", 144, 2),
            _ro("present_temperature", 146, 1),
        )


XM430_W350 = Model("XM430-W350", 1020, current_limit=1193, velocity_limit=200,
                   stall_torque=4.1, stall_current=2.3, no_load_speed_rpm=46)
XM540_W270 = Model("XM540-W270", 1120, current_limit=2047, velocity_limit=128,
                   stall_torque=10.6, stall_current=4.4, no_load_speed_rpm=30)
MODELS = {m.number: m for m in (XM430_W350, XM540_W270)}
