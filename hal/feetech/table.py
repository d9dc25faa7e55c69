"""The STS/SMS memory table, its units and sign bits, the baud table, and the data sheets of the
Feetech servos servodyn drives: the one place a Feetech register, unit or figure is written (the
configuration checks against it, the backend and the simulated servo take it from here).

Addresses, sizes, defaults and units: Feetech's STS memory table (its wiki, and the English table
of the fw 3.x era), cross-checked with Feetech's SDK and LeRobot's tables; sign bits: the SDK's
scs_toscs (position and speed bit 15, the PWM goal bit 10), LeRobot's encodings table (Present
Load bit 10, Homing Offset bit 11) and the debug tool's Present Current (bit 15). All of it with
its sources in ../shared/notes/servos/feetech.md §2-§4.

The EEPROM lock is inverted against what its name says: Lock(55) = 0 *unlocks* (a write to an
EEPROM address is kept across a power cycle), 1 locks (EEPROM writes act until power-off only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property

from ..motor import MotorModel
from ..servos import RPM, ServoSpec
from .protocol import PacketError, decode_sign_magnitude, encode_sign_magnitude

TICKS_PER_REV = 4096             # Present/Goal Position: 0.088° a step
STEP = 2 * math.pi / TICKS_PER_REV   # rad per position step, and rad/s per speed unit (step/s)
DUTY_FULL = 1000                 # Goal_Time in mode 2 and Present Load: 0.1 % a unit
VOLTAGE_UNIT = 0.1               # V per Present Voltage unit
CURRENT_UNIT = 6.5e-3            # A per Present Current / Protection Current unit
RETURN_DELAY_UNIT = 2e-6         # s per Return Delay Time unit
PROTECTION_TIME_UNIT = 0.01      # s per Protection Time / Over Current Protection Time unit
EEPROM_END = 40                  # addresses below are EEPROM (kept across power-off when Lock = 0)
TABLE_SIZE = 87                  # up to the factory area's last item (86)
BAUD_RATES = (1_000_000, 500_000, 250_000, 128_000, 115_200, 76_800, 57_600, 38_400)   # Baud_Rate(6) 0..7
DEFAULT_BAUD = 1_000_000
# A simulated servo answers a READ of one byte here with the clock its simulator serves on
# (SIMULATOR_CLOCKS); the STS table ends at 86, so a real servo answers no such byte: how a swing on
# a pseudo-terminal learns its plant's clock (hal/served_clock.py)
SIMULATOR_CLOCK_ADDRESS = 0xF0
SIMULATOR_CLOCKS = {1: "lockstep", 2: "realtime"}


class Mode(IntEnum):
    """Operating_Mode(33)."""
    POSITION = 0
    SPEED = 1
    PWM = 2
    STEP = 3


@dataclass(frozen=True)
class Item:
    """One register. ``sign_bit``: a sign-magnitude field's sign (None: unsigned)."""
    name: str
    address: int
    size: int
    default: int = 0
    writable: bool = True
    sign_bit: int | None = None
    unit: str = ""

    @property
    def eeprom(self) -> bool:
        return self.address < EEPROM_END


ITEMS = (
    # EEPROM
    Item("firmware_major", 0, 1, 3, writable=False),
    Item("firmware_minor", 1, 1, 10, writable=False),
    Item("end", 2, 1, 0, writable=False, unit="0: little-endian"),
    Item("model_number", 3, 2, 777, writable=False),
    Item("id", 5, 1, 1),
    Item("baud_rate", 6, 1, 0, unit="code of BAUD_RATES"),
    Item("return_delay_time", 7, 1, 0, unit="2 us"),
    Item("response_status_level", 8, 1, 1),
    Item("min_position_limit", 9, 2, 0, unit="step"),
    Item("max_position_limit", 11, 2, 4095, unit="step"),
    Item("max_temperature_limit", 13, 1, 70, unit="degC"),
    Item("max_voltage_limit", 14, 1, 80, unit="0.1 V"),
    Item("min_voltage_limit", 15, 1, 40, unit="0.1 V"),
    Item("max_torque_limit", 16, 2, 1000, unit="0.1 %"),
    Item("phase", 18, 1, 12),
    Item("unloading_condition", 19, 1, 44),
    Item("led_alarm_condition", 20, 1, 47),
    Item("p_coefficient", 21, 1, 32),
    Item("d_coefficient", 22, 1, 32),
    Item("i_coefficient", 23, 1, 0),
    Item("minimum_startup_force", 24, 1, 16, unit="0.1 %"),
    Item("cw_dead_zone", 26, 1, 1, unit="step"),
    Item("ccw_dead_zone", 27, 1, 1, unit="step"),
    Item("protection_current", 28, 2, 500, unit="6.5 mA"),
    Item("angular_resolution", 30, 1, 1),
    Item("homing_offset", 31, 2, 0, sign_bit=11, unit="step"),
    Item("operating_mode", 33, 1, Mode.POSITION),
    Item("protective_torque", 34, 1, 20, unit="%"),
    Item("protection_time", 35, 1, 200, unit="10 ms"),
    Item("overload_torque", 36, 1, 80, unit="%"),
    Item("speed_p", 37, 1, 10),
    Item("over_current_protection_time", 38, 1, 200, unit="10 ms"),
    Item("speed_i", 39, 1, 10),
    # SRAM control
    Item("torque_enable", 40, 1, 0),
    Item("acceleration", 41, 1, 0, unit="100 step/s^2"),
    Item("goal_position", 42, 2, 0, sign_bit=15, unit="step"),
    Item("goal_time", 44, 2, 0, sign_bit=10, unit="0.1 % duty in mode 2"),
    Item("goal_velocity", 46, 2, 0, sign_bit=15, unit="step/s"),
    Item("torque_limit", 48, 2, 1000, unit="0.1 %"),
    Item("lock", 55, 1, 1, unit="0: EEPROM writes kept; power-on 1 (newest table; fw 3.x: 0)"),
    # SRAM feedback
    Item("present_position", 56, 2, writable=False, sign_bit=15, unit="step"),
    Item("present_velocity", 58, 2, writable=False, sign_bit=15, unit="step/s"),
    Item("present_load", 60, 2, writable=False, sign_bit=10, unit="0.1 % duty"),
    Item("present_voltage", 62, 1, writable=False, unit="0.1 V"),
    Item("present_temperature", 63, 1, writable=False, unit="degC"),
    Item("async_write_flag", 64, 1, writable=False),
    Item("status", 65, 1, writable=False),
    Item("moving", 66, 1, writable=False),
    Item("present_current", 69, 2, writable=False, sign_bit=15, unit="6.5 mA"),
)
ITEM = {item.name: item for item in ITEMS}
PRESENT_ADDRESS, PRESENT_LENGTH = 56, 15        # Present Position .. Present Current, read each tick


def item_value(name: str, raw: int) -> int:
    """A register's value from its raw unsigned bytes (sign-magnitude decoded)."""
    sign = ITEM[name].sign_bit
    return raw if sign is None else decode_sign_magnitude(raw, sign)


def item_raw(name: str, value: int) -> int:
    """A register's raw unsigned value for `value` (sign-magnitude encoded); ProtocolError out of range."""
    item = ITEM[name]
    if item.sign_bit is not None:
        return encode_sign_magnitude(value, item.sign_bit)
    if not 0 <= value < 1 << (8 * item.size):
        raise PacketError(f"{name}: {value} does not fit {item.size} byte(s)")
    return int(value)


def baud_code(baud: int) -> int:
    return BAUD_RATES.index(baud)


@dataclass(frozen=True, kw_only=True)
class FeetechSpec(ServoSpec):
    """A Feetech STS/SMS servo: its data sheet (ServoSpec) and the voltage-level motor model the
    backend inverts to turn a torque into a PWM duty and the simulated servo runs forwards:
    i = (V·duty − ke·ω)/R, τ = kt·i, output-referred (at the horn: the internal gear folded in, as
    Rhoban's BAM writes it). STS servos have no current loop: Operating_Mode 2 is open-loop PWM."""
    kind: str = "feetech"
    current_control: bool = False
    model_number: int = 777
    motor_kt: float               # N m/A at the horn
    motor_ke: float               # V s/rad at the horn (back-EMF)
    motor_resistance: float       # Ω
    armature: float               # kg m² at the horn (reflected rotor inertia)
    friction_coulomb: float = 0.0  # N m at the horn
    friction_viscous: float = 0.0  # N m s/rad at the horn
    ticks_per_rev: int = TICKS_PER_REV
    velocity_unit: float = 60.0 / TICKS_PER_REV   # rpm per speed unit (1 step/s)
    source: str = ""

    @cached_property
    def motor(self) -> MotorModel:
        """The voltage-level motor at the horn (hal.motor), the one the backend inverts to turn a
        torque into a duty, the simulated servo runs forwards and identification starts from; its
        bridge gives at most MAX_DUTY (BAM's max_pwm)."""
        return MotorModel(torque_constant=self.motor_kt, back_emf_constant=self.motor_ke,
                          resistance=self.motor_resistance, armature=self.armature,
                          friction_coulomb=self.friction_coulomb, friction_viscous=self.friction_viscous,
                          max_duty=MAX_DUTY)

    @property
    def torque_constant(self) -> float:
        """N m per A at the horn: the motor model's kt. Present_Current reads the motor's current, so
        torque = current x kt (the data sheet's stall torque / stall current is another figure: 0.96
        against BAM's 1.21 for the STS3215, and identification from current took it 21 % low)."""
        return self.motor_kt

    @property
    def max_current(self) -> float:
        """Protection_Current(28)'s top: 2047 x 6.5 mA (the newest table's range)."""
        return 2047 * CURRENT_UNIT


KG_CM = 9.80665e-2        # N m per kg cm
# Position mode's law (P, I = D = 0): duty = POSITION_GAIN x P x error (rad), capped at ±MAX_DUTY; both
# measured by Rhoban's BAM with an oscilloscope on an STS3215 (bam/feetech/actuator.py: error_gain
# 0.166, max_pwm 0.97). Feetech's table writes P at 1/4 (0.163 per P per rad in 0.1 % duty steps)
POSITION_GAIN = 0.166     # duty per (P unit x rad of position error)
MAX_DUTY = 0.97
# Rhoban BAM's identified STS3215 (7.4 V) model m1, the only one identified for it (bam/params/
# feetech_sts3215_7_4V/m1.json): the anchor every STS3215 entry below is scaled from
BAM_KT, BAM_R, BAM_ARMATURE, BAM_KC, BAM_KV = 1.21164135295077, 2.6761663274455603, 0.02840336348682085, \
    0.05239296084748866, 0.05908515565091076
_BAM = "BAM STS3215 m1 fit (Rhoban/bam bam/params/feetech_sts3215_7_4V/m1.json): kt = ke, R, armature, friction"


def _geared(gear: float) -> dict:
    """The motor model of an STS3215 of another gear than the C001's 1/345: the same motor, so kt,
    ke scale with the gear and the armature with its square (DERIVED from BAM's fit, an estimate)."""
    k = gear / 345.0
    return dict(motor_kt=BAM_KT * k, motor_ke=BAM_KT * k, motor_resistance=BAM_R, armature=BAM_ARMATURE * k * k,
                friction_coulomb=BAM_KC * k, friction_viscous=BAM_KV * k)


STS3215_C001 = FeetechSpec(
    name="STS3215-C001", gear_ratio=345.0, nominal_voltage=7.4, supply_range=(4.0, 7.4),
    stall_torque=19.5 * KG_CM, stall_current=2.0, no_load_speed_rpm=52.0, no_load_current=0.15,
    ratings=((6.0, 19.5 * KG_CM * 6.0 / 7.4, 2.0 * 6.0 / 7.4, 42.0),), temperature_limit=70.0,
    motor_kt=BAM_KT, motor_ke=BAM_KT, motor_resistance=BAM_R, armature=BAM_ARMATURE,
    friction_coulomb=BAM_KC, friction_viscous=BAM_KV,
    source="Stall 19.5 kg cm: at 6 V per Feetech's spec (ftservo-wiki official-specs.json, 2.0 A, 42 rpm, 1/345), "
           "at 7.4 V per DFRobot's SER0069 listing (52 rpm no load at 7.4 V, 4-7.4 V), 16.5 kg cm at 6 V per "
           "TheRobotStudio's SO-ARM100 README: taken at 7.4 V and in proportion below (15.8 kg cm at 6 V, between "
           "the two 6 V claims; the validator's envelope errs low). " + _BAM + " (the anchor)")
STS3215_C018 = FeetechSpec(
    name="STS3215-C018", gear_ratio=345.0, nominal_voltage=12.0, supply_range=(9.0, 12.6),
    stall_torque=30.0 * KG_CM, stall_current=2.7, no_load_speed_rpm=45.0, no_load_current=0.18,
    temperature_limit=70.0, motor_kt=30.0 * KG_CM / 2.7, motor_ke=12.0 / (45.0 * RPM), motor_resistance=12.0 / 2.7,
    armature=BAM_ARMATURE, friction_coulomb=BAM_KC, friction_viscous=BAM_KV,
    source="Feetech STS3215-C018 page (ftservo-wiki st-3215-c018): 30 kg cm at 12 V, 9-12.6 V, 1/345; stall 2.7 A, "
           "no load 45 rpm / 0.18 A at 12 V (the 12 V STS3215 data of Gregory119/RBE501-RL-arm-project); kt = "
           "stall torque / current, ke = V / no-load speed, R = V / stall current (DERIVED); armature and friction "
           "BAM's C001 fit (same gearing; an estimate)")
STS3215_C044 = FeetechSpec(
    name="STS3215-C044", gear_ratio=191.0, nominal_voltage=7.4, supply_range=(4.0, 7.4),
    stall_torque=22.0 * KG_CM, stall_current=2.0,
    no_load_speed_rpm=52.0 * 345.0 / 191.0, temperature_limit=70.0, **_geared(191.0),
    source="Feetech representative (roboninecom/SO-ARM100-101-Parallel-Gripper #5): C044 7.4 V 22 kg cm 1/191; "
           "no-load speed and motor model from the C001's scaled by 345/191 (DERIVED, an estimate)")
STS3215_C046 = FeetechSpec(
    name="STS3215-C046", gear_ratio=147.0, nominal_voltage=7.4, supply_range=(4.0, 7.4),
    stall_torque=14.0 * KG_CM, stall_current=2.0, no_load_speed_rpm=52.0 * 345.0 / 147.0,
    temperature_limit=70.0, **_geared(147.0),
    source="Feetech representative (roboninecom/SO-ARM100-101-Parallel-Gripper #5): C046 7.4 V 14 kg cm 1/147; "
           "no-load speed and motor model from the C001's scaled by 345/147 (DERIVED, an estimate)")
STS3250 = FeetechSpec(
    name="STS3250", model_number=2825, gear_ratio=345.0, nominal_voltage=12.0, supply_range=(9.0, 12.6),
    stall_torque=50.0 * KG_CM, stall_current=3.0, no_load_speed_rpm=60.0 / (0.133 * 6.0), no_load_current=0.18,
    temperature_limit=70.0, motor_kt=50.0 * KG_CM / 3.0, motor_ke=12.0 / (60.0 / (0.133 * 6.0) * RPM),
    motor_resistance=12.0 / 3.0, armature=BAM_ARMATURE, friction_coulomb=BAM_KC, friction_viscous=BAM_KV,
    source="Feetech STS3250-C001 page (ftservo-wiki st-3250-c001): 50 kg cm at 12 V, 9-12.6 V, 0.133 s/60 deg "
           "no load at 12 V, 70 degC cut; 1/345 (robonine's comparison); model number 2825 (LeRobot's table). "
           "Stall current 3.0 A and no-load current 0.18 A (the 12 V STS3215-C018's) are ESTIMATES (not published in "
           "the sources read); kt, ke, R DERIVED from these; "
           "armature and friction BAM's STS3215 fit (an estimate, the STS3250 logs identify it)")

SERVOS = {s.name: s for s in (STS3215_C001, STS3215_C018, STS3215_C044, STS3215_C046, STS3250)}
MODELS = {s.model_number: s for s in (STS3215_C001, STS3250)}     # Model_Number(3) -> the servo it names
