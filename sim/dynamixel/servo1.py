"""A simulated Dynamixel on Protocol 1.0 (AX-12A; MX-28/64/106 with their 1.0 firmware): its control
table (hal/dynamixel/table1.py), the instructions that act on it, a device of the bench, and the
side a plant steps (sim/plant.py's Drive) on the voltage-level motor the backend inverts
(hal.motor.MotorModel: BAM's identification for MX-64/106, the data sheet's estimate otherwise):

    i = (V·duty − k_e·ω)/R,   τ = k_t·i − friction        (output-referred)

The duty comes from the mode: torque control mode (MX-64/106, Torque Control Mode Enable(70) = 1):
the current loop drives Goal Torque(71) x 4.5 mA as far as ±max duty less the back-EMF allows; else
the position loop: MX duty = 0.158 x P x error (rad) (BAM's gain, D and I not modelled), AX the
compliance law, full output at Compliance Slope units of error past the margin. Each is capped by
Torque Limit(34) (0.1 % of full). Faults as the status error byte says them: input voltage out of
Min/Max Voltage Limit(12, 13), overheating over Temperature Limit(11), overload (set from outside,
as the 2.0 simulator's hardware errors); those Shutdown(18) selects switch the torque off. A goal
position outside the angle limits is an angle limit error (bit 1) and is not taken; a value over an
item's range a range error (bit 3); an unknown instruction an instruction error (bit 6)."""

from __future__ import annotations

import math
from collections.abc import Callable

from servodyn.hal.dynamixel import protocol1
from servodyn.hal.dynamixel.protocol1 import ErrorBit, Instruction
from servodyn.hal.dynamixel.table1 import (BAUD_CODES, CURRENT_UNIT, CURRENT_ZERO, LOAD_FULL, MX_64, TABLE_SIZE,
                                           Dynamixel1Spec, speed_rad)
from servodyn.hal.feetech.protocol import decode_sign_magnitude, encode_sign_magnitude
from servodyn.hal.feetech.table import SIMULATOR_CLOCK_ADDRESS     # past every 1.0 table too (hal/served_clock.py)
from servodyn.hal.thermal import winding_step

from .drive import Mechanics



class Dynamixel1Servo:
    """One simulated 1.0 servo; ``baud`` the speed it listens at (its Baud Rate's as it powered up)."""

    def __init__(self, model: Dynamixel1Spec = MX_64, servo_id: int = 1, *, baud: int | None = None,
                 supply_voltage: float | None = None, temperature: float = 25.0):
        self.model = model
        self.items = {i.name: i for i in model.items()}
        self.supply_voltage = supply_voltage or model.nominal_voltage
        self.flash = {i.name: i.default for i in self.items.values() if i.eeprom}
        self.flash["id"] = servo_id
        if baud is not None:
            self.flash["baud_rate"] = next(code for code, rate in BAUD_CODES.items() if rate == baud)
        motor = model.motor_model
        self.motor = motor
        self.mechanics = Mechanics.of_motor(motor)
        self.thermal = (model.thermal_resistance, model.thermal_time_constant)
        self.temperature = temperature
        self.silent = False
        self.on_nonvolatile: Callable[["Dynamixel1Servo"], None] | None = None
        self.clock_answer = 0
        self._power_up()

    @classmethod
    def factory_fresh(cls, model: Dynamixel1Spec = MX_64, **hardware) -> "Dynamixel1Servo":
        """As it leaves the factory: ID 1 at its default rate (MX 57 600, AX 1 Mbps)."""
        return cls(model, 1, **hardware)

    # --- memory -----------------------------------------------------------------------------------
    def _power_up(self) -> None:
        self.mem = bytearray(TABLE_SIZE)
        for item in self.items.values():
            self._put(item.name, self.flash[item.name] if item.eeprom else item.default)
        self._put("torque_limit", self.get("max_torque"))
        self.error = 0
        self.baud = BAUD_CODES[self.get("baud_rate")]
        self._shaft = (0.0, 0.0, 0.0)
        self._duty = 0.0
        self._registered: tuple[int, bytes] | None = None
        self._check_voltage()

    def _put(self, name: str, value: int) -> None:
        item = self.items[name]
        raw = encode_sign_magnitude(value, item.sign_bit) if item.sign_bit is not None else value
        self.mem[item.address:item.address + item.size] = int(raw).to_bytes(item.size, "little")

    def get(self, name: str) -> int:
        item = self.items[name]
        raw = int.from_bytes(self.mem[item.address:item.address + item.size], "little")
        return decode_sign_magnitude(raw, item.sign_bit) if item.sign_bit is not None else raw

    @property
    def id(self) -> int:
        return self.mem[3]

    def nonvolatile(self) -> dict[str, int]:
        return dict(self.flash)

    def restore(self, state: dict) -> None:
        unknown = [k for k in state if k not in self.flash]
        if unknown:
            raise ValueError(f"{unknown[0]!r} is not in a {self.model.name}'s EEPROM")
        self.flash.update({k: int(v) for k, v in state.items()})
        self._power_up()

    def power_cycle(self) -> None:
        self._power_up()

    @property
    def torque_enabled(self) -> bool:
        return self.mem[24] == 1

    def set_hardware_error(self, bits: int) -> None:
        """Raise error-byte bits (protocol1.ErrorBit); those Shutdown(18) selects cut the torque."""
        self.error |= bits
        if bits & self.get("shutdown"):
            self._put("torque_enable", 0)

    def _check_voltage(self) -> None:
        if not self.get("min_voltage_limit") <= round(self.supply_voltage * 10) <= self.get("max_voltage_limit"):
            self.set_hardware_error(ErrorBit.INPUT_VOLTAGE)

    def heat(self, current_squared: float, dt: float) -> None:
        r_th, tau_th = self.thermal
        if r_th <= 0 or tau_th <= 0:
            return
        self.temperature = winding_step(self.temperature, current_squared, dt, self.motor.resistance, r_th, tau_th)
        if self.temperature > self.get("temperature_limit"):
            self.set_hardware_error(ErrorBit.OVERHEATING)

    # --- instructions -----------------------------------------------------------------------------
    def execute(self, packet: protocol1.Packet) -> bytes | None:
        """Act on one instruction packet addressed to it (or broadcast): the status packet to send
        back, or None (a broadcast; Status Return Level 0, or 1 for anything but READ and PING)."""
        code, params, broadcast = packet.code, packet.params, packet.id == protocol1.BROADCAST_ID
        level = self.get("status_return_level")
        answer = lambda error=0, data=b"": protocol1.status(self.id, self.error | error, data)
        if code == Instruction.PING:
            return answer()
        if code == Instruction.READ and len(params) == 2 and not broadcast:
            return answer(0, self.read(params[0], params[1])) if level >= 1 else None
        if code in (Instruction.WRITE, Instruction.REG_WRITE) and len(params) >= 2:
            old_id = self.id
            if code == Instruction.REG_WRITE:
                self._registered, error, after = (params[0], bytes(params[1:])), 0, None
            else:
                error, after = self.write(params[0], params[1:])
            reply = None if broadcast or level < 2 else protocol1.status(old_id, self.error | error)
            if after is not None:
                after()
            return reply
        if code == Instruction.ACTION and self._registered is not None:
            (address, data), self._registered = self._registered, None
            error, after = self.write(address, data)
            if after is not None:
                after()
            return None if broadcast or level < 2 else answer(error)
        if code == Instruction.FACTORY_RESET:
            reply = None if broadcast else answer()
            self.flash = {i.name: i.default for i in self.items.values() if i.eeprom}
            self._power_up()
            return reply
        return None if broadcast else answer(ErrorBit.INSTRUCTION)

    def read(self, address: int, length: int) -> bytes:
        if address == SIMULATOR_CLOCK_ADDRESS and length == 1 and self.clock_answer:
            return bytes((self.clock_answer,))
        self._present()
        return bytes(self.mem[address:address + length]).ljust(length, b"\0")[:max(0, TABLE_SIZE - address)]

    def write(self, address: int, data: bytes):
        """Write table items; (error bits, a callable to run once the reply is sent or None). A
        value out of its item's range is a range error and is not taken; a goal position outside
        the angle limits an angle limit error."""
        error, old_baud = 0, self.get("baud_rate")
        for item in self.items.values():
            if not (address <= item.address and item.address + item.size <= address + len(data)):
                continue
            if not item.writable:
                continue
            raw = int.from_bytes(data[item.address - address:item.address - address + item.size], "little")
            if raw > item.high:
                error |= ErrorBit.RANGE
                continue
            if item.name == "goal_position" and not self.get("cw_angle_limit") <= raw <= self.get("ccw_angle_limit"):
                error |= ErrorBit.ANGLE_LIMIT
                continue
            self.mem[item.address:item.address + item.size] = raw.to_bytes(item.size, "little")
            if item.eeprom and not self.get("lock"):
                self.flash[item.name] = raw
                if self.on_nonvolatile is not None:
                    self.on_nonvolatile(self)
        if self.get("torque_enable") and self.error & self.get("shutdown"):
            self._put("torque_enable", 0)           # a fault the servo shut down on holds the torque off
        code = self.get("baud_rate")
        if code != old_baud and code in BAUD_CODES and (self.model.mx or code < 250):
            return error, lambda: setattr(self, "baud", BAUD_CODES[code])
        return error, None

    # --- the plant's side -------------------------------------------------------------------------
    def set_present(self, position: float, velocity: float, current: float) -> None:
        self._shaft = (position, velocity, current)

    def _present(self) -> None:
        position, velocity, current = self._shaft
        m = self.model
        ticks = round(position / m.step)
        self._put("present_position", ticks % (m.position_max + 1) if m.mx else max(0, min(m.position_max, ticks)))
        self._put("present_speed", max(-1023, min(1023, round(velocity / speed_rad(m)))))
        self._put("present_load", max(-1023, min(1023, round(self._duty * LOAD_FULL))))
        self._put("present_voltage", round(self.supply_voltage * 10))
        self._put("present_temperature", max(0, min(255, round(self.temperature))))
        self._put("moving", int(abs(velocity) > speed_rad(m)))
        if m.torque_mode:
            self._put("current", max(0, min(4095, CURRENT_ZERO + round(current / CURRENT_UNIT))))

    def _torque_mode(self) -> bool:
        return self.model.torque_mode and self.get("torque_control_mode_enable") == 1

    def output_current(self, position: float, velocity: float, dt: float) -> float:
        if not self.torque_enabled:
            self._duty = 0.0
            return 0.0
        cap = self.motor.max_duty * min(self.get("torque_limit"), LOAD_FULL) / LOAD_FULL
        if self._torque_mode():
            goal = self.get("goal_torque") * CURRENT_UNIT
            limit = self.get("torque_limit") * CURRENT_UNIT           # Goal Torque cannot exceed Torque Limit
            amps, self._duty = self.motor.current_loop(max(-limit, min(limit, goal)), self.supply_voltage, velocity,
                                                       self.temperature, duty_cap=cap)
            return amps
        m = self.model
        error = self.get("goal_position") - position / m.step
        if m.mx:
            duty = m.duty_per_tick(self.get("p_gain")) * error
        else:
            margin = self.get("cw_compliance_margin" if error < 0 else "ccw_compliance_margin")
            slope = self.get("cw_compliance_slope" if error < 0 else "ccw_compliance_slope")
            duty = math.copysign(max(0.0, abs(error) - margin), error) * m.duty_per_tick(slope)
        self._duty = max(-cap, min(cap, duty))
        return self.motor.current(self._duty, self.supply_voltage, velocity, self.temperature)

    def output_torque(self, current: float, velocity: float) -> float:
        return self.mechanics.torque(current, velocity)
