"""The Feetech STS backend of the servo bus, over pyserial and servodyn's own codec (protocol.py).

Torque feed-forward through PWM: STS servos have no current loop, so every servo runs in
Operating_Mode 2 (open-loop PWM) and the host closes the joint PD itself; the torque the controller
computes — feed-forward plus PD — becomes a duty through the servo's motor model at the supply
voltage the servo last reported and the joint's measured speed (spec.joint_duty), written to
Goal_Time(44) (0.1 %, sign bit 10).

A tick is two transactions: one SYNC READ (0x82) of Present Position .. Present Current
(addresses 56..70: position, speed, load = the applied duty, voltage, temperature, status,
current) that every servo answers with a status packet of its own, in the order of the IDs; and
one SYNC WRITE of the duties, which no servo answers. A short reply is retried (what still arrives
after its time-out dropped first; replies that come only after it are a stalled bus,
BusStallError); then each silent servo is named (ServoTimeoutError). A status byte with a fault
bit (voltage, encoder, temperature, current, overload) is a ServoHardwareError naming it.

At open, each servo: answers a PING; Torque_Enable 0; Lock 1 (so the mode written next lasts
until power-off and is not written to flash: the lock is inverted, 0 persists); Return_Delay_Time
0; Operating_Mode 2; Goal_Time 0.
"""

from __future__ import annotations

import os
import select
import time

import numpy as np

from ..bus import PORT_ERRORS, JointCommand, JointState, ServoBus
from ..errors import BusStallError, ServoHardwareError, ServoInitializationError, ServoOperationError, ServoTimeoutError
from ..port_access import claim_port, open_failure
from ..ports import is_pseudo_terminal
from . import protocol
from .protocol import Instruction, Packet, PacketReader, decode_sign_magnitude, encode_sign_magnitude, status_faults
from .spec import BITS_PER_BYTE, joint_duty
from .wire import StatusWire
from .table import CURRENT_UNIT, DUTY_FULL, ITEM, PRESENT_ADDRESS, PRESENT_LENGTH, STEP, VOLTAGE_UNIT, Mode

GOAL = ITEM["goal_time"]
FAULT_BITS = 0x2F         # the status bits that are faults (voltage, encoder, temperature, current, overload)


def decode_present(params: bytes) -> tuple[int, int, int, int, int, int, int]:
    """(position, speed, load, voltage, temperature, status, current) of a SYNC READ reply's 15
    bytes from address 56, sign-magnitude decoded."""
    raw = lambda a: params[a - PRESENT_ADDRESS] | params[a - PRESENT_ADDRESS + 1] << 8
    return (decode_sign_magnitude(raw(56), 15), decode_sign_magnitude(raw(58), 15),
            decode_sign_magnitude(raw(60), 10), params[62 - PRESENT_ADDRESS], params[63 - PRESENT_ADDRESS],
            params[65 - PRESENT_ADDRESS], decode_sign_magnitude(raw(69), 15))


class FeetechBus(StatusWire, ServoBus):
    kind = "feetech"

    def __init__(self, config, bus=None, *, port: str | None = None, retries: int = 2,
                 reply_timeout: float | None = None, realtime: bool = True, **kwargs):
        """retries: tries after the first before a read fails; reply_timeout: s to wait for a reply
        (None: its wire time plus wire.PACKET_TIMEOUT); realtime: an adapter whose latency timer stays
        above 1 ms is refused at open (False: bring-up commands)."""
        super().__init__(config, bus, **kwargs)
        self.port_name = port or self.bus.port
        if self.port_name in (None, "", "auto"):
            raise ServoInitializationError(f"bus '{self.bus.name}': no serial port (port = 'auto' means "
                                           "the simulated bus: start it with `servodyn sim`)")
        self.retries, self.reply_timeout, self.realtime = retries, reply_timeout, realtime
        self.ids = [j.id for j in self.joints]
        self.direction = np.array([j.direction for j in self.joints], dtype=float)
        self.gear = np.array([j.gear_ratio for j in self.joints], dtype=float)
        self.zero_offset = np.array([j.zero_offset for j in self.joints], dtype=float)
        supply = config.supply.voltage if config.supply else None
        self.voltage = np.array([supply or j.servo.nominal_voltage for j in self.joints], dtype=float)
        self.temperature = np.full(self.n, np.nan)
        self.present: dict[str, np.ndarray] = {}     # the last tick's load (duty), voltage, temperature, current
        self._last: JointState | None = None
        self._reader = PacketReader()
        self._read_frame = protocol.sync_read(PRESENT_ADDRESS, PRESENT_LENGTH, self.ids)

    # ---------------------------------------------------------------- the wire
    def _open(self) -> None:
        import serial
        try:
            self.serial = serial.Serial(self.port_name, int(self.bus.baud), timeout=0)
        except Exception as err:      # pyserial raises its own kinds, most with the OS's errno
            reason = err.errno if isinstance(getattr(err, "errno", None), int) else err
            raise ServoInitializationError(open_failure(self.port_name, reason)) from None
        if not is_pseudo_terminal(self.port_name):
            try:
                claim_port(self.serial.fileno(), self.port_name, realtime=self.realtime)
            except ServoInitializationError:
                self.serial.close()
                raise
        self._fd = self.serial.fileno()
        for joint in self.joints:
            self._check_servo(joint)
            self.write_item(joint, "torque_enable", 0)
            self.write_item(joint, "lock", 1)               # inverted: 1 = EEPROM writes until power-off only
            self.write_item(joint, "return_delay_time", 0)
            self.write_item(joint, "operating_mode", Mode.PWM)
            self.write_item(joint, "goal_time", 0)

    def _close(self) -> None:
        self.serial.close()

    def _drain(self, quiet: float) -> int:
        """After a failed read, the bytes that still arrive dropped until the line has been quiet for
        `quiet` s (at most 4 x): a reply after its time-out is never taken for the retry's."""
        dropped, deadline = 0, time.monotonic() + 4 * quiet
        while time.monotonic() < deadline:
            try:
                if not select.select([self._fd], [], [], quiet)[0]:
                    break
                dropped += len(os.read(self._fd, 4096))
            except PORT_ERRORS as err:
                raise self._gone(err) from None
        return dropped

    def transact(self, servo_id: int, frame: bytes, reply_params: int = 0) -> Packet | None:
        """One instruction to one servo and its status packet (None if it did not answer)."""
        self._send(frame)
        return self._receive([servo_id], len(frame) + 6 + reply_params).get(servo_id)

    # ---------------------------------------------------------------- registers
    def _check_servo(self, joint) -> None:
        for _ in range(self.retries + 1):
            reply = self.transact(joint.id, protocol.read(joint.id, 3, 2), 2)
            if reply is not None:
                break
        else:
            raise ServoInitializationError(
                f"joint '{joint.dof}' (id {joint.id}) did not answer at {self.bus.baud} baud on {self.port_name}: "
                f"check its power and cable, and that it was set up (ID {joint.id}, {self.bus.baud} baud)")
        model = reply.params[0] | reply.params[1] << 8 if len(reply.params) == 2 else None
        if model != joint.servo.model_number:
            raise ServoInitializationError(f"joint '{joint.dof}' (id {joint.id}) is model number {model}, not the "
                                           f"{joint.servo.name}'s {joint.servo.model_number}")

    def read_item(self, joint, name: str) -> int:
        item = ITEM[name]
        for _ in range(self.retries + 1):
            reply = self.transact(joint.id, protocol.read(joint.id, item.address, item.size), item.size)
            if reply is not None and len(reply.params) == item.size:
                return decode_sign_magnitude(int.from_bytes(reply.params, "little"), item.sign_bit) \
                    if item.sign_bit is not None else int.from_bytes(reply.params, "little")
        raise ServoTimeoutError(joint.dof, joint.id, f"no reply to a read of {name}")

    def write_item(self, joint, name: str, value: int) -> None:
        item = ITEM[name]
        raw = encode_sign_magnitude(value, item.sign_bit) if item.sign_bit is not None else int(value)
        frame = protocol.write(joint.id, item.address, raw.to_bytes(item.size, "little"))
        for _ in range(self.retries + 1):
            reply = self.transact(joint.id, frame)
            if reply is not None:
                if reply.error & FAULT_BITS:
                    raise ServoHardwareError(joint.dof, joint.id, reply.error, status_faults(reply.error))
                return
        raise ServoTimeoutError(joint.dof, joint.id, f"no reply to a write of {name}")

    # ---------------------------------------------------------------- one tick
    def _enable_torque(self, on: bool) -> None:
        for joint in self.joints:
            if on:
                self.write_item(joint, "goal_time", 0)
            self.write_item(joint, "torque_enable", int(on))

    def _read(self) -> JointState:
        nbytes = len(self._read_frame) + len(self.ids) * (6 + PRESENT_LENGTH)
        got: dict[int, Packet] = {}
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats.reads_retried += attempt == 1
            self._send(self._read_frame)
            got = self._receive(self.ids, nbytes)
            if len(got) == len(self.ids) and all(len(p.params) == PRESENT_LENGTH for p in got.values()):
                break
            late = self._drain(self._timeout(nbytes))
            if late and not got:
                # nothing in time, then replies after the time-out: the bus held back; a retry
                # would take them for its own (a tick old, and every later one too)
                raise BusStallError(self.bus.name, f"no reply to the tick's SYNC READ in time; {late} bytes "
                                                   "came after the time-out and were dropped")
        else:
            silent = next(j for j in self.joints if j.id not in got or len(got[j.id].params) != PRESENT_LENGTH)
            raise ServoTimeoutError(silent.dof, silent.id, "no reply to the tick's SYNC READ")
        t = time.monotonic()
        rows = np.array([decode_present(got[i].params) for i in self.ids], dtype=float)
        for joint, packet in zip(self.joints, (got[i] for i in self.ids)):
            if packet.error & FAULT_BITS:
                raise ServoHardwareError(joint.dof, joint.id, packet.error, status_faults(packet.error))
        sense = self.direction * self.gear
        q = (rows[:, 0] * STEP - self.zero_offset) / sense
        qd = rows[:, 1] * STEP / sense
        self.voltage = np.where(rows[:, 3] > 0, rows[:, 3] * VOLTAGE_UNIT, self.voltage)
        self.temperature = rows[:, 4]
        current = self.direction * rows[:, 6] * CURRENT_UNIT
        duty = rows[:, 2] / DUTY_FULL
        horn = np.array([j.servo.motor.torque(d, v, w) for d, w, j, v in zip(duty, rows[:, 1] * STEP, self.joints,
                                                                                    self.voltage)])
        self.present = {"load": duty * self.direction, "voltage": self.voltage, "temperature": self.temperature,
                        "current": current}
        state = JointState(t=t, q=q, qd=qd, current=current, tau=sense * horn, temperature=self.temperature.copy())
        self._last = state
        return state

    def duties(self, tau, qd) -> np.ndarray:
        """The Goal_Time(44) value of each joint for joint torques `tau` at joint speeds `qd`: the
        duty at each servo's last reported voltage, in its sense, rounded to 0.1 % and clipped to
        ±100 % (a clipped one counts as limited)."""
        duty = np.array([joint_duty(t, w, j, v) for t, w, j, v in zip(tau, qd, self.joints, self.voltage)])
        units = np.rint(self.direction * duty * DUTY_FULL)
        clipped = np.clip(units, -DUTY_FULL, DUTY_FULL)
        self.stats.limited += clipped != units
        return clipped.astype(int)

    def _write(self, command: JointCommand) -> None:
        if self._last is None:
            raise ServoOperationError("write before the first read_state: the PD needs a measured state")
        tau = command.torque_at(self._last.q, self._last.qd)
        units = self.duties(tau, self._last.qd)
        goals = {i: encode_sign_magnitude(int(u), GOAL.sign_bit).to_bytes(2, "little") for i, u in zip(self.ids, units)}
        frame = protocol.sync_write(GOAL.address, 2, goals)
        self._send(frame)
