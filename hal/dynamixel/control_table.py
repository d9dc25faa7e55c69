"""X-series control tables (Protocol 2.0) and the data sheets of the servos servodyn drives.

The one place a Dynamixel register, unit or figure is written: the configuration checks against
it, the backend takes its addresses and units from it, and the simulated servo is built from it.
From the ROBOTIS e-manual pages of the X-series servos (addresses, sizes, access, defaults,
ranges) and their performance tables (stall torque and current, no-load speed at 12 V).
Addresses 0..146 are modelled; indirect addresses, external ports and backups are not.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from ..servos import RPM, ServoSpec

EEPROM_END = 64                # addresses below are EEPROM, writable only with torque off
TABLE_SIZE = 147               # up to Present Temperature(146)
TICKS_PER_REV = 4096           # position unit: 0.088°
VELOCITY_UNIT = 0.229 * RPM    # rad/s per unit (0.229 rpm)
PWM_FULL = 885                 # Goal/Present PWM unit is 0.113 %: 885 = 100 %
GOAL_POSITION_SPAN = 1_048_575  # ±256 rev: Goal Position range outside Position Control Mode
WATCHDOG_UNIT = 0.020          # s per Bus Watchdog(98) unit
RETURN_DELAY_UNIT = 2e-6       # s per Return Delay Time(9) unit
BAUD_RATES = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000)  # Baud Rate(8) 0..7
FAST_READ_FIRMWARE = 45        # Firmware Version(6) from which X430/540 take FAST SYNC/BULK READ (0x8A, 0x9A)
DRIVE_MODE_REVERSE = 0x01      # Drive Mode(10) bit 0: Present/Goal Position counted the other way


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


def watchdog_units(seconds: float) -> int:
    """Bus Watchdog(98) value for a silence of `seconds` (at least one unit: 0 disables it)."""
    return max(1, int(round(seconds / WATCHDOG_UNIT)))


HARDWARE_FAULTS = {bit.name.lower().replace("_", " "): bit for bit in HardwareError}   # "overload" -> bit


def hardware_faults(status: int) -> tuple[str, ...]:
    """The names of the bits set in a Hardware Error Status value ("overload", ...)."""
    return tuple(name for name, bit in HARDWARE_FAULTS.items() if status & bit)


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


@dataclass(frozen=True, kw_only=True)
class Model(ServoSpec):
    """One X-series servo model: its data sheet at 12 V (ROBOTIS e-manual) and its control table.
    The HAL (configuration, units, backend) and the simulated servo both read it from here."""
    kind: str = "dynamixel"
    model_number: int           # Model Number(0)
    current_limit_max: int      # maximum and default of Current Limit(38), in current units
    velocity_limit_default: int  # default of Velocity Limit(44), in velocity units
    current_unit: float = 2.69e-3   # A per Goal / Present Current unit
    ticks_per_rev: int = TICKS_PER_REV   # Goal / Present Position units per horn turn
    velocity_unit: float = 0.229     # rpm per Goal / Present Velocity unit
    firmware: int = 46          # fast sync/bulk read need FAST_READ_FIRMWARE or later

    @property
    def max_current(self) -> float:
        return self.current_limit_max * self.current_unit

    def items(self) -> tuple[Item, ...]:
        return (
            # EEPROM
            _ro("model_number", 0, 2, self.model_number),
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
            Item("current_limit", 38, 2, self.current_limit_max, low=0, high=self.current_limit_max),
            Item("velocity_limit", 44, 4, self.velocity_limit_default, low=0, high=1023),
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


# The e-manual's rows at 12 V and at 11.1 and 14.8 V (stall torque and current, no-load speed; the
# XH540-W270's other rows are not in our notes), Current Limit(38) ranges and
# Velocity Limit(44) defaults. The XH540-W270's Velocity Limit default is not in our notes: its
# no-load speed in 0.229 rpm units, rounded down. No-load current: a fit of the XM430-W350's
# torque-current curve gives 0.125 A (5.4 % of its stall current); the others are given the same
# fraction. Temperature Limit(31) defaults to 80 °C. ROBOTIS publishes no thermal resistance or
# time constant: R_th and τ_th are estimates for a 28 mm (X430) and a 33 mm (X540) motor in a
# closed plastic case — R_th such that the winding reaches 80 °C from 25 °C at about 40 % of the
# stall current, τ_th a few minutes — to be identified on the arm from Present Temperature(146)
# under a known current.
_X430 = dict(gear_ratio=353.5, thermal_resistance=12.0, thermal_time_constant=240.0)
_X540 = dict(gear_ratio=272.5, thermal_resistance=6.0, thermal_time_constant=420.0)
XM430_W350 = Model(name="XM430-W350", model_number=1020, stall_torque=4.1, stall_current=2.3, no_load_speed_rpm=46.0,
                   no_load_current=0.125, current_limit_max=1193, velocity_limit_default=200,
                   ratings=((11.1, 3.8, 2.1, 43.0), (14.8, 4.8, 2.7, 57.0)), **_X430)
XM540_W270 = Model(name="XM540-W270", model_number=1120, stall_torque=10.6, stall_current=4.4, no_load_speed_rpm=30.0,
                   no_load_current=0.24, current_limit_max=2047, velocity_limit_default=128,
                   ratings=((11.1, 10.0, 4.2, 28.0), (14.8, 12.9, 5.5, 37.0)), **_X540)
XH430_W350 = Model(name="XH430-W350", model_number=1000, stall_torque=3.4, stall_current=1.3, no_load_speed_rpm=30.0,
                   no_load_current=0.07, current_limit_max=648, velocity_limit_default=130,
                   ratings=((11.1, 3.1, 1.2, 27.0), (14.8, 4.2, 1.5, 37.0)), **_X430)
XH540_W270 = Model(name="XH540-W270", model_number=1100, stall_torque=9.9, stall_current=4.9, no_load_speed_rpm=39.0,
                   no_load_current=0.26, current_limit_max=2047, velocity_limit_default=170, **_X540)
SERVOS = {m.name: m for m in (XM430_W350, XM540_W270, XH430_W350, XH540_W270)}
MODELS = {m.model_number: m for m in SERVOS.values()}

# the items the host reads and writes, by address
ITEMS = {item.name: item for item in XM430_W350.items()}
ADDR_MODEL_NUMBER = ITEMS["model_number"].address
ADDR_RETURN_DELAY = ITEMS["return_delay_time"].address
ADDR_OPERATING_MODE = ITEMS["operating_mode"].address
ADDR_TORQUE_ENABLE = ITEMS["torque_enable"].address
ADDR_HARDWARE_ERROR = ITEMS["hardware_error_status"].address
ADDR_BUS_WATCHDOG = ITEMS["bus_watchdog"].address
ADDR_GOAL_CURRENT = ITEMS["goal_current"].address
ADDR_PRESENT = ITEMS["present_current"].address      # Present Current (2), Velocity (4), Position (4)
PRESENT_LENGTH = sum(ITEMS[n].size for n in ("present_current", "present_velocity", "present_position"))
# the same read on to Present Temperature (146, 1 byte, °C): what the loop reads at a low rate
ADDR_PRESENT_TEMPERATURE = ITEMS["present_temperature"].address
PRESENT_WITH_TEMPERATURE_LENGTH = ADDR_PRESENT_TEMPERATURE + 1 - ADDR_PRESENT
