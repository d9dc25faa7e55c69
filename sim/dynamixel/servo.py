"""A virtual X-series servo: its control table with the e-manual's access rules, the instructions
that act on one servo, the bus watchdog and hardware errors, and a drive model a plant can step.

The plant works in SI at the servo's output shaft: it reports the shaft state with
``set_present(position, velocity, current)`` and asks ``output_current(position, velocity, dt)``
for the current to hold over its next step, then ``output_torque(current, velocity)``.
Refusals raise ``StatusError`` with the e-manual's error number; the bus adds the alert bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from servodyn.hal.dynamixel import MAX_ID, ErrorNumber, ResetOption, StatusError, pack_field, unpack_field
from servodyn.hal.dynamixel.control_table import (GOAL_POSITION_SPAN, PWM_FULL, RETURN_DELAY_UNIT, TABLE_SIZE,
                                                  TICKS_PER_REV, VELOCITY_UNIT, WATCHDOG_UNIT, XM430_W350, Item,
                                                  Model, OperatingMode)

from .drive import Mechanics, PositionPid

WATCHDOG_TRIPPED = -1
_FROM_SHAFT = frozenset({"present_position", "present_velocity", "present_current", "moving"})   # set_present
GOAL_ITEMS = ("goal_pwm", "goal_current", "goal_velocity", "goal_position")
GAIN_ITEMS = ("velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain",
              "position_p_gain", "feedforward_2nd_gain", "feedforward_1st_gain")


def _fail(number: ErrorNumber) -> StatusError:
    return StatusError(number)


@dataclass
class _Shaft:
    position: float = 0.0      # rad
    velocity: float = 0.0      # rad/s
    current: float = 0.0       # A


class Servo:
    """One simulated servo. ``zero_ticks`` is the encoder reading at the plant's zero angle (2048,
    half a turn, so that a joint at zero can move both ways inside Position Control Mode's 0..4095)."""

    def __init__(self, model: Model = XM430_W350, servo_id: int = 1, *, position: float = 0.0,
                 zero_ticks: int = TICKS_PER_REV // 2, supply_voltage: float = 12.0,
                 temperature: int = 30, mechanics: Mechanics | None = None):
        if not 0 <= servo_id <= MAX_ID:
            raise ValueError(f"servo ID {servo_id}: 0..{MAX_ID}")
        if supply_voltage <= 0:
            raise ValueError(f"supply voltage {supply_voltage} V: must be positive")
        self.model = model
        self.mechanics = mechanics or Mechanics.of(model)
        self.zero_ticks = zero_ticks
        self.items = {item.name: item for item in model.items()}
        # name -> (first byte, end, signed): get() and _set() are the simulator's hottest path
        self._span = {item.name: (item.address, item.address + item.size, item.signed) for item in self.items.values()}
        self._owner: list[Item | None] = [None] * TABLE_SIZE      # the item holding each byte
        for item in self.items.values():
            self._owner[item.address:item.address + item.size] = [item] * item.size
        self._table = bytearray(TABLE_SIZE)
        self._shaft = _Shaft(position)
        self._stale = False            # the shaft moved since the Present registers were written
        self._pid = PositionPid()
        self._turns = 0                # whole turns hidden from Present Position
        self._registered: tuple[int, bytes] | None = None
        self._heard_at: float | None = None
        self.silent = False            # a fault: the servo executes but never answers
        self._load_defaults(eeprom=True)
        self._set("id", servo_id)
        self._set("present_input_voltage", round(supply_voltage * 10))
        self._set("present_temperature", temperature)
        self._power_up()

    # --- table access --------------------------------------------------------------------------

    def get(self, name: str) -> int:
        if self._stale and name in _FROM_SHAFT:
            self._refresh_present()
        start, end, signed = self._span[name]
        return int.from_bytes(self._table[start:end], "little", signed=signed)

    def _set(self, name: str, value: int) -> None:
        item = self.items[name]
        self._table[item.address:item.address + item.size] = pack_field(value, item.size, item.signed)

    def _set_clamped(self, name: str, value: float) -> None:
        bound = 1 << (8 * self.items[name].size - 1)
        self._set(name, max(-bound, min(bound - 1, round(value))))

    @property
    def id(self) -> int:
        return self.get("id")

    @property
    def torque_enabled(self) -> bool:
        return self.get("torque_enable") == 1

    @property
    def alert(self) -> bool:
        return self.get("hardware_error_status") != 0

    @property
    def return_delay(self) -> float:
        """Return Delay Time in seconds (metadata: the bus does not wait)."""
        return self.get("return_delay_time") * RETURN_DELAY_UNIT

    # --- instructions on one servo ---------------------------------------------------------------

    def ping_reply(self) -> bytes:
        return pack_field(self.get("model_number"), 2) + bytes([self.get("firmware_version")])

    def read(self, address: int, length: int) -> bytes:
        """Undefined bytes inside the table read as 0; beyond it is an access error."""
        if address + length > TABLE_SIZE:
            raise _fail(ErrorNumber.ACCESS)
        if self._stale:
            self._refresh_present()
        return bytes(self._table[address:address + length])

    def write(self, address: int, data: bytes) -> None:
        """Write whole items, all or nothing."""
        self._apply(self._check_write(address, data))

    def reg_write(self, address: int, data: bytes) -> None:
        """Check now, apply on ACTION."""
        self._check_write(address, data)
        self._registered = (address, bytes(data))
        self._set("registered_instruction", 1)

    def action(self) -> None:
        if self._registered is None:
            raise _fail(ErrorNumber.INSTRUCTION)
        address, data = self._registered
        self._registered = None
        self._set("registered_instruction", 0)
        self.write(address, data)

    def reboot(self) -> None:
        """RAM back to its defaults: torque off, hardware errors and watchdog cleared."""
        self._power_up()

    def factory_reset(self, option: int) -> None:
        if option not in set(ResetOption):
            raise _fail(ErrorNumber.DATA_RANGE)
        kept = {"id": self.get("id"), "baud_rate": self.get("baud_rate")}
        self._load_defaults(eeprom=True)
        if option != ResetOption.ALL:
            self._set("id", kept["id"])
        if option == ResetOption.EXCEPT_ID_AND_BAUD:
            self._set("baud_rate", kept["baud_rate"])
        self.reboot()

    def clear_multi_turn(self) -> None:
        """Present Position back within one turn; refused while moving."""
        if self.get("moving"):
            raise _fail(ErrorNumber.RESULT_FAIL)
        self._reset_turns()
        self._refresh_present()

    # --- write checks and effects --------------------------------------------------------------

    def _check_write(self, address: int, data: bytes) -> list[tuple[Item, int]]:
        end = address + len(data)
        if not data:
            raise _fail(ErrorNumber.DATA_LENGTH)
        if end > TABLE_SIZE:
            raise _fail(ErrorNumber.ACCESS)
        writes, k = [], address
        while k < end:
            item = self._owner[k]
            if item is None or not item.writable:
                raise _fail(ErrorNumber.ACCESS)
            if item.address != k or k + item.size > end:      # part of an item
                raise _fail(ErrorNumber.DATA_LENGTH)
            writes.append((item, unpack_field(data[k - address:k - address + item.size], item.signed)))
            k += item.size
        if self.torque_enabled and any(item.eeprom for item, _ in writes):
            raise _fail(ErrorNumber.ACCESS)
        for item, value in writes:
            self._check_value(item, value)
        return writes

    def _check_value(self, item: Item, value: int) -> None:
        tripped = self.get("bus_watchdog") == WATCHDOG_TRIPPED
        if tripped and (item.name in GOAL_ITEMS or (item.name == "bus_watchdog" and value != 0)):
            raise _fail(ErrorNumber.DATA_RANGE)          # goals are read-only until written 0
        shut_down = self.get("hardware_error_status") & self.get("shutdown")
        if item.name == "torque_enable" and value == 1 and shut_down:
            raise _fail(ErrorNumber.RESULT_FAIL)         # after a shutdown only REBOOT restores torque
        if item.name == "goal_position":
            self._check_goal_position(value)
        out_of_range = ((item.low is not None and not item.low <= value <= item.high)
                        or (item.choices is not None and value not in item.choices)
                        or (item.mask is not None and value & ~item.mask))
        if out_of_range:
            raise _fail(ErrorNumber.DATA_RANGE)
        if item.limit is not None and abs(value) > self.get(item.limit):
            raise _fail(ErrorNumber.DATA_LIMIT)

    def _check_goal_position(self, value: int) -> None:
        if self.get("operating_mode") == OperatingMode.POSITION:
            if not self.get("min_position_limit") <= value <= self.get("max_position_limit"):
                raise _fail(ErrorNumber.DATA_LIMIT)
        elif abs(value) > GOAL_POSITION_SPAN:
            raise _fail(ErrorNumber.DATA_RANGE)

    def _apply(self, writes: list[tuple[Item, int]]) -> None:
        for item, value in writes:
            before = self.get(item.name)
            self._set(item.name, value)
            if item.name == "operating_mode" and value != before:
                self._enter_mode(value)
            elif item.name == "torque_enable" and value != before:
                self._pid.reset()
                if value and self.get("operating_mode") == OperatingMode.POSITION:
                    self._reset_turns()
            elif item.name == "goal_position":
                self._set("position_trajectory", value)
        self._refresh_present()

    def _enter_mode(self, mode: int) -> None:
        """Switching mode resets the profile, the gains and the goal PWM/current to their limits."""
        for name in ("profile_acceleration", "profile_velocity", *GAIN_ITEMS):
            self._set(name, self.items[name].default)
        self._set("goal_pwm", self.get("pwm_limit"))
        self._set("goal_current", self.get("current_limit"))
        self._pid.reset()
        if mode == OperatingMode.POSITION:
            self._reset_turns()

    def _load_defaults(self, eeprom: bool) -> None:
        for item in self.items.values():
            if item.default is not None and item.eeprom == eeprom:
                self._set(item.name, item.default)

    def _power_up(self) -> None:
        self._load_defaults(eeprom=False)
        self._set("goal_pwm", self.get("pwm_limit"))
        self._set("goal_current", self.get("current_limit"))
        self._registered = None
        self._heard_at = None
        self._pid.reset()
        self._reset_turns()
        self._refresh_present()
        self._set("goal_position", self.get("present_position"))
        self._set("position_trajectory", self.get("present_position"))

    # --- time: bus watchdog and realtime tick --------------------------------------------------

    def heard(self, now: float) -> None:
        """An instruction packet for this servo arrived at ``now`` (s)."""
        self._heard_at = now
        self.clock(now)

    def clock(self, now: float) -> None:
        """Advance the servo's clock: Realtime Tick, and the bus watchdog while torque is on."""
        self._set("realtime_tick", int(now * 1000) % 32768)
        period = self.get("bus_watchdog") * WATCHDOG_UNIT
        silent = now - self._heard_at if self._heard_at is not None else 0.0
        if period > 0 and self.torque_enabled and silent > period:
            self._trip_watchdog()

    def _trip_watchdog(self) -> None:
        """Stop: a current-mode servo drops its goal current, a position servo holds where it is."""
        self._set("bus_watchdog", WATCHDOG_TRIPPED)
        if self.get("operating_mode") == OperatingMode.CURRENT:
            self._set("goal_current", 0)
        else:
            self._set("goal_position", self.get("present_position"))
            self._set("position_trajectory", self.get("present_position"))

    # --- hardware errors ---------------------------------------------------------------------------

    def set_hardware_error(self, bits: int) -> None:
        """Raise hardware error bits (HardwareError); those selected by Shutdown(63) cut the torque."""
        self._set("hardware_error_status", self.get("hardware_error_status") | bits)
        if bits & self.get("shutdown"):
            self._set("torque_enable", 0)
            self._pid.reset()

    # --- the plant's side ------------------------------------------------------------------------

    @property
    def _sign(self) -> int:
        return -1 if self.get("drive_mode") & 0x01 else 1

    def _encoder(self, position: float) -> float:
        return self.zero_ticks + self._sign * position * TICKS_PER_REV / (2 * math.pi)

    def _position_ticks(self, position: float) -> float:
        """Present Position for a shaft angle: encoder, less hidden turns, plus Homing Offset."""
        return self._encoder(position) - TICKS_PER_REV * self._turns + self.get("homing_offset")

    def _reset_turns(self) -> None:
        self._turns = math.floor(round(self._encoder(self._shaft.position)) / TICKS_PER_REV)

    def set_present(self, position: float, velocity: float, current: float) -> None:
        """The plant's shaft state: rad, rad/s, A (reverse mode flips all three in the table)."""
        self._shaft = _Shaft(position, velocity, current)
        self._stale = True         # written when next read: the plant steps more often than the host reads

    def _refresh_present(self) -> None:
        self._stale = False
        shaft, sign = self._shaft, self._sign
        self._set_clamped("present_position", self._position_ticks(shaft.position))
        self._set_clamped("present_velocity", sign * shaft.velocity / VELOCITY_UNIT)
        self._set_clamped("present_current", sign * shaft.current / self.model.current_unit)
        self._set("moving", int(abs(self.get("present_velocity")) > self.get("moving_threshold")))

    def output_current(self, position: float, velocity: float, dt: float) -> float:
        """Motor current (A, shaft sign) the drive applies for the next ``dt`` seconds."""
        if not self.torque_enabled:
            self._pid.reset()
            self._set("present_pwm", 0)
            return 0.0
        model, sign = self.model, self._sign
        back_emf = sign * velocity / model.no_load_speed      # fraction of the supply it cancels
        supply = self.get("present_input_voltage") / 10 / model.nominal_voltage
        pwm_cap = min(abs(self.get("goal_pwm")), self.get("pwm_limit"))
        mode = self.get("operating_mode")
        if mode == OperatingMode.POSITION:                    # position PID → PWM
            pwm = self._pid_output(position, velocity, dt, pwm_cap)
            amps = model.stall_current * (pwm / PWM_FULL * supply - back_emf)
        else:
            if mode == OperatingMode.CURRENT:
                limit = self.get("current_limit")
                units = max(-limit, min(limit, self.get("goal_current")))
            else:                                             # position PID → current, Goal Current caps it
                units = self._pid_output(position, velocity, dt, abs(self.get("goal_current")))
            # the current loop can only reach what the PWM cap and the back-EMF leave
            reach = model.stall_current * pwm_cap / PWM_FULL * supply
            amps = max(-reach - model.stall_current * back_emf,
                       min(reach - model.stall_current * back_emf, units * model.current_unit))
            pwm = (amps / model.stall_current + back_emf) / supply * PWM_FULL
        self._set_clamped("present_pwm", pwm)
        return sign * amps

    def _pid_output(self, position: float, velocity: float, dt: float, cap: float) -> float:
        error = self.get("goal_position") - self._position_ticks(position)
        ticks_per_second = self._sign * velocity * TICKS_PER_REV / (2 * math.pi)
        gains = (self.get("position_p_gain"), self.get("position_i_gain"), self.get("position_d_gain"))
        return self._pid.step(error, ticks_per_second, dt, gains, cap)

    def output_torque(self, current: float, velocity: float) -> float:
        """Torque at the output shaft (N·m) for a motor current and shaft speed."""
        return self.mechanics.torque(current, velocity)
