"""A simulated MIT-style CAN motor: its firmware's side of the frames (hal.can's codec and
dialect tables) and its physics as a plant Drive.

Control law, every plant step: τ = kp (p − θ) + t_ff + kd (v − ω) from the last command decoded,
limited to ±min(TMAX, peak torque) and, driving, by back-EMF to τ_peak·(1 − |ω|/ω₀(V)) — zero at
the no-load speed at the supply voltage. The law runs at the plant's step (1 ms), coarser than a
real driver's 10–40 kHz loop: with the host closing the PD (kp = kd = 0) the feed-forward it
applies is the same. Current I = τ/Kt heats the winding, C·dT/dt = I²R − (T − T_amb)/R_th; over
the motor's temperature limit it faults (Damiao status C, CubeMars error 1) and goes limp. A motor
that gets no command for its CAN timeout goes limp (Damiao status D). Friction: viscous plus a
smoothed Coulomb term at the output.
"""

from __future__ import annotations

import math

from servodyn.hal.can import dialects, frames
from servodyn.hal.can.dialects import DIALECTS
from servodyn.hal.can.motors import MotorSpec

AMBIENT = 25.0                 # °C
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
        self.spec, self.can_id = spec, can_id
        self.dialect = DIALECTS[dialect or spec.dialect]
        self.feedback_id = self.dialect.feedback_id(can_id) if feedback_id is None else feedback_id
        self.ranges = ranges or spec.ranges
        self.voltage = supply_voltage or spec.nominal_voltage
        self.peak_torque = spec.stall_torque_at(self.voltage)       # N m at stall, this supply
        self.no_load_speed = spec.no_load_speed_at(self.voltage)    # rad/s, this supply
        self.registers = {dialects.REG_CTRL_MODE: dialects.MIT_MODE, dialects.REG_MST_ID: self.feedback_id,
                          dialects.REG_ESC_ID: can_id, dialects.REG_OT: spec.temperature_limit,
                          dialects.REG_TIMEOUT: 0}
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
        r_th, tau_th = self.spec.thermal_resistance, self.spec.thermal_time_constant
        if r_th <= 0 or tau_th <= 0:
            return
        capacity = tau_th / r_th
        self.temperature += dt * (current ** 2 * self.spec.winding_resistance - (self.temperature - AMBIENT) / r_th) / capacity
        if self.temperature > self.spec.temperature_limit and not self.fault:
            self.fault = 0xC if self.dialect.name == "damiao" else 1

    def output_torque(self, current: float, velocity: float) -> float:
        friction = self.viscous * velocity + self.coulomb * math.tanh(velocity / FRICTION_VELOCITY)
        return current * self.spec.torque_constant - friction

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
        if g.cmd == frames.REG_WRITE:
            value = g.value if g.rid in dialects.UINT_REGISTERS else g.as_float
            self.registers[g.rid] = value
            ranges = {dialects.REG_PMAX: "p_max", dialects.REG_VMAX: "v_max", dialects.REG_TMAX: "t_max"}
            if g.rid in ranges and frames.RANGE_MIN <= value <= frames.RANGE_MAX:   # else kept, as a motor would
                self.ranges = frames.Ranges(**{**self.ranges.__dict__, ranges[g.rid]: value})
        if g.cmd in (frames.REG_READ, frames.REG_WRITE):
            value = self._register_value(g.rid)
            return [(self.feedback_id, frames.pack_register(frames.Register(self.can_id, g.cmd, g.rid, value)))]
        return []

    def _register_value(self, rid: int) -> int:
        value = {dialects.REG_PMAX: self.ranges.p_max, dialects.REG_VMAX: self.ranges.v_max,
                 dialects.REG_TMAX: self.ranges.t_max}.get(rid, self.registers.get(rid, 0))
        return int(value) if rid in dialects.UINT_REGISTERS else frames.float_bits(float(value))
