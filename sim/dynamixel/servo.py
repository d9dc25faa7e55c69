"""A virtual X-series servo: its control table (memory and access), a device of the bench, the
bus watchdog and Realtime Tick, heat and hardware errors, and the side a plant steps. The
instructions that act on it are instructions.py's (`Instructions`, a part of this class); the
motor, PID and friction laws are drive.py's.

The plant works in SI at the servo's output shaft: it reports the shaft state with
``set_present(position, velocity, current)`` and asks ``output_current(position, velocity, dt)``
for the current to hold over its next step, then ``output_torque(current, velocity)``.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable

from servodyn.hal.dynamixel import MAX_ID, pack_field
from servodyn.hal.dynamixel.control_table import (HARDWARE_FAULTS, BAUD_RATES, DRIVE_MODE_REVERSE, RETURN_DELAY_UNIT,
                                                  TABLE_SIZE, TICKS_PER_REV, VELOCITY_UNIT, WATCHDOG_UNIT, XM430_W350,
                                                  Item, DynamixelSpec, OperatingMode)

from servodyn.hal.thermal import winding_step

from .drive import Mechanics, Motor, PositionPid, VelocityPi, clamp
from .instructions import WATCHDOG_TRIPPED, Instructions

OVERHEATING = HARDWARE_FAULTS["overheating"]
# plain ints: an enum's cost less
_POSITION, _CURRENT, _PWM = int(OperatingMode.POSITION), int(OperatingMode.CURRENT), int(OperatingMode.PWM)
_VELOCITY, _CURRENT_POSITION_MODE = int(OperatingMode.VELOCITY), int(OperatingMode.CURRENT_POSITION)
_FROM_SHAFT = frozenset({"present_position", "present_velocity", "present_current", "present_load",
                         "moving"})   # set_present
# a little-endian field of each (size, signed), read and written in place in the table
_FIELD = {(size, signed): struct.Struct("<" + (code.lower() if signed else code))
          for size, code in ((1, "B"), (2, "H"), (4, "I")) for signed in (False, True)}
_I8, _U16, _I16, _U32, _I32 = (_FIELD[k] for k in ((1, True), (2, False), (2, True), (4, False), (4, True)))

class Servo(Instructions):
    """One simulated servo. ``zero_ticks`` is the encoder reading at the plant's zero angle (2048,
    half a turn, so that a joint at zero can move both ways inside Position Control Mode's 0..4095).

    On a bench (sim/lab.py) a servo is a device of its protocol: ``factory_fresh`` makes one as it
    leaves the factory, ``nonvolatile`` and ``restore`` are its EEPROM (addresses below 64) as a
    JSON-able dict, ``power_cycle`` switches it off and on, and ``on_nonvolatile(servo)``, when set,
    is told after every write that reached its EEPROM. ``baud`` is the speed (bit/s) it listens and
    answers at: its Baud Rate register's as it powered up or last answered (a written Baud Rate
    takes effect once the write's status is sent, as on the real servo; `listen`)."""

    wiring = 0      # counts changes of any servo's ID, Baud Rate or EEPROM: a bus's cached view of
                    # who listens at which speed is stale when this moved (DynamixelWire._rewire)

    def __init__(self, model: DynamixelSpec = XM430_W350, servo_id: int = 1, *, position: float = 0.0,
                 zero_ticks: int = TICKS_PER_REV // 2, supply_voltage: float = 12.0,
                 temperature: float = 30.0, mechanics: Mechanics | None = None, baud: int | None = None,
                 firmware: int | None = None):
        if not 0 <= servo_id <= MAX_ID:
            raise ValueError(f"servo ID {servo_id}: 0..{MAX_ID}")
        if supply_voltage <= 0:
            raise ValueError(f"supply voltage {supply_voltage} V: must be positive")
        self.model = model
        self.mechanics = mechanics or Mechanics.of(model)
        self.motor = Motor.of(model)
        self.zero_ticks = zero_ticks
        self.items = {item.name: item for item in model.items()}
        # name -> (unpack_from, pack_into, address, clamp bound): get() and _set() are the
        # simulator's hottest path, so each item's field is packed in place by a prebuilt Struct
        self._field = {item.name: (codec.unpack_from, codec.pack_into, item.address, 1 << (8 * item.size - 1))
                       for item in self.items.values() for codec in [_FIELD[item.size, item.signed]]}
        # the addresses the per-packet and per-step paths read directly (one-byte items, or a Struct)
        self._at = {name: self.items[name].address for name in
                    ("id", "drive_mode", "torque_enable", "status_return_level", "hardware_error_status",
                     "return_delay_time", "operating_mode", "bus_watchdog", "realtime_tick", "goal_pwm", "baud_rate",
                     "pwm_limit", "goal_current", "current_limit", "present_input_voltage", "homing_offset",
                     "moving_threshold", "moving")
                    if name in self.items}       # a model without current control has no current items
        # Present Current, or Present Load on a model without current control (its unit in current_unit)
        self._present = tuple(self._field[name] for name in ("present_position", "present_velocity",
                                                              "present_current" if model.current_control
                                                              else "present_load"))
        self._owner: list[Item | None] = [None] * TABLE_SIZE      # the item holding each byte
        self._layouts: dict[tuple[int, int], tuple] = {}           # (address, length) -> items written
        for item in self.items.values():
            self._owner[item.address:item.address + item.size] = [item] * item.size
        self._table = bytearray(TABLE_SIZE)
        self._shaft = (position, 0.0, 0.0)      # rad, rad/s, A
        self._stale = False            # the shaft moved since the Present registers were written
        self._pid = PositionPid(model.p_gain_divisor)
        self._velocity_pi = VelocityPi()
        self._turns = 0                # whole turns hidden from Present Position
        self._registered: tuple[int, bytes] | None = None
        self._heard_at: float | None = None
        self.clocked_at: float | None = None     # the time of the last clock()
        self.silent = False            # a fault: the servo executes but never answers
        self.on_nonvolatile: Callable[[Servo], None] | None = None   # told after an EEPROM write
        self._load_defaults(eeprom=True)
        self._set("id", servo_id)
        if baud is not None:         # set up at this rate (its EEPROM); a new servo says 57600
            if baud not in BAUD_RATES:
                raise ValueError(f"baud rate {baud}: a Dynamixel X servo runs at {', '.join(map(str, BAUD_RATES))}")
            self._set("baud_rate", BAUD_RATES.index(baud))
        if firmware is not None:
            self._set("firmware_version", self._checked("firmware_version", firmware))
        self.baud = BAUD_RATES[self.get("baud_rate")]
        self._set("present_input_voltage", round(supply_voltage * 10))
        # the winding: the validator's model (hal/thermal.py), stepped by heat(); Present
        # Temperature reports it in whole degrees
        self.thermal = (model.thermal_resistance, model.thermal_time_constant)    # K/W, s
        self.temperature = float(temperature)
        self._set("present_temperature", max(0, min(255, round(temperature))))
        self._power_up()

    # --- a device of the bench (sim/lab.py) -----------------------------------------------------

    @classmethod
    def factory_fresh(cls, model: DynamixelSpec = XM430_W350, **hardware) -> "Servo":
        """A servo as it leaves the factory: every EEPROM item at its control-table default (ID,
        Baud Rate, Return Delay Time, Operating Mode, ...). `hardware`: the constructor's
        keywords for what is not its memory (position, zero_ticks, supply_voltage, firmware, ...)."""
        return cls(model, next(item.default for item in model.items() if item.name == "id"), **hardware)

    def nonvolatile(self) -> dict[str, int]:
        """The EEPROM, item by item (name -> value): what a power cycle keeps."""
        return {name: self.get(name) for name, item in self.items.items() if item.eeprom}

    def restore(self, state: dict) -> None:
        """Put `state` (nonvolatile()'s, or any part of it) in the EEPROM, then power up with it
        (RAM at its defaults, torque off). ValueError, before anything changes, for an item that
        is not in the EEPROM, a value out of its range, or another model's memory."""
        values = {}
        for name, value in state.items():
            item = self.items.get(name)
            if item is None or not item.eeprom:
                raise ValueError(f"{self.model.name}: {name!r} is not an item of its EEPROM")
            values[name] = self._checked(name, value)
        if values.get("model_number", self.model.model_number) != self.model.model_number:
            raise ValueError(f"a memory of model number {values['model_number']} does not fit a {self.model.name} "
                             f"(model number {self.model.model_number})")
        for name, value in values.items():
            self._set(name, value)
        self.power_cycle()

    def power_cycle(self) -> None:
        """Off and on: RAM back to its defaults (torque off, hardware errors cleared), the EEPROM
        kept, listening at its Baud Rate register's speed. A fault (`silent`) stays: it is the
        bench's, not the servo's memory."""
        self._power_up()
        self.listen()
        Servo.wiring += 1

    def listen(self) -> int:
        """Listen (and answer) at the Baud Rate register's speed from now on; that speed."""
        self.baud = BAUD_RATES[self._table[self._at["baud_rate"]]]
        return self.baud

    def _checked(self, name: str, value) -> int:
        """`value` for item `name` as the bench sets it (any item, read-only ones too): an int in the
        item's range and field, or ValueError."""
        item = self.items[name]
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{self.model.name} {name}: {value!r} is not an integer")
        bits = 8 * item.size
        low, high = (-(1 << bits - 1), (1 << bits - 1) - 1) if item.signed else (0, (1 << bits) - 1)
        if (not low <= value <= high or (item.low is not None and not item.low <= value <= item.high)
                or (item.choices is not None and value not in item.choices)
                or (item.mask is not None and value & ~item.mask)):
            raise ValueError(f"{self.model.name} {name}: {value} is out of its range")
        return value

    def _nonvolatile_written(self) -> None:
        """A write reached the EEPROM (ID, Baud Rate, ...): buses see it, the bench is told."""
        Servo.wiring += 1
        if self.on_nonvolatile is not None:
            self.on_nonvolatile(self)

    # --- table access --------------------------------------------------------------------------

    def get(self, name: str) -> int:
        if self._stale and name in _FROM_SHAFT:
            self._refresh_present()
        unpack, _, address, _ = self._field[name]
        return unpack(self._table, address)[0]

    def _set(self, name: str, value: int) -> None:
        _, pack, address, _ = self._field[name]
        try:
            pack(self._table, address, value)
        except struct.error:             # not an int, or out of range: as pack_field has it
            item = self.items[name]
            self._table[address:address + item.size] = pack_field(value, item.size, item.signed)

    def _set_clamped(self, name: str, value: float) -> None:
        _, pack, address, bound = self._field[name]
        pack(self._table, address, clamp(round(value), -bound, bound - 1))

    @property
    def id(self) -> int:
        return self._table[self._at["id"]]

    @property
    def torque_enabled(self) -> bool:
        return self._table[self._at["torque_enable"]] == 1

    @property
    def alert(self) -> bool:
        return self._table[self._at["hardware_error_status"]] != 0

    @property
    def status_return_level(self) -> int:
        return self._table[self._at["status_return_level"]]

    @property
    def return_delay(self) -> float:
        """Return Delay Time in seconds (metadata: the bus does not wait)."""
        return self._table[self._at["return_delay_time"]] * RETURN_DELAY_UNIT

    def _load_defaults(self, eeprom: bool, writable_only: bool = False) -> None:
        for item in self.items.values():
            if item.default is not None and item.eeprom == eeprom and (item.writable or not writable_only):
                self._set(item.name, item.default)

    def _power_up(self) -> None:
        self._load_defaults(eeprom=False)
        self._set("goal_pwm", self.get("pwm_limit"))
        self._goal_current_to_limit()
        self._registered = None
        self._heard_at = None
        self._reset_loops()
        self._reset_turns()
        self._refresh_present()
        self._set("goal_position", self.get("present_position"))
        self._set("position_trajectory", self.get("present_position"))

    # --- time: bus watchdog and realtime tick --------------------------------------------------

    def heard(self, now: float) -> None:
        """An instruction packet for this servo arrived at ``now`` (s)."""
        self._heard_at = now
        if now != self.clocked_at:      # clocked at `now` already: silent 0 now, so nothing would change
            self.clock(now)

    def clock(self, now: float) -> None:
        """Advance the servo's clock: Realtime Tick, and the bus watchdog while torque is on."""
        table, at = self._table, self._at
        self.clocked_at = now
        _U16.pack_into(table, at["realtime_tick"], int(now * 1000) % 32768)
        period = _I8.unpack_from(table, at["bus_watchdog"])[0] * WATCHDOG_UNIT
        silent = now - self._heard_at if self._heard_at is not None else 0.0
        if period > 0 and table[at["torque_enable"]] == 1 and silent > period:
            self._trip_watchdog()

    def _trip_watchdog(self) -> None:
        """Stop: a current-mode servo drops its goal current, a PWM-mode one its goal PWM, a
        velocity-mode one its goal velocity; a position servo holds where it is."""
        self._set("bus_watchdog", WATCHDOG_TRIPPED)
        mode = self.get("operating_mode")
        if mode in (OperatingMode.CURRENT, OperatingMode.PWM, OperatingMode.VELOCITY):
            self._set({OperatingMode.CURRENT: "goal_current", OperatingMode.PWM: "goal_pwm",
                       OperatingMode.VELOCITY: "goal_velocity"}[mode], 0)
        else:
            self._set("goal_position", self.get("present_position"))
            self._set("position_trajectory", self.get("present_position"))

    # --- heat ------------------------------------------------------------------------------------------

    def heat(self, current_squared: float, dt: float) -> None:
        """The winding `dt` seconds on at a mean I² (A²); over Temperature Limit(31) the servo
        raises Overheating (Hardware Error Status bit 2), which its Shutdown cuts the torque for."""
        r_th, tau_th = self.thermal
        if r_th <= 0 or tau_th <= 0:
            return
        self.temperature = winding_step(self.temperature, current_squared, dt, self.model.winding_resistance,
                                        r_th, tau_th)
        degrees = max(0, min(255, round(self.temperature)))
        if degrees != self._table[self.items["present_temperature"].address]:
            self._set("present_temperature", degrees)
            if degrees > self.get("temperature_limit") and not self.get("hardware_error_status") & OVERHEATING:
                self.set_hardware_error(OVERHEATING)

    # --- hardware errors ---------------------------------------------------------------------------

    def set_hardware_error(self, bits: int) -> None:
        """Raise hardware error bits (HardwareError); those selected by Shutdown(63) cut the torque."""
        self._set("hardware_error_status", self.get("hardware_error_status") | bits)
        if bits & self.get("shutdown"):
            self._set("torque_enable", 0)
            self._reset_loops()

    # --- the plant's side ------------------------------------------------------------------------

    @property
    def _sign(self) -> int:
        return -1 if self._table[self._at["drive_mode"]] & DRIVE_MODE_REVERSE else 1

    def _encoder(self, position: float) -> float:
        return self.zero_ticks + self._sign * position * TICKS_PER_REV / (2 * math.pi)

    def _position_ticks(self, position: float) -> float:
        """Present Position for a shaft angle: encoder, less hidden turns, plus Homing Offset."""
        return (self._encoder(position) - TICKS_PER_REV * self._turns
                + _I32.unpack_from(self._table, self._at["homing_offset"])[0])

    def _reset_turns(self) -> None:
        self._turns = math.floor(round(self._encoder(self._shaft[0])) / TICKS_PER_REV)

    def set_present(self, position: float, velocity: float, current: float) -> None:
        """The plant's shaft state: rad, rad/s, A (reverse mode flips all three in the table)."""
        self._shaft = (position, velocity, current)
        self._stale = True         # written when next read: the plant steps more often than the host reads

    def _refresh_present(self) -> None:
        """Present Position, Velocity, Current and Moving from the shaft, each clamped to its field
        (the simulator's hottest path: written out, without _set_clamped's lookups)."""
        self._stale = False
        position, velocity, current = self._shaft
        table, at = self._table, self._at
        sign = -1 if table[at["drive_mode"]] & DRIVE_MODE_REVERSE else 1
        (_, pack_p, at_p, bound_p), (_, pack_v, at_v, bound_v), (_, pack_c, at_c, bound_c) = self._present
        ticks = (self.zero_ticks + sign * position * TICKS_PER_REV / (2 * math.pi)      # _position_ticks
                 - TICKS_PER_REV * self._turns + _I32.unpack_from(table, at["homing_offset"])[0])
        pack_p(table, at_p, clamp(round(ticks), -bound_p, bound_p - 1))
        speed = clamp(round(sign * velocity / VELOCITY_UNIT), -bound_v, bound_v - 1)
        pack_v(table, at_v, speed)
        pack_c(table, at_c, clamp(round(sign * current / self.model.current_unit), -bound_c, bound_c - 1))
        table[at["moving"]] = int(abs(speed) > _U32.unpack_from(table, at["moving_threshold"])[0])

    def output_current(self, position: float, velocity: float, dt: float) -> float:
        """Motor current (A, shaft sign) the drive applies for the next ``dt`` seconds: the operating
        mode's demand from the registers, turned into current and PWM by the motor (drive.py)."""
        table, at = self._table, self._at
        if table[at["torque_enable"]] != 1:
            self._reset_loops()
            self._set("present_pwm", 0)
            return 0.0
        u16, i16 = _U16.unpack_from, _I16.unpack_from
        sign = -1 if table[at["drive_mode"]] & DRIVE_MODE_REVERSE else 1
        speed = sign * velocity                               # in the motor's own sign
        supply = u16(table, at["present_input_voltage"])[0] / 10
        goal_pwm, pwm_limit = abs(i16(table, at["goal_pwm"])[0]), u16(table, at["pwm_limit"])[0]
        pwm_cap = pwm_limit if pwm_limit < goal_pwm else goal_pwm         # min(goal_pwm, pwm_limit)
        mode = table[at["operating_mode"]]
        if mode == _CURRENT or mode == _CURRENT_POSITION_MODE:
            pwm = None
        elif mode == _PWM:                                    # Goal PWM straight to the bridge
            pwm = clamp(i16(table, at["goal_pwm"])[0], -pwm_limit, pwm_limit)
        elif mode == _VELOCITY:                               # velocity PI → PWM
            error = _I32.unpack_from(table, self.items["goal_velocity"].address)[0] - speed / VELOCITY_UNIT
            gains = (self.get("velocity_p_gain"), self.get("velocity_i_gain"))
            pwm = self._velocity_pi.step(error, dt, gains, pwm_limit)
        else:                                                 # (extended) position PID → PWM
            pwm = self._pid_output(position, velocity, dt, pwm_cap)
        if pwm is not None:
            amps = self.motor.pwm_driven(pwm, supply, speed)
        else:
            if mode == _CURRENT:
                limit = u16(table, at["current_limit"])[0]
                units = clamp(i16(table, at["goal_current"])[0], -limit, limit)
            else:                                             # position PID → current, Goal Current caps it
                units = self._pid_output(position, velocity, dt, abs(i16(table, at["goal_current"])[0]))
            amps, pwm = self.motor.current_driven(units, pwm_cap, supply, speed)
        self._set_clamped("present_pwm", pwm)
        return sign * amps

    def _reset_loops(self) -> None:
        """The position PID's and velocity PI's integrals back to 0 (torque or mode changed)."""
        self._pid.reset()
        self._velocity_pi.reset()

    def _pid_output(self, position: float, velocity: float, dt: float, cap: float) -> float:
        error = self.get("goal_position") - self._position_ticks(position)
        ticks_per_second = self._sign * velocity * TICKS_PER_REV / (2 * math.pi)
        gains = (self.get("position_p_gain"), self.get("position_i_gain"), self.get("position_d_gain"))
        return self._pid.step(error, ticks_per_second, dt, gains, cap)

    def output_torque(self, current: float, velocity: float) -> float:
        """Torque at the output shaft (N·m) for a motor current and shaft speed."""
        return self.mechanics.torque(current, velocity)
