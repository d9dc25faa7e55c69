"""The Protocol 1.0 control tables (AX-12A; MX-28, MX-64 and MX-106 with their 1.0 firmware), their
units, and the data sheets of those servos: the one place a 1.0 register, unit or figure is
written (the configuration checks against it, the 1.0 bus and the simulated 1.0 servo take it
from here). Facts: ROBOTIS e-manual pages ax-12a, mx-28, mx-64, mx-106 and the includes under
_includes/en/dxl/ (read for ../shared/notes/servos/protocol1.md §2-§4).

Every 1.0 table shares its layout (addresses below 24 EEPROM, kept across power-off): position at
30/36, speed at 32/38, load 40, voltage 42 (0.1 V), temperature 43. Speed, load and goal torque are
sign-magnitude with the sign in bit 10 (set = CW, the negative sense here). Where they differ:
AX-12A positions span 0..1023 over 300°, its loop is a compliance margin/slope (26-29) and it has no
BULK READ; MX positions span 0..4095 a turn, their loop a PID (D 26, I 27, P 28); MX-64 and MX-106
alone have a current loop: Current(68) = 2048 + I/4.5 mA, Torque Control Mode Enable(70), Goal
Torque(71) in 4.5 mA.

How servodyn drives each (hal.dynamixel.backend1): MX-64/106 by their torque, in torque control
mode (Goal Torque = the current); MX-28 and AX-12A have neither a current loop nor a PWM mode (their
wheel mode is speed control on MX), so their position loop is used as the voltage source it is:
Goal Position = present + duty / duty_per_tick, the duty the motor model gives for the torque.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

from ..motor import MotorModel
from ..servos import RPM, ServoSpec

EEPROM_END = 24               # addresses below are EEPROM
TABLE_SIZE = 74               # up to Goal Acceleration(73)
SIGN_BIT = 10                 # speed, load, goal torque: bit 10 set = CW (negative)
VOLTAGE_UNIT = 0.1            # V per Present Voltage unit
CURRENT_UNIT = 4.5e-3         # A per Current(68) and Goal Torque(71) unit
CURRENT_ZERO = 2048           # Current(68) at no current
GOAL_TORQUE_MAX = 1023
LOAD_FULL = 1023              # Present Load / Torque Limit: 0.1 % a unit
RETURN_DELAY_UNIT = 2e-6      # s per Return Delay Time(5) unit
# Baud Rate(4) value -> bit/s: 2 Mbps / (value + 1) for 1..207; MX adds 250..252 (2.25, 2.5, 3 Mbps)
BAUD_CODES = {1: 1_000_000, 3: 500_000, 4: 400_000, 7: 250_000, 9: 200_000, 16: 115_200, 34: 57_600,
              103: 19_200, 207: 9600, 250: 2_250_000, 251: 2_500_000, 252: 3_000_000}
MX_ONLY_CODES = (250, 251, 252)
BAUD_RATES = tuple(sorted(BAUD_CODES.values()))
# BAM's oscilloscope measurement of the MX position loop (Rhoban/bam, atomic README; ../shared/notes/
# servos/real-logs.md §1.D-F): duty = H x P x error (rad), H = 0.1594 (MX-64) and 0.1575 (MX-106),
# BAM uses 0.158 for both; the bridge tops out at a duty of 0.9625 (measured on an MX-106)
MX_ERROR_GAIN = 0.158
MX_MAX_DUTY = 0.9625


@dataclass(frozen=True)
class Item:
    """One register of a 1.0 table. ``sign_bit``: a sign-magnitude field's sign (None: unsigned);
    ``high``: the largest value a write takes (a larger one is a Range error)."""
    name: str
    address: int
    size: int
    default: int = 0
    writable: bool = True
    sign_bit: int | None = None
    high: int = 0xFFFF

    @property
    def eeprom(self) -> bool:
        return self.address < EEPROM_END


def _ro(name, address, size, default=0, sign_bit=None):
    return Item(name, address, size, default, writable=False, sign_bit=sign_bit)


@dataclass(frozen=True, kw_only=True)
class Dynamixel1Spec(ServoSpec):
    """A servo on Protocol 1.0: its data sheet and its 1.0 control table."""
    kind: str = "dynamixel"
    protocol: float = 1.0
    model_number: int
    position_span: float = 2 * math.pi        # rad Goal/Present Position's range covers
    position_max: int = 4095                  # its top value
    velocity_unit: float = 0.114              # rpm per Present Speed unit
    torque_mode: bool = False                 # Torque Control Mode Enable(70), Goal Torque(71), Current(68)
    bulk_read: bool = True                    # answers a BULK READ (0x92)
    mx: bool = True                           # an MX (PID at 26-28, 4096 a turn); False: an AX
    default_baud_code: int = 34
    motor: MotorModel | None = None           # the identified motor; None: the data sheet's estimate
    motor_source: str = "the data sheet's estimate (hal.motor.MotorModel.from_datasheet)"
    duty_source: str = ""                     # where duty_per_tick's law comes from
    source: str = ""

    @property
    def step(self) -> float:
        """rad at the horn per position unit."""
        return self.position_span / (self.position_max + 1)

    @property
    def ticks_per_rev(self) -> float:
        return 2 * math.pi / self.step

    @property
    def current_unit(self) -> float:
        return CURRENT_UNIT

    @property
    def max_current(self) -> float:
        """Goal Torque's largest magnitude (a torque joint); the stall current otherwise."""
        return GOAL_TORQUE_MAX * CURRENT_UNIT if self.torque_mode else self.stall_current

    @property
    def torque_constant(self) -> float:
        """The identified motor's k_t where there is one (BAM's), else stall torque / stall current."""
        return self.motor.torque_constant if self.motor is not None else self.stall_torque / self.stall_current

    @cached_property
    def motor_model(self) -> MotorModel:
        """The identified motor, else the data sheet's estimate (made once)."""
        if self.motor is not None:
            return self.motor
        return MotorModel.from_datasheet(self).with_(max_duty=MX_MAX_DUTY if self.mx else 1.0)

    def duty_per_tick(self, gain: int) -> float:
        """The position loop's duty per position unit of error: MX, BAM's H x P per rad (gain = P
        Gain(28)); AX, full output over the compliance slope (gain = Compliance Slope(28/29)),
        the e-manual's figure of the compliance law (not measured)."""
        if self.mx:
            return MX_ERROR_GAIN * gain * self.step
        return 1.0 / max(gain, 1)

    def items(self) -> tuple[Item, ...]:
        mx, torque = self.mx, self.torque_mode
        table = [
            _ro("model_number", 0, 2, self.model_number),
            _ro("firmware_version", 2, 1, 36 if mx else 24),
            Item("id", 3, 1, 1, high=253),
            Item("baud_rate", 4, 1, self.default_baud_code, high=254),
            Item("return_delay_time", 5, 1, 250, high=254),
            Item("cw_angle_limit", 6, 2, 0, high=self.position_max),
            Item("ccw_angle_limit", 8, 2, self.position_max, high=self.position_max),
            Item("temperature_limit", 11, 1, round(self.temperature_limit), high=99),
            Item("min_voltage_limit", 12, 1, 60, high=250),
            Item("max_voltage_limit", 13, 1, 240 if mx else 140, high=250),
            Item("max_torque", 14, 2, 1023, high=1023),
            Item("status_return_level", 16, 1, 2, high=2),
            Item("alarm_led", 17, 1, 36, high=127),
            Item("shutdown", 18, 1, 36, high=127),
            Item("torque_enable", 24, 1, 0, high=1),
            Item("led", 25, 1, 0, high=1),
            *([Item("d_gain", 26, 1, 0, high=254), Item("i_gain", 27, 1, 0, high=254),
               Item("p_gain", 28, 1, 32, high=254)] if mx else
              [Item("cw_compliance_margin", 26, 1, 1, high=255), Item("ccw_compliance_margin", 27, 1, 1, high=255),
               Item("cw_compliance_slope", 28, 1, 32, high=254), Item("ccw_compliance_slope", 29, 1, 32, high=254)]),
            Item("goal_position", 30, 2, 0, high=self.position_max),
            Item("moving_speed", 32, 2, 0, high=2047),
            Item("torque_limit", 34, 2, 1023, high=1023),
            _ro("present_position", 36, 2),
            _ro("present_speed", 38, 2, sign_bit=SIGN_BIT),
            _ro("present_load", 40, 2, sign_bit=SIGN_BIT),
            _ro("present_voltage", 42, 1),
            _ro("present_temperature", 43, 1),
            _ro("registered", 44, 1),
            _ro("moving", 46, 1),
            Item("lock", 47, 1, 0, high=1),
            Item("punch", 48, 2, 0 if mx else 32, high=1023),
        ]
        if mx:
            table += [_ro("realtime_tick", 50, 2), Item("goal_acceleration", 73, 1, 0, high=254)]
        if torque:
            table += [_ro("current", 68, 2, CURRENT_ZERO), Item("torque_control_mode_enable", 70, 1, 0, high=1),
                      Item("goal_torque", 71, 2, 0, sign_bit=SIGN_BIT, high=2047)]
        return tuple(table)


def item(spec: Dynamixel1Spec, name: str) -> Item:
    found = next((i for i in spec.items() if i.name == name), None)
    if found is None:
        raise KeyError(f"the {spec.name}'s 1.0 control table has no {name}")
    return found


# The tick's read of each model: Present Position(36) .. Present Temperature(43), and on to
# Current(68) where the model has it (one BULK READ entry per servo: one span)
PRESENT = 36
PRESENT_LENGTH = 8
PRESENT_WITH_CURRENT_LENGTH = 70 - PRESENT


def present_length(spec: Dynamixel1Spec) -> int:
    return PRESENT_WITH_CURRENT_LENGTH if spec.torque_mode else PRESENT_LENGTH


_EMANUAL = "ROBOTIS e-manual, emanual.robotis.com/docs/en/dxl/{}/ (specifications and the Protocol 1.0 control table)"
_MX_SUPPLY = (10.0, 14.8)      # MX pages: 10 ~ 14.8 V, 12 V recommended
_BAM = ("; motor: Rhoban BAM's identification (bam/params/{}/m1.json: kt {kt}, R {R}, armature {a}, Coulomb {c}, "
        "viscous {v}; at the output, BAM's own, identified at 15 V), max duty 0.9625 (BAM, oscilloscope)")


def _bam(kt, r, armature, coulomb, viscous) -> MotorModel:
    return MotorModel(torque_constant=kt, resistance=r, armature=armature, friction_coulomb=coulomb,
                      friction_viscous=viscous, max_duty=MX_MAX_DUTY)


AX_12A = Dynamixel1Spec(
    name="AX-12A", model_number=12, gear_ratio=254.0, stall_torque=1.5, stall_current=1.5, no_load_speed_rpm=59.0,
    nominal_voltage=12.0, supply_range=(9.0, 12.0), temperature_limit=70.0, position_span=math.radians(300.0),
    position_max=1023, velocity_unit=0.111, bulk_read=False, mx=False, default_baud_code=1, current_control=False,
    duty_source="the e-manual's compliance figure: full output at Compliance Slope units of error (not measured)",
    source=_EMANUAL.format("ax/ax-12a") + "; 254:1, 1.5 N m and 1.5 A at 12 V, 59 rpm at 12 V, 9-12 V")
MX_28 = Dynamixel1Spec(
    name="MX-28", model_number=29, gear_ratio=193.0, stall_torque=2.5, stall_current=1.4, no_load_speed_rpm=55.0,
    nominal_voltage=12.0, supply_range=_MX_SUPPLY, current_control=False,
    ratings=((11.1, 2.3, 1.3, 50.0), (14.8, 3.1, 1.7, 67.0)),
    duty_source="BAM's MX position-loop gain H = 0.158 duty per (P x rad), measured on MX-64/106 (assumed for MX-28)",
    source=_EMANUAL.format("mx/mx-28") + "; 193:1; 2.3, 2.5, 3.1 N m at 11.1, 12, 14.8 V (1.3, 1.4, 1.7 A); "
    "50, 55, 67 rpm; 10-14.8 V (the MX series page's table, Protocol 1.0 and 2.0 alike)")
MX_64 = Dynamixel1Spec(
    name="MX-64", model_number=310, gear_ratio=200.0, stall_torque=6.0, stall_current=4.1, no_load_speed_rpm=63.0,
    nominal_voltage=12.0, supply_range=_MX_SUPPLY, torque_mode=True,
    ratings=((11.1, 5.5, 3.9, 58.0), (14.8, 7.3, 5.2, 78.0)),
    motor=_bam(1.6225, 3.949, 0.01195, 0.0904, 0.01169), motor_source="BAM mx64 m1",
    duty_source="BAM's MX position-loop gain H = 0.158 duty per (P x rad) (oscilloscope)",
    source=_EMANUAL.format("mx/mx-64") + "; 200:1; 5.5, 6.0, 7.3 N m at 11.1, 12, 14.8 V (3.9, 4.1, 5.2 A); "
    "58, 63, 78 rpm; 10-14.8 V"
    + _BAM.format("mx64", kt=1.6225, R=3.949, a=0.01195, c=0.0904, v=0.01169))
MX_106 = Dynamixel1Spec(
    name="MX-106", model_number=320, gear_ratio=225.0, stall_torque=8.4, stall_current=5.2, no_load_speed_rpm=45.0,
    nominal_voltage=12.0, supply_range=_MX_SUPPLY, torque_mode=True,
    ratings=((11.1, 8.0, 4.8, 41.0), (14.8, 10.0, 6.3, 55.0)),
    motor=_bam(2.1914, 2.965, 0.02661, 0.1035, 0.03520), motor_source="BAM mx106 m1",
    duty_source="BAM's MX position-loop gain H = 0.158 duty per (P x rad) (oscilloscope)",
    source=_EMANUAL.format("mx/mx-106") + "; 225:1; 8.0, 8.4, 10.0 N m at 11.1, 12, 14.8 V (4.8, 5.2, 6.3 A); "
    "41, 45, 55 rpm; 10-14.8 V"
    + _BAM.format("mx106", kt=2.1914, R=2.965, a=0.02661, c=0.1035, v=0.0352))

SERVOS1 = {s.name: s for s in (AX_12A, MX_28, MX_64, MX_106)}
MODELS1 = {s.model_number: s for s in SERVOS1.values()}


def is_protocol1(servo) -> bool:
    return isinstance(servo, Dynamixel1Spec)


def speed_rad(spec: Dynamixel1Spec) -> float:
    """rad/s at the horn per Present Speed unit."""
    return spec.velocity_unit * RPM
