"""The instructions that act on one simulated servo (`Instructions`, a part of `Servo`): PING's
answer, READ, WRITE with the e-manual's access rules (whole items, all or nothing; EEPROM locked
while torque is on; ranges, masks, limits; goals read-only while the bus watchdog is tripped),
REG_WRITE and ACTION, REBOOT, FACTORY_RESET and CLEAR, and what a write sets off (a mode switch,
torque on or off). Refusals raise ``StatusError`` with the e-manual's error number; the bus
(wire.py) adds the alert bit. The servo's memory, clocks and drive are servo.py's."""

from __future__ import annotations

from servodyn.hal.dynamixel import ErrorNumber, ResetOption, StatusError, pack_field
from servodyn.hal.dynamixel.control_table import EEPROM_END, GOAL_POSITION_SPAN, TABLE_SIZE, Item, OperatingMode

WATCHDOG_TRIPPED = -1
GOAL_ITEMS = ("goal_pwm", "goal_current", "goal_velocity", "goal_position")
_CHANGES = frozenset({"operating_mode", "torque_enable"})    # items whose change, not the write, acts
GAIN_ITEMS = ("velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain",
              "position_p_gain", "feedforward_2nd_gain", "feedforward_1st_gain")


def _fail(number: ErrorNumber) -> StatusError:
    return StatusError(number)


class Instructions:
    """One servo's instructions, on the servo's own memory: a part of ``Servo`` (servo.py), whose
    table access (get, _set, _field, _owner, _table), power-up and turn count it uses."""

    def ping_reply(self) -> bytes:
        return pack_field(self.get("model_number"), 2) + bytes([self.get("firmware_version")])

    def read(self, address: int, length: int) -> bytes:
        """Undefined bytes inside the table read as 0; beyond it is an access error."""
        if address + length > TABLE_SIZE:
            raise _fail(ErrorNumber.ACCESS)
        if self._stale:
            self._refresh_present()
        return bytes(self._table[address:address + length])

    def read_into(self, out: bytearray, offset: int, address: int, length: int) -> None:
        """read(), its bytes copied into `out` at `offset` (a reply being assembled in place)."""
        if address + length > TABLE_SIZE:
            raise _fail(ErrorNumber.ACCESS)
        if self._stale:
            self._refresh_present()
        out[offset:offset + length] = memoryview(self._table)[address:address + length]

    def write(self, address: int, data: bytes) -> None:
        """Write whole items, all or nothing."""
        self._apply(self._check_write(address, data))
        if address < EEPROM_END:
            self._nonvolatile_written()

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
        self._load_defaults(eeprom=True, writable_only=True)     # Model Number, Firmware Version stay
        if option != ResetOption.ALL:
            self._set("id", kept["id"])
        if option == ResetOption.EXCEPT_ID_AND_BAUD:
            self._set("baud_rate", kept["baud_rate"])
        self.reboot()
        self._nonvolatile_written()

    def clear_multi_turn(self) -> None:
        """Present Position back within one turn; refused while moving."""
        if self.get("moving"):
            raise _fail(ErrorNumber.RESULT_FAIL)
        self._reset_turns()
        self._refresh_present()

    # --- write checks and effects --------------------------------------------------------------

    def _layout(self, address: int, length: int) -> tuple | ErrorNumber:
        """The items a write of `length` bytes at `address` covers, each with its unpacker and
        offset in the data, and whether one is in the EEPROM; or the error that refuses it. The
        table's layout decides, so a good one is kept for the next write of the same span."""
        layout = self._layouts.get((address, length))
        if layout is not None:
            return layout
        end = address + length
        if not length:
            return ErrorNumber.DATA_LENGTH
        if end > TABLE_SIZE:
            return ErrorNumber.ACCESS
        items, k = [], address
        while k < end:
            item = self._owner[k]
            if item is None or not item.writable:
                return ErrorNumber.ACCESS
            if item.address != k or k + item.size > end:      # part of an item
                return ErrorNumber.DATA_LENGTH
            items.append((item, self._field[item.name][0], k - address))
            k += item.size
        layout = self._layouts[address, length] = (tuple(items), any(item.eeprom for item, _, _ in items))
        return layout

    def _check_write(self, address: int, data: bytes) -> list[tuple[Item, int]]:
        layout = self._layout(address, len(data))
        if isinstance(layout, ErrorNumber):
            raise _fail(layout)
        items, eeprom = layout
        writes = [(item, unpack(data, offset)[0]) for item, unpack, offset in items]
        if eeprom and self.torque_enabled:
            raise _fail(ErrorNumber.ACCESS)
        for item, value in writes:
            self._check_value(item, value)
        return writes

    def _check_value(self, item: Item, value: int) -> None:
        if ((item.name in GOAL_ITEMS or (item.name == "bus_watchdog" and value != 0))
                and self.get("bus_watchdog") == WATCHDOG_TRIPPED):
            raise _fail(ErrorNumber.DATA_RANGE)          # goals are read-only until written 0
        if (item.name == "torque_enable" and value == 1
                and self.get("hardware_error_status") & self.get("shutdown")):
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
            changes = item.name in _CHANGES
            before = self.get(item.name) if changes else None
            self._set(item.name, value)
            if not changes:
                if item.name == "goal_position":
                    self._set("position_trajectory", value)
            elif item.name == "operating_mode" and value != before:
                self._enter_mode(value)
            elif item.name == "torque_enable" and value != before:
                self._reset_loops()
                if value and self.get("operating_mode") == OperatingMode.POSITION:
                    self._reset_turns()
        self._stale = True         # Present registers as the items now stand, written when next read

    def _enter_mode(self, mode: int) -> None:
        """Switching mode resets the profile, the gains and the goal PWM/current to their limits."""
        for name in ("profile_acceleration", "profile_velocity", *GAIN_ITEMS):
            self._set(name, self.items[name].default)
        self._set("goal_pwm", self.get("pwm_limit"))
        self._goal_current_to_limit()
        self._reset_loops()
        if mode == OperatingMode.POSITION:
            self._reset_turns()

    def _goal_current_to_limit(self) -> None:
        """Goal Current = Current Limit, as a mode switch or power-up leaves it (a model without
        current control has neither)."""
        if self.model.current_control:
            self._set("goal_current", self.get("current_limit"))
