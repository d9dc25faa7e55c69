"""The Dynamixel backend on Protocol 1.0 (AX and MX servos with their 1.0 firmware): dynamixel-sdk's
PortHandler and Protocol1PacketHandler for the port and every register read and write at set-up,
servodyn's codec (protocol1.py) for the tick.

How each servo is driven (table1.py):
- MX-64 and MX-106 in torque control mode (Torque Control Mode Enable(70) = 1): the controller's
  joint torque, feed-forward plus the host's PD, becomes Goal Torque(71) = the current through the
  joint's torque constant, in 4.5 mA, sign in bit 10, clamped to the joint's current limit.
- MX-28 and AX-12A have no current loop and no PWM mode, so the servo's position loop is driven as
  the voltage source it is (BAM's model of it): the torque becomes a duty through the motor model
  at the reported supply and speed, and the duty a position offset, Goal Position = present +
  duty / duty_per_tick (P = 32, D = I = 0 on MX; compliance margins 0, slopes 32 on AX). Refusing
  them would leave the MX-28 undrivable by torque; the offset is the same inversion servodyn uses
  for PWM, through a gain BAM measured on the MX loop (the AX's is the e-manual's figure). It is
  quantised to one position unit (~0.8 % duty on MX at P = 32) and a capped duty counts as limiting.

A tick: one BULK READ (0x92, MX) of each servo's span from Present Position(36) — to Current(69)
on a torque-mode servo — each servo answering in turn; on a bus with an AX-12A (no BULK READ in its
firmware) one READ per servo instead. Then one SYNC WRITE per goal register. dynamixel-sdk's
GroupBulkRead is not used: on 1.0 it raises a TypeError (protocol1.py). A status error byte with
input voltage, overheating or overload set is a ServoHardwareError naming it.
"""

from __future__ import annotations

import time

import numpy as np

from ..bus import JointCommand, JointState, ServoBus
from ..errors import ServoHardwareError, ServoInitializationError, ServoOperationError, ServoTimeoutError
from ..port_access import claim_port, open_failure
from ..ports import is_pseudo_terminal
from . import protocol1
from .backend import DynamixelBus
from .protocol1 import FAULT_BITS, Packet, PacketReader, error_faults
from .spec1 import BITS_PER_BYTE, sequential
from .table1 import (CURRENT_UNIT, CURRENT_ZERO, GOAL_TORQUE_MAX, LOAD_FULL, PRESENT, SIGN_BIT, VOLTAGE_UNIT,
                     item, present_length, speed_rad)
from ..feetech.protocol import decode_sign_magnitude, encode_sign_magnitude
from ..feetech.wire import StatusWire

POSITION_GAIN = 32           # P Gain(28) on MX, Compliance Slope(28, 29) on AX, while driven by position


def dynamixel_bus(config, bus=None, **options):
    """The Dynamixel bus of a configuration: DynamixelBus (Protocol 2.0) or Dynamixel1Bus (1.0)."""
    name = bus if bus is not None else next(iter(config.buses))
    spec = config.buses.get(name)
    if spec is not None and spec.protocol == 1.0:
        return Dynamixel1Bus(config, bus, **options)
    return DynamixelBus(config, bus, **options)


class Dynamixel1Bus(StatusWire, ServoBus):
    kind = "dynamixel"

    def __init__(self, config, bus=None, *, port: str | None = None, retries: int = 2,
                 reply_timeout: float | None = None, realtime: bool = True, **kwargs):
        """retries: tries after the first before a read fails; reply_timeout: s to wait for a reply
        (None: its wire time plus hal.feetech.wire's PACKET_TIMEOUT); realtime: an adapter whose latency timer stays
        above 1 ms is refused at open (False: bring-up commands)."""
        kwargs.pop("watchdog", None)          # 1.0 servos have no Bus Watchdog
        super().__init__(config, bus, **kwargs)
        self.port_name = port or self.bus.port
        if self.port_name in (None, "", "auto"):
            raise ServoInitializationError(f"bus '{self.bus.name}': no serial port (port = 'auto' means "
                                           "the simulated bus: start it with `servodyn sim`)")
        self.retries, self.reply_timeout, self.realtime = retries, reply_timeout, realtime
        self.ids = [j.id for j in self.joints]
        self.servos = [j.servo for j in self.joints]
        self.direction = np.array([j.direction for j in self.joints], dtype=float)
        self.gear = np.array([j.gear_ratio for j in self.joints], dtype=float)
        self.zero_offset = np.array([j.zero_offset for j in self.joints], dtype=float)
        self.kt = np.array([j.torque_constant for j in self.joints], dtype=float)
        self.torque_mode = np.array([s.torque_mode for s in self.servos], dtype=bool)
        self.motors = [s.motor_model for s in self.servos]
        self.step = np.array([s.step for s in self.servos])
        self.speed_unit = np.array([speed_rad(s) for s in self.servos])
        self.torque_cap = np.array([min(GOAL_TORQUE_MAX, int(j.current_limit / CURRENT_UNIT)) for j in self.joints])
        self.duty_per_tick = np.array([s.duty_per_tick(POSITION_GAIN) for s in self.servos])
        self.position_max = np.array([s.position_max for s in self.servos])
        supply = config.supply.voltage if config.supply else None
        self.voltage = np.array([supply or s.nominal_voltage for s in self.servos], dtype=float)
        self.temperature = np.full(self.n, np.nan)
        self.spans = [(j.id, PRESENT, present_length(j.servo)) for j in self.joints]
        self.sequential = sequential(self.joints)
        self._read_frames = [protocol1.read(*span) for span in self.spans] if self.sequential else \
            [protocol1.bulk_read(self.spans)]
        self._ticks = np.zeros(self.n)      # Present Position as last read (units)
        self._last: JointState | None = None
        self._reader = PacketReader()

    # ---------------------------------------------------------------- the port and set-up
    def _open(self) -> None:
        import dynamixel_sdk as sdk
        self._sdk = sdk
        self.port = sdk.PortHandler(self.port_name)
        try:
            opened = self.port.openPort()
        except Exception as err:      # pyserial raises its own kinds, most with the OS's errno
            reason = err.errno if isinstance(getattr(err, "errno", None), int) else err
            raise ServoInitializationError(open_failure(self.port_name, reason)) from None
        if not opened or not self.port.setBaudRate(int(self.bus.baud)):
            raise ServoInitializationError(f"{self.port_name}: cannot open at {self.bus.baud} baud")
        if not is_pseudo_terminal(self.port_name):
            try:
                claim_port(self.port.ser.fileno(), self.port_name, realtime=self.realtime)
            except ServoInitializationError:
                self.port.closePort()
                raise
        self._fd = self.port.ser.fileno()
        self.packets = sdk.PacketHandler(1.0)
        for joint in self.joints:
            self._check_servo(joint)
            self.write_item(joint, "torque_enable", 0)
            self.write_item(joint, "return_delay_time", 0)
            self.write_item(joint, "torque_limit", LOAD_FULL)
            if joint.servo.torque_mode:
                self.write_item(joint, "goal_torque", 0)
                self.write_item(joint, "torque_control_mode_enable", 1)
            elif joint.servo.mx:
                for name, value in (("d_gain", 0), ("i_gain", 0), ("p_gain", POSITION_GAIN), ("moving_speed", 0),
                                    ("goal_acceleration", 0)):
                    self.write_item(joint, name, value)
            else:
                for name, value in (("cw_compliance_margin", 0), ("ccw_compliance_margin", 0),
                                    ("cw_compliance_slope", POSITION_GAIN), ("ccw_compliance_slope", POSITION_GAIN),
                                    ("moving_speed", 0)):
                    self.write_item(joint, name, value)

    def _close(self) -> None:
        self.port.closePort()

    def _check_servo(self, joint) -> None:
        for _ in range(self.retries + 1):
            model, result, error = self.packets.ping(self.port, joint.id)
            if result == self._sdk.COMM_SUCCESS:
                break
        else:
            raise ServoInitializationError(
                f"joint '{joint.dof}' (id {joint.id}) did not answer at {self.bus.baud} baud on {self.port_name} "
                f"({self.packets.getTxRxResult(result)}): check its power and cable, and that it was set up "
                f"(ID {joint.id}, {self.bus.baud} baud, Protocol 1.0 firmware)")
        if model != joint.servo.model_number:
            raise ServoInitializationError(f"joint '{joint.dof}' (id {joint.id}) is model number {model}, not the "
                                           f"{joint.servo.name}'s {joint.servo.model_number}")
        if error & FAULT_BITS:
            raise ServoHardwareError(joint.dof, joint.id, error, error_faults(error))

    def read_item(self, joint, name: str) -> int:
        spec = item(joint.servo, name)
        read = {1: self.packets.read1ByteTxRx, 2: self.packets.read2ByteTxRx}[spec.size]
        for _ in range(self.retries + 1):
            value, result, error = read(self.port, joint.id, spec.address)
            if result == self._sdk.COMM_SUCCESS:
                return decode_sign_magnitude(value, spec.sign_bit) if spec.sign_bit is not None else value
        raise ServoTimeoutError(joint.dof, joint.id, self.packets.getTxRxResult(result))

    def write_item(self, joint, name: str, value: int) -> None:
        spec = item(joint.servo, name)
        raw = encode_sign_magnitude(value, spec.sign_bit) if spec.sign_bit is not None else int(value)
        write = {1: self.packets.write1ByteTxRx, 2: self.packets.write2ByteTxRx}[spec.size]
        for _ in range(self.retries + 1):
            result, error = write(self.port, joint.id, spec.address, raw)
            if result == self._sdk.COMM_SUCCESS:
                if error & FAULT_BITS:
                    raise ServoHardwareError(joint.dof, joint.id, error, error_faults(error))
                if error:
                    raise ServoOperationError(f"joint '{joint.dof}': servo {joint.id} refused a write of {name} = "
                                              f"{value} ({self.packets.getRxPacketError(error)})")
                return
        raise ServoTimeoutError(joint.dof, joint.id, self.packets.getTxRxResult(result))

    # ---------------------------------------------------------------- the tick's wire
    @property
    def serial(self):
        """The SDK port's pyserial object (StatusWire clears its input before a request)."""
        return self.port.ser

    def _read_once(self) -> dict[int, Packet]:
        if not self.sequential:
            self._send(self._read_frames[0])
            return self._receive(self.ids, len(self._read_frames[0]) + sum(6 + n for *_, n in self.spans))
        got = {}
        for frame, (servo_id, _, n) in zip(self._read_frames, self.spans):
            self._send(frame)
            got.update(self._receive([servo_id], len(frame) + 6 + n))
        return got

    def _read(self) -> JointState:
        ok = lambda got: all(i in got and len(got[i].params) == n for i, _, n in self.spans)
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats.reads_retried += attempt == 1
            got = self._read_once()
            if ok(got):
                break
        else:
            silent = next(j for j, (i, _, n) in zip(self.joints, self.spans) if i not in got or len(got[i].params) != n)
            raise ServoTimeoutError(silent.dof, silent.id, "no reply to the tick's read")
        t = time.monotonic()
        for joint in self.joints:
            if got[joint.id].error & FAULT_BITS:
                error = got[joint.id].error
                raise ServoHardwareError(joint.dof, joint.id, error, error_faults(error))
        word = lambda p, a: decode_sign_magnitude(p[a - PRESENT] | p[a - PRESENT + 1] << 8, SIGN_BIT)
        params = [got[i].params for i in self.ids]
        self._ticks = np.array([p[0] | p[1] << 8 for p in params], dtype=float)
        horn_speed = np.array([word(p, 38) for p in params]) * self.speed_unit
        load = np.array([word(p, 40) for p in params]) / LOAD_FULL
        volts = np.array([p[42 - PRESENT] for p in params]) * VOLTAGE_UNIT
        self.voltage = np.where(volts > 0, volts, self.voltage)
        self.temperature = np.array([p[43 - PRESENT] for p in params], dtype=float)
        # the horn's current: measured (Current(68)) in torque mode; else the motor's at the duty Present Load reports
        amps = np.array([((p[68 - PRESENT] | p[69 - PRESENT] << 8) - CURRENT_ZERO) * CURRENT_UNIT if tm else
                         m.current(d, v, w)
                         for p, tm, m, d, v, w in zip(params, self.torque_mode, self.motors, load, self.voltage,
                                                      horn_speed)])
        sense = self.direction * self.gear
        q = (self._ticks * self.step - self.zero_offset) / sense
        state = JointState(t=t, q=q, qd=horn_speed / sense, current=self.direction * amps,
                           tau=sense * self.kt * amps, temperature=self.temperature.copy())
        self._last = state
        return state

    # ---------------------------------------------------------------- one tick's goals
    def goals(self, tau, qd) -> tuple[np.ndarray, np.ndarray]:
        """Each joint's goal register value for joint torques `tau` at joint speeds `qd`: Goal Torque
        units (torque mode) or Goal Position units (position loop), and which were limited."""
        sense = self.direction * self.gear
        amps = np.asarray(tau, dtype=float) / sense / self.kt           # horn current wanted
        horn_speed = np.asarray(qd, dtype=float) * sense
        # torque mode: Goal Torque units, clamped to the joint's current limit
        units = np.rint(amps / CURRENT_UNIT)
        torque_goal = np.clip(units, -self.torque_cap, self.torque_cap)
        # the position loop: the duty for that current, capped, as a position offset from the present
        heat = np.nan_to_num(self.temperature, nan=25.0)
        duty = np.array([m.duty_for_current(a, v, w, t) for m, a, v, w, t in
                         zip(self.motors, amps, self.voltage, horn_speed, heat)])
        top = np.array([m.max_duty for m in self.motors])
        capped = np.clip(duty, -top, top)
        ticks = np.rint(self._ticks + capped / self.duty_per_tick)
        position_goal = np.clip(ticks, 0, self.position_max)
        goal = np.where(self.torque_mode, torque_goal, position_goal)
        limited = np.where(self.torque_mode, torque_goal != units, (capped != duty) | (position_goal != ticks))
        return goal.astype(int), limited

    def _enable_torque(self, on: bool) -> None:
        if on and self._last is None:
            self.read_state()
        for joint, ticks in zip(self.joints, self._ticks):
            if on:
                self.write_item(joint, "goal_torque" if joint.servo.torque_mode else "goal_position",
                                0 if joint.servo.torque_mode else int(ticks))
            self.write_item(joint, "torque_enable", int(on))

    def _write(self, command: JointCommand) -> None:
        if self._last is None:
            raise ServoOperationError("write before the first read_state: the PD needs a measured state")
        goal, limited = self.goals(command.torque_at(self._last.q, self._last.qd), self._last.qd)
        self.stats.limited += limited
        frames = b""
        for torque_mode, address in ((True, 71), (False, 30)):
            group = {i: encode_sign_magnitude(int(g), SIGN_BIT if torque_mode else 15).to_bytes(2, "little")
                     for i, g, tm in zip(self.ids, goal, self.torque_mode) if tm == torque_mode}
            if group:
                frames += protocol1.sync_write(address, 2, group)
        self._send(frames)
