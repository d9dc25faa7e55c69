"""A simulated MIT-style CAN motor: its firmware's side of the frames (hal.can's codec and
dialect tables) and its physics as a plant Drive.

Control law, every plant step: τ = kp (p − θ) + t_ff + kd (v − ω) from the last command decoded,
limited to ±min(TMAX, peak torque) and, driving, by back-EMF to τ_peak·(1 − |ω|/ω₀(V)) — zero at
the no-load speed at the supply voltage. The law runs at the plant's step (1 ms), coarser than a
real driver's 10–40 kHz loop: with the host closing the PD (kp = kd = 0) the feed-forward it
applies is the same. Current I = τ/Kt heats the winding by the validator's model (hal/thermal.py:
C·dT/dt = I²R(1 + α(T − 25 °C)) − (T − T_amb)/R_th); over the motor's temperature limit it faults (Damiao status C, CubeMars error 1) and goes limp. A motor
that gets no command for its CAN timeout goes limp (Damiao status D). Friction: viscous plus a
smoothed Coulomb term at the output.

Its memory, as a Damiao motor's (hal/can/dialects.py has the sources): register writes (0x55)
change RAM; 0xAA stores every register to flash, only while the motor is disabled (the vendor's
tools disable first; a save while enabled is modelled as ignored without an answer, which no
document confirms), and is echoed; the zero (FE, "SaveZero" in the vendor's debugging tool,
Seeed's Damiao wiki) is kept by the motor itself. A power cycle loses RAM: the motor comes back
disabled, without a latched fault, with its flash's registers. `factory_fresh` is a motor as it
leaves the factory (CAN ID 1, Master ID 0); `nonvolatile`/`restore` carry what survives a power
cycle (JSON-able), for a bench that keeps its devices between runs.
"""

from __future__ import annotations

import math

from servodyn.hal.can import dialects, frames
from servodyn.hal.can.dialects import DIALECTS
from servodyn.hal.can.motors import MotorSpec
from servodyn.hal.thermal import AMBIENT, winding_step

MIT_FIRMWARE_TIMEOUT = 0.025   # s: the mini-cheetah firmware's CAN_TIMEOUT default
FRICTION_VELOCITY = 0.2       # rad/s
COOL_MARGIN = 10.0             # K below the limit before an over-temperature fault clears


class CanMotor:
    """One motor on a CAN bus; position and velocity at its output shaft (the plant's horn)."""

    @property
    def torque_enabled(self) -> bool:
        """Whether the motor drives (MIT mode entered), as a servo's Torque Enable."""
        return self.enabled

    def __init__(self, spec: MotorSpec, can_id: int, *, dialect: str | None = None, feedback_id: int | None = None,
                 ranges: frames.Ranges | None = None, supply_voltage: float | None = None):
        """A motor set up as a configuration says (its ids, ranges and MIT mode already in flash)."""
        self.spec = spec
        self.dialect = DIALECTS[dialect or spec.dialect]
        # RAM: the registers (ESC_ID is `can_id`, MST_ID `feedback_id`; PMAX/VMAX/TMAX are `ranges`)
        self.registers = {dialects.REG_CTRL_MODE: dialects.MIT_MODE, dialects.REG_OT: spec.temperature_limit,
                          dialects.REG_TIMEOUT: 0, dialects.REG_GR: spec.gear_ratio}
        self.can_id = can_id
        self.feedback_id = self.dialect.feedback_id(can_id) if feedback_id is None else feedback_id
        self.ranges = ranges or spec.ranges
        self.voltage = supply_voltage or spec.nominal_voltage
        self.peak_torque = spec.stall_torque_at(self.voltage)       # N m at stall, this supply
        self.no_load_speed = spec.no_load_speed_at(self.voltage)    # rad/s, this supply
        self.position = self.velocity = self.current = 0.0
        self.zero = 0.0                      # output angle the motor calls 0 (set by SET_ZERO)
        self.enabled = False
        self.fault = 0                       # Damiao status / CubeMars error code latched, 0: none
        self.command = frames.Command(0.0, 0.0, 0.0, 0.0, 0.0)
        self.last_command = None             # plant time of the last command frame
        self.time = 0.0
        self.temperature = AMBIENT           # coil, °C
        self.silent = False
        self.commands = 0                    # command frames acted on
        peak = spec.stall_torque
        # friction at the output (estimates: no vendor figures), a Coulomb step smoothed over
        # FRICTION_VELOCITY so the plant's explicit 1 ms step stays stable on the light wrist links
        self.viscous, self.coulomb = 0.001 * peak, 0.005 * peak   # N m s/rad, N m
        # the motor as it really is (a simulated plant that is not its data sheet, sim/robot.py):
        # the torque its current gives (its replies still convert with the data sheet's) and its
        # winding's thermal resistance and time constant
        self.torque_constant = spec.torque_constant          # N m / A at the output
        self.thermal = (spec.thermal_resistance, spec.thermal_time_constant)
        self.flash = self._ram()             # the registers a power cycle comes back with
        self.on_nonvolatile = None           # a bench's: told after the flash or the zero changed
        self.saves = 0                       # flash writes (0xAA acted on)

    @property
    def can_id(self) -> int:
        """CAN ID (ESC_ID, register 8): the id it takes commands on."""
        return self.registers[dialects.REG_ESC_ID]

    @can_id.setter
    def can_id(self, value: int) -> None:
        self.registers[dialects.REG_ESC_ID] = value

    @property
    def feedback_id(self) -> int:
        """Master ID (MST_ID, register 7): the id of every frame it sends."""
        return self.registers[dialects.REG_MST_ID]

    @feedback_id.setter
    def feedback_id(self, value: int) -> None:
        self.registers[dialects.REG_MST_ID] = value

    # ---------------------------------------------------------------- memory (the device protocol)
    @classmethod
    def factory_fresh(cls, spec: MotorSpec, *, can_id: int = dialects.FACTORY_CAN_ID, dialect: str | None = None,
                      ctrl_mode: int = dialects.MIT_MODE, supply_voltage: float | None = None) -> "CanMotor":
        """A motor as it leaves the factory: CAN ID 1, Master ID 0 (a Damiao motor; other dialects
        answer on their own fixed id), the data sheet's MIT ranges, no CAN timeout. ctrl_mode: the
        mode it was shipped in (MIT by default; no vendor document states it, so test others)."""
        dialect = dialect or spec.dialect
        fresh = cls(spec, can_id, dialect=dialect, ranges=spec.ranges, supply_voltage=supply_voltage,
                    feedback_id=dialects.FACTORY_MASTER_ID if DIALECTS[dialect].registers else None)
        fresh.registers[dialects.REG_CTRL_MODE] = ctrl_mode
        fresh.flash = fresh._ram()
        return fresh

    def _saved(self) -> None:
        if self.on_nonvolatile is not None:
            self.on_nonvolatile(self)

    def nonvolatile(self) -> dict:
        """What survives a power cycle, JSON-able: the registers in flash (by number) and the zero."""
        return {"registers": {str(rid): value for rid, value in sorted(self.flash.items())}, "zero": self.zero}

    def restore(self, state: dict) -> None:
        """Flash and zero from `nonvolatile()`'s dict; the motor then powers up with them."""
        self.flash = {int(rid): value for rid, value in state["registers"].items()}
        self.zero = float(state["zero"])
        self.power_cycle()

    def power_cycle(self) -> None:
        """Power off and on: RAM from flash, disabled, no latched fault, no command; the zero and
        the flash are kept (and the plant's position, which is the shaft's)."""
        self._load(self.flash)
        self.enabled = False
        self.fault = 0
        self.command = frames.Command(0.0, 0.0, 0.0, 0.0, 0.0)
        self.last_command = None

    _RANGES = dialects.RANGE_REGISTERS

    def _ram(self) -> dict:
        return {**self.registers, **{rid: getattr(self.ranges, name) for rid, name in self._RANGES.items()}}

    def _load(self, registers: dict) -> None:
        self.registers = {rid: value for rid, value in registers.items() if rid not in self._RANGES}
        self.ranges = frames.Ranges(**{**self.ranges.__dict__,
                                       **{name: registers[rid] for rid, name in self._RANGES.items() if rid in registers}})

    # ---------------------------------------------------------------- physics (plant Drive)
    @property
    def timeout(self) -> float:
        if self.dialect.registers:
            return self.registers[dialects.REG_TIMEOUT] * dialects.TIMEOUT_UNIT
        return MIT_FIRMWARE_TIMEOUT

    def set_present(self, position: float, velocity: float, current: float) -> None:
        self.position, self.velocity, self.current = position, velocity, current

    def _check_timeout(self) -> None:
        if (self.enabled and self.timeout > 0 and self.last_command is not None
                and self.time - self.last_command > self.timeout + 1e-12 and not self.fault):
            if self.dialect.name == "damiao":
                self.fault = 0xD
            else:
                self.command = frames.Command(0.0, 0.0, 0.0, 0.0, 0.0)   # bgkatz: zeroed, still in motor mode

    def torque_wanted(self, position: float, velocity: float) -> float:
        c = self.command
        return c.kp * (c.p - (position - self.zero)) + c.t + c.kd * (c.v - velocity)

    def output_current(self, position: float, velocity: float, dt: float) -> float:
        self.time += dt
        self._check_timeout()
        tau = 0.0
        if self.enabled and not self.fault:
            peak = min(self.ranges.t_max, self.peak_torque)
            tau = max(-peak, min(peak, self.torque_wanted(position, velocity)))
            if tau * velocity > 0:           # driving: back-EMF leaves less torque as speed rises
                room = self.peak_torque * (1 - abs(velocity) / self.no_load_speed)
                tau = math.copysign(min(abs(tau), max(0.0, room)), tau)
        current = tau / self.spec.torque_constant
        self._heat(current, dt)
        return current

    def _heat(self, current: float, dt: float) -> None:
        """The validator's winding model (hal/thermal.py), a step at the held current."""
        r_th, tau_th = self.thermal
        if r_th <= 0 or tau_th <= 0:
            return
        self.temperature = winding_step(self.temperature, current * current, dt, self.spec.winding_resistance,
                                        r_th, tau_th)
        if self.temperature > self.spec.temperature_limit and not self.fault:
            self.fault = 0xC if self.dialect.name == "damiao" else 1

    def output_torque(self, current: float, velocity: float) -> float:
        friction = self.viscous * velocity + self.coulomb * math.tanh(velocity / FRICTION_VELOCITY)
        return current * self.torque_constant - friction

    # ---------------------------------------------------------------- frames
    def status(self) -> int:
        if self.dialect.name == "damiao":
            return self.fault or (dialects.DAMIAO_ENABLED if self.enabled else dialects.DAMIAO_DISABLED)
        if self.dialect.name == "cubemars":
            return self.fault
        return 0

    def reply(self) -> tuple[int, bytes]:
        torque = self.current * self.spec.torque_constant
        y = frames.Reply(id=self.can_id, p=self.position - self.zero, v=self.velocity, t=torque,
                         status=self.status(), temperature=int(round(min(127, self.temperature - 5))),
                         temperature2=int(round(min(127, self.temperature))))
        return self.feedback_id, self.dialect.pack(self.ranges, y)

    def receive(self, arbitration_id: int, data: bytes) -> tuple[list[tuple[int, bytes]], bool]:
        """A frame off the bus: (the frames this motor answers, whether it was a command). A silent
        motor (a fault) acts on every frame but its answers never reach the host, as one whose
        transmitter failed or whose Master ID was set to another id."""
        answers, command = self._receive(arbitration_id, data)
        return ([] if self.silent else answers), command

    def _receive(self, arbitration_id: int, data: bytes) -> tuple[list[tuple[int, bytes]], bool]:
        if arbitration_id == frames.REGISTER_ID and self.dialect.registers:
            return self._register(data), False
        if arbitration_id != self.can_id or len(data) != 8:
            return [], False
        code = frames.special(data)
        if code:
            # the mini-cheetah firmware packs its reply before it acts on the frame; Damiao's
            # feedback to enable / disable already shows the new state
            answer = self.reply()
            self._special(code)
            return [self.reply() if self.dialect.registers else answer], False
        if self.dialect.registers and self.registers[dialects.REG_CTRL_MODE] != dialects.MIT_MODE:
            return [], False                 # in another mode an MIT frame is ignored, silently
        answer = self.reply()
        if self.enabled and not self.fault:
            self.command = frames.unpack_command(self.ranges, data)
        self.last_command = self.time
        self.commands += 1
        return [answer], True

    def _special(self, code: int) -> None:
        if code == frames.ENTER:
            self.enabled = True
            self.last_command = self.time
        elif code == frames.EXIT:
            self.enabled = False
            self.command = frames.Command(0.0, 0.0, 0.0, 0.0, 0.0)
        elif code == frames.SET_ZERO:
            self.zero = self.position
            self._saved()
        elif code == frames.CLEAR_ERROR:
            if self.fault in (0xC, 1) and self.temperature > self.spec.temperature_limit - COOL_MARGIN:
                return                       # still too hot
            self.fault = 0
            self.enabled = False

    def _register(self, data: bytes) -> list[tuple[int, bytes]]:
        try:
            g = frames.unpack_register(data)
        except frames.FrameError:
            return []
        if g.can_id != self.can_id:
            return []
        if g.cmd == frames.REG_REFRESH:
            return [self.reply()]
        if g.cmd == frames.REG_STORE:
            if self.enabled:
                return []                    # stored only when disabled: ignored, no answer
            self.flash = self._ram()
            self._saved()
            self.saves += 1
            return [(self.feedback_id, frames.pack_register(frames.Register(self.can_id, g.cmd, g.rid)))]
        if g.cmd == frames.REG_WRITE:
            self._write(g.rid, dialects.register_value(g.rid, g))
        if g.cmd in (frames.REG_READ, frames.REG_WRITE):
            # the echo names the CAN ID it was addressed to, on the (new) Master ID: which id a real
            # motor names after a write of ESC_ID is not documented (the host accepts either)
            value = dialects.register_bits(g.rid, self._ram().get(g.rid, 0))
            return [(self.feedback_id, frames.pack_register(frames.Register(g.can_id, g.cmd, g.rid, value)))]
        return []

    def _write(self, rid: int, value) -> None:
        """A register write to RAM; a value out of the register's range is kept out, as a motor would."""
        if rid in self._RANGES:
            if frames.RANGE_MIN <= value <= frames.RANGE_MAX:
                self.ranges = frames.Ranges(**{**self.ranges.__dict__, self._RANGES[rid]: value})
        elif rid in (dialects.REG_ESC_ID, dialects.REG_MST_ID):
            if 0 <= value <= frames.REGISTER_ID:
                self.registers[rid] = value
        elif rid == dialects.REG_CTRL_MODE:
            if value in dialects.CTRL_MODES:
                self.registers[rid] = value
        elif rid != dialects.REG_GR:         # read-only
            self.registers[rid] = value
