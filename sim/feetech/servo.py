"""A simulated Feetech STS servo: its memory table (hal/feetech/table.py), the instructions that act
on it, the EEPROM lock, a device of the bench, overload protection, and the side a plant steps
(sim/plant.py's Drive) on the voltage-level motor model the backend inverts:

    i = (V·duty − ke·ω)/R,   τ = kt·i − friction        (output-referred, table.FeetechSpec)

The duty comes from the operating mode: 0 position (a P loop on the horn angle: duty = 0.166 x P x
error in rad, BAM's oscilloscope gain for the STS3215; the D term is not modelled), 1 speed (the
speed's back-EMF duty plus a proportional term), 2 PWM (Goal_Time, 0.1 %, sign bit 10), 3 step
(not modelled: no output). Every duty is capped by Torque_Limit(48) (an assumption: whether mode 2
honours it is UNVERIFIED). Overload protection as the memory table describes it: a duty above
Overload_Torque(36) % held for Protection_Time(35) x 10 ms sets the overload bit (Status 65, the
error byte) and caps the output at Protective_Torque(34) % until torque is switched off and on;
Protection_Current(28) x 6.5 mA exceeded for Over_Current_Protection_Time(38) x 10 ms sets the
current bit and, when Unloading_Condition(19) selects it, switches the torque off.

The EEPROM lock (Lock 55, inverted): with Lock = 0 a write to an EEPROM address (< 40) is kept
across a power cycle (and `on_nonvolatile` is told); with Lock = 1 it acts until power-off only.
Its power-on value is 1 here (the newest Feetech table; the fw 3.x translation says 0).

Present_Position wraps within 0..4095 while Phase(18) bit 4 is clear (single-turn feedback, the
STS3215's default): Actual − Homing_Offset modulo a turn, which is why a calibration puts the joint's
range in the middle of the turn (LeRobot: Homing_Offset = position − 2047 at mid-range). RESTART
(0x08) powers it up again from its EEPROM, without a status packet.
"""

from __future__ import annotations

from collections.abc import Callable

from servodyn.hal.feetech import protocol
from servodyn.hal.feetech.protocol import Instruction, StatusBit, decode_sign_magnitude, encode_sign_magnitude
from servodyn.hal.feetech.table import (POSITION_GAIN, BAUD_RATES, CURRENT_UNIT, DUTY_FULL, EEPROM_END, ITEM, ITEMS,
                                        PROTECTION_TIME_UNIT, SIMULATOR_CLOCK_ADDRESS, STEP, STS3215_C001, TABLE_SIZE,
                                        TICKS_PER_REV,
                                        FeetechSpec, Mode)
from servodyn.hal.thermal import winding_step

from ..dynamixel.drive import Mechanics

SPEED_GAIN = 0.01          # duty per (speed_p x rad/s of error): a model, not a measured gain
MULTI_TURN = 0x10          # Phase(18) bit 4: full-range (multi-turn) angle feedback; clear: 0..4095
FAULT_BITS = {"voltage": StatusBit.VOLTAGE, "input voltage": StatusBit.VOLTAGE, "encoder": StatusBit.ENCODER,
              "motor encoder": StatusBit.ENCODER, "temperature": StatusBit.TEMPERATURE,
              "overheating": StatusBit.TEMPERATURE, "current": StatusBit.CURRENT,
              "electrical shock": StatusBit.CURRENT, "overload": StatusBit.OVERLOAD}


class FeetechServo:
    """One simulated STS servo; ``baud`` the speed it listens at (its Baud_Rate's as it powered up
    or last answered: a written rate takes effect once the write's status is sent)."""

    def __init__(self, model: FeetechSpec = STS3215_C001, servo_id: int = 1, *, baud: int | None = None,
                 supply_voltage: float | None = None, temperature: float = 25.0):
        self.model = model
        self.supply_voltage = supply_voltage or model.nominal_voltage
        self.flash = {item.name: item.default for item in ITEMS if item.eeprom}     # kept across power-off
        self.flash["model_number"] = model.model_number
        self.flash["id"] = servo_id
        if baud is not None:
            self.flash["baud_rate"] = BAUD_RATES.index(baud)
        self.motor = model.motor
        self.mechanics = Mechanics.of_motor(self.motor)
        self.thermal = (model.thermal_resistance, model.thermal_time_constant)
        self.temperature = temperature
        self.silent = False
        self.on_nonvolatile: Callable[["FeetechServo"], None] | None = None
        self.clock_answer = 0            # SIMULATOR_CLOCK_ADDRESS's byte (the served clock), 0: none
        self._power_up()

    @classmethod
    def factory_fresh(cls, model: FeetechSpec = STS3215_C001, **hardware) -> "FeetechServo":
        """As it leaves the factory: ID 1 at 1 Mbps, position mode, every EEPROM item at its default."""
        return cls(model, 1, **hardware)

    # --- memory -----------------------------------------------------------------------------------

    def _power_up(self) -> None:
        self.mem = bytearray(TABLE_SIZE)
        for item in ITEMS:
            value = self.flash[item.name] if item.eeprom else item.default
            self._put(item.name, value)
        self._put("torque_limit", self.get("max_torque_limit"))
        self._put("present_voltage", round(self.supply_voltage * 10))
        self._put("present_temperature", round(self.temperature))
        self.baud = BAUD_RATES[self.get("baud_rate")]
        self._shaft = getattr(self, "_shaft", (0.0, 0.0, 0.0))     # the shaft stays where it is
        self._overload_for = self._overcurrent_for = 0.0
        self._protected = False
        self._duty = 0.0
        self._registered: tuple[int, bytes] | None = None

    def _put(self, name: str, value: int) -> None:
        item = ITEM[name]
        raw = encode_sign_magnitude(value, item.sign_bit) if item.sign_bit is not None else value
        self.mem[item.address:item.address + item.size] = int(raw).to_bytes(item.size, "little")

    def get(self, name: str) -> int:
        item = ITEM[name]
        raw = int.from_bytes(self.mem[item.address:item.address + item.size], "little")
        return decode_sign_magnitude(raw, item.sign_bit) if item.sign_bit is not None else raw

    @property
    def id(self) -> int:
        return self.mem[ITEM["id"].address]

    def nonvolatile(self) -> dict[str, int]:
        return dict(self.flash)

    def restore(self, state: dict) -> None:
        unknown = [k for k in state if k not in self.flash]
        if unknown:
            raise ValueError(f"{unknown[0]!r} is not in a Feetech servo's EEPROM")
        self.flash.update({k: int(v) for k, v in state.items()})
        self._power_up()

    def power_cycle(self) -> None:
        """Off and on: SRAM to its defaults (torque off, faults cleared), the EEPROM as last persisted."""
        self._power_up()

    @property
    def torque_enabled(self) -> bool:
        return self.mem[ITEM["torque_enable"].address] == 1

    def set_hardware_error(self, bits: int) -> None:
        """Raise Status bits (protocol.StatusBit); those Unloading_Condition(19) selects cut the torque."""
        self.mem[ITEM["status"].address] |= bits
        if bits & self.get("unloading_condition"):
            self._put("torque_enable", 0)

    def overheat(self) -> None:
        """The winding past Max_Temperature_Limit(13): the temperature bit, as the next heat() would set it."""
        self.temperature = self.get("max_temperature_limit") + 1.0
        self._put("present_temperature", round(self.temperature))
        self.set_hardware_error(StatusBit.TEMPERATURE)

    def heat(self, current_squared: float, dt: float) -> None:
        r_th, tau_th = self.thermal
        if r_th <= 0 or tau_th <= 0:
            return
        self.temperature = winding_step(self.temperature, current_squared, dt, self.motor.resistance,
                                        r_th, tau_th)
        self._put("present_temperature", max(0, min(255, round(self.temperature))))
        if self.temperature > self.get("max_temperature_limit"):
            self.set_hardware_error(StatusBit.TEMPERATURE)

    # --- instructions -----------------------------------------------------------------------------

    def execute(self, packet: protocol.Packet) -> bytes | None:
        """Act on one instruction packet addressed to it (or broadcast); the status packet to send
        back, or None (a broadcast, or Response_Status_Level 0 for anything but READ and PING)."""
        code, params, broadcast = packet.code, packet.params, packet.id == protocol.BROADCAST_ID
        error = self.mem[ITEM["status"].address]
        reply_all = self.get("response_status_level") == 1
        if code == Instruction.PING:
            return protocol.status(self.id, error)
        if code == Instruction.READ and len(params) == 2 and not broadcast:
            return protocol.status(self.id, error, self.read(params[0], params[1]))
        if code in (Instruction.WRITE, Instruction.REG_WRITE) and len(params) >= 2:
            if code == Instruction.WRITE:
                old_id, after = self.id, self.write(params[0], params[1:])
            else:
                old_id, after = self.id, None
                self._registered = (params[0], bytes(params[1:]))
            reply = None if broadcast or not reply_all else protocol.status(old_id, error)
            if after is not None:
                after()                           # a new rate once the status is on its way
            return reply
        if code == Instruction.RESTART:
            self.power_cycle()                    # no status packet: it is starting again
            return None
        if code == Instruction.ACTION and self._registered is not None:
            (address, data), self._registered = self._registered, None
            after = self.write(address, data)
            if after is not None:
                after()
            return None if broadcast or not reply_all else protocol.status(self.id, error)
        return None if broadcast else protocol.status(self.id, error)

    def read(self, address: int, length: int) -> bytes:
        if address == SIMULATOR_CLOCK_ADDRESS and length == 1 and self.clock_answer:
            return bytes((self.clock_answer,))
        self._present()
        return bytes(self.mem[address:address + length]).ljust(length, b"\0")[:max(0, TABLE_SIZE - address)]

    def write(self, address: int, data: bytes):
        """Write table bytes; the read-only ones are left. Returns a callable to run once the reply is
        sent (a new baud rate), or None."""
        old_baud = self.mem[ITEM["baud_rate"].address]
        old_torque = self.torque_enabled
        for k, byte in enumerate(data):
            at = address + k
            item = next((i for i in ITEMS if i.address <= at < i.address + i.size), None)
            if at >= TABLE_SIZE or item is None or not item.writable:
                continue
            self.mem[at] = byte
        persisted = [i for i in ITEMS if i.eeprom and i.writable and address < i.address + i.size
                     and i.address < address + len(data)]
        if persisted and self.get("lock") == 0:
            for item in persisted:
                self.flash[item.name] = self.get(item.name)
            if self.on_nonvolatile is not None:
                self.on_nonvolatile(self)
        if self.torque_enabled and not old_torque:
            self._protected, self._overload_for = False, 0.0
            self.mem[ITEM["status"].address] &= ~StatusBit.OVERLOAD & 0xFF
        if self.mem[ITEM["baud_rate"].address] != old_baud:
            code = self.mem[ITEM["baud_rate"].address]
            if code < len(BAUD_RATES):
                return lambda: setattr(self, "baud", BAUD_RATES[code])
        return None

    # --- the plant's side -------------------------------------------------------------------------

    def set_present(self, position: float, velocity: float, current: float) -> None:
        self._shaft = (position, velocity, current)

    def _present(self) -> None:
        position, velocity, current = self._shaft
        offset = self.get("homing_offset")
        ticks = round(position / STEP) - offset                 # Present = Actual − Homing_Offset
        if not self.get("phase") & MULTI_TURN:
            ticks %= TICKS_PER_REV                              # single-turn feedback: 0..4095, wrapping
        self._put("present_position", max(-32767, min(32767, ticks)))
        self._put("present_velocity", max(-32767, min(32767, round(velocity / STEP))))
        self._put("present_load", max(-1023, min(1023, round(self._duty * DUTY_FULL))))
        self._put("present_current", max(-32767, min(32767, round(current / CURRENT_UNIT))))
        self._put("moving", int(abs(velocity) > 2 * STEP))

    def demand(self, position: float, velocity: float) -> float:
        """The duty (fraction) the operating mode asks for."""
        mode = self.get("operating_mode")
        if mode == Mode.PWM:
            return self.get("goal_time") / DUTY_FULL
        if mode == Mode.POSITION:
            goal = (self.get("goal_position") + self.get("homing_offset")) * STEP
            return POSITION_GAIN * self.get("p_coefficient") * (goal - position)
        if mode == Mode.SPEED:
            goal = self.get("goal_velocity") * STEP
            feed = self.motor.ke * goal / self.supply_voltage
            return feed + SPEED_GAIN * self.get("speed_p") * (goal - velocity)
        return 0.0

    def output_current(self, position: float, velocity: float, dt: float) -> float:
        if not self.torque_enabled:
            self._duty = 0.0
            return 0.0
        cap = self.motor.max_duty * min(self.get("torque_limit"), DUTY_FULL) / DUTY_FULL
        if self._protected:
            cap = min(cap, self.get("protective_torque") / 100)
        duty = max(-cap, min(cap, self.demand(position, velocity)))
        self._duty = duty
        amps = self.motor.current(duty, self.supply_voltage, velocity, self.temperature)
        self._protect(duty, amps, dt)
        return amps if self.torque_enabled else 0.0

    def _protect(self, duty: float, amps: float, dt: float) -> None:
        """Overload and over-current protection, timed on the plant's steps."""
        over = abs(duty) * 100 > self.get("overload_torque")
        self._overload_for = self._overload_for + dt if over else 0.0
        if over and self._overload_for >= self.get("protection_time") * PROTECTION_TIME_UNIT and not self._protected:
            self._protected = True
            self.mem[ITEM["status"].address] |= StatusBit.OVERLOAD
        high = abs(amps) > self.get("protection_current") * CURRENT_UNIT
        self._overcurrent_for = self._overcurrent_for + dt if high else 0.0
        if high and self._overcurrent_for >= self.get("over_current_protection_time") * PROTECTION_TIME_UNIT:
            self.set_hardware_error(StatusBit.CURRENT)

    def output_torque(self, current: float, velocity: float) -> float:
        return self.mechanics.torque(current, velocity)
