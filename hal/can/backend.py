"""The CAN backend of the servo bus: MIT-style motors over python-can, so every adapter python-can
drives works (socketcan, slcan, gs_usb, pcan, virtual, ...).

Each joint's motor closes τ = kp (p − θ) + t_ff + kd (v − ω) itself; the host sends one 8-byte
command frame per motor a tick (hal/can/frames.py) and each motor answers it with its state
(hal/can/dialects.py: where and how). A tick is `write()` — every motor's frame out — then the
next `read_state()`, which collects the replies against a deadline: a motor that does not answer
raises ServoTimeoutError naming its joint, a fault status ServoHardwareError with the decoded
fault. So the state a tick reads is the motors' answer to the previous tick's command, as the
firmware packs its reply before it acts on the frame.

At open every motor is sent "exit motor mode" and must answer; a Damiao motor's CTRL_MODE and
PMAX/VMAX/TMAX registers are read and checked against the configuration (a motor in another mode
ignores MIT frames without a word), and its CAN timeout register is written so a dead host leaves
it limp. `enable_torque(True)` enters motor mode, `stop()` exits it. Zero is set only by
`set_zero(dof)`, an explicit calibration command. Error frames and python-can errors (bus-off,
a failed write) raise ServoOperationError: the caller's safe stop follows.

Joint ↔ motor: p = direction·gear·q + zero_offset, v = direction·gear·qd, t = direction·τ/gear,
kp_motor = kp/gear², kd_motor = kd/gear² (gear_ratio: a reduction after the motor's own, 1 by default).
"""

from __future__ import annotations

import time

import numpy as np

from ..bus import JointCommand, JointState, ServoBus
from ..errors import (ServoError, ServoHardwareError, ServoInitializationError, ServoOperationError,
                      ServoTimeoutError)
from . import frames
from .dialects import (CTRL_MODES, DIALECTS, MIT_MODE, RANGE_REGISTERS, REG_CTRL_MODE, REG_TIMEOUT, TIMEOUT_UNIT,
                       range_matches, register_bits, register_value)
from .link import CanLink, open_bus
from .spec import interface_for

REPLY_TIMEOUT = 0.02            # s to collect a tick's replies (14 frames are ~2 ms at 1 Mbit/s)
MOTOR_CAN_TIMEOUT = 0.1         # s without a command after which a motor goes limp by itself
# s the stop keeps trying a motor's exit frame while sends fail: a controller that went bus-off
# rejoins by itself after its restart time (Linux can: restart-ms, often 100 ms)
STOP_PATIENCE = 0.25


class CanBus(ServoBus):
    kind = "can"

    def __init__(self, config, bus=None, *, port: str | None = None, interface: str | None = None,
                 can_bus=None, reply_timeout: float = REPLY_TIMEOUT, can_timeout: float = MOTOR_CAN_TIMEOUT,
                 **kwargs):
        """port: the channel (default the configuration's); interface: python-can's (default: what
        the channel names, spec.interface_for, else the configuration's); can_bus: an open python-can bus to use instead (not shut down by close());
        reply_timeout: s to wait for a tick's replies; can_timeout: s after which a motor with no
        command goes limp (Damiao's TIMEOUT register)."""
        super().__init__(config, bus, **kwargs)
        self.channel = port or self.bus.port
        # --port can0 means SocketCAN, a /dev/tty* an SLCAN adapter, whatever the configuration's default
        self.interface = interface or interface_for(self.channel, self.bus.options.get("interface"))
        if can_bus is None and self.channel in (None, "", "auto"):
            raise ServoInitializationError(f"bus '{self.bus.name}': no channel (channel = 'auto' means the "
                                           "simulated bus: start it with `servodyn sim`)")
        self._given = can_bus
        self.reply_timeout, self.can_timeout = reply_timeout, can_timeout
        self.dialects = [DIALECTS[j.options["dialect"]] for j in self.joints]
        self.ranges = [j.options["ranges"] for j in self.joints]
        self._route = {}
        for k, (joint, dialect) in enumerate(zip(self.joints, self.dialects)):
            key = (joint.options["feedback_id"], (joint.id & 0xF) if dialect.name == "damiao" else joint.id)
            if key in self._route:
                other = self.joints[self._route[key]].dof
                raise ServoInitializationError(f"joints '{other}' and '{joint.dof}' would answer on the same "
                                               f"id 0x{key[0]:X} with the same motor id {key[1]}")
            self._route[key] = k
        self._reply_ids = {key[0] for key in self._route}     # no other node may send on these
        scale = np.array([j.direction * j.gear_ratio for j in self.joints], dtype=float)
        self._scale, self._gear = scale, np.array([j.gear_ratio for j in self.joints], dtype=float)
        self._offset = np.array([j.zero_offset for j in self.joints], dtype=float)
        self.temperatures = np.zeros((self.n, 2))      # °C per motor as last reported (MOS/motor, coil)
        self.winding = np.full(self.n, np.nan)         # °C per motor's winding, as last reported (nan: none)
        self.link = CanLink(self.bus.name, timeout=reply_timeout)
        self.sent = np.zeros((self.n, 5))              # the last command as sent, decoded (p, v, kp, kd, t)

    # ---------------------------------------------------------------- set-up
    def _open(self) -> None:
        self.can = self._given if self._given is not None else open_bus(self.channel, self.interface, self.bus.baud)
        self.link.can = self.can
        try:
            self._torque_on = False
            self._pending: set[int] = set()
            self._fresh = False              # replies collected that no read has returned yet
            self._state = [None] * self.n
            for k, joint in enumerate(self.joints):
                if self.dialects[k].registers:
                    self._check_registers(k)
            self._special_all(frames.EXIT)
            self._collect()
        except BaseException:
            self._close()
            raise

    def _close(self) -> None:
        if self._given is None and getattr(self, "can", None) is not None:
            try:
                self.can.shutdown()
            except Exception:
                pass
        self.can = self.link.can = None

    @property
    def warnings(self) -> int:
        """Error frames of a controller's warning or passive state alone (the run went on)."""
        return self.link.warnings

    @property
    def foreign(self) -> int:
        """29-bit, CAN FD and remote frames seen: no motor's reply, skipped."""
        return self.link.foreign

    def _check_registers(self, k: int) -> None:
        joint, ranges = self.joints[k], self.ranges[k]
        mode = self.read_register(joint.dof, REG_CTRL_MODE)
        if mode != MIT_MODE:
            raise ServoInitializationError(
                f"joint '{joint.dof}': motor {joint.id} is in {CTRL_MODES.get(mode, f'mode {mode}')} mode "
                f"(CTRL_MODE = {mode}); in any mode but MIT (1) it ignores MIT frames without a word")
        for rid, name in RANGE_REGISTERS.items():
            value = self.read_register(joint.dof, rid)
            if not range_matches(value, getattr(ranges, name)):
                raise ServoInitializationError(
                    f"joint '{joint.dof}': motor {joint.id} has {name.upper().replace('_', '')} = {value:g} "
                    f"(register {rid}), the configuration says {getattr(ranges, name):g}: every frame would "
                    f"be scaled wrong")
        units = max(1, int(round(self.can_timeout / TIMEOUT_UNIT)))
        self.write_register(joint.dof, REG_TIMEOUT, units)

    def _joint(self, dof: str) -> int:
        if dof not in self.dof_names:
            raise ServoOperationError(f"bus '{self.bus.name}' has no joint '{dof}'")
        return self.dof_names.index(dof)

    def _register(self, k: int, cmd: int, rid: int, value: int = 0) -> frames.Register:
        """One register transaction with a Damiao motor; its reply on the feedback id."""
        joint = self.joints[k]
        if not self.dialects[k].registers:
            raise ServoOperationError(f"joint '{joint.dof}': a {self.dialects[k].name} motor has no registers")
        answer = self.link.register(joint.id, cmd, rid, value, reply_ids={joint.options["feedback_id"]})
        if answer is not None:
            return answer[0]
        raise ServoTimeoutError(joint.dof, joint.id, f"no answer to register {rid} "
                                                     f"({'read' if cmd == frames.REG_READ else 'write'})")

    def read_register(self, dof: str, rid: int) -> float:
        """A Damiao register (uint32 or float32 by its number)."""
        return register_value(rid, self._register(self._joint(dof), frames.REG_READ, rid))

    def write_register(self, dof: str, rid: int, value: float) -> None:
        self._register(self._joint(dof), frames.REG_WRITE, rid, register_bits(rid, value))

    def set_zero(self, dof: str) -> None:
        """Calibration: the motor's present position becomes its zero. Never called implicitly;
        only with torque off (a motor in motor mode would jump to the new zero's target)."""
        self._check_open()
        if self._torque_on:
            raise ServoOperationError("set_zero: switch the torque off first")
        k = self._joint(dof)
        self._send(self.joints[k].id, frames.pack_special(frames.SET_ZERO))
        self._pending.add(k)
        self._collect()

    def clear_errors(self) -> None:
        """Damiao: clear every motor's latched fault (the FB special frame)."""
        self._check_open()
        for k, joint in enumerate(self.joints):
            if self.dialects[k].name == "damiao":
                self._send(joint.id, frames.pack_special(frames.CLEAR_ERROR))
                self._pending.add(k)
        self._collect(check_faults=False)

    # ---------------------------------------------------------------- the wire
    def _send(self, arbitration_id: int, data: bytes) -> None:
        try:
            self.link.send(arbitration_id, data)
        finally:
            self.lost = self.lost or self.link.lost

    def _recv(self, timeout: float):
        try:
            return self.link.recv(timeout)
        finally:
            self.lost = self.lost or self.link.lost

    def _flush(self) -> None:
        """Take the answers still owed, then drop whatever else waits (late replies of a tick that
        failed), so the next round's replies are matched to their own frames."""
        for _ in range(100):            # error frames interleaved with the owed answers: keep taking them
            try:
                self._collect(check_faults=False)
                break
            except ServoOperationError:
                continue
            except ServoError:
                break
        for _ in range(1000):          # a bounded drain: a flooding bus cannot hold the stop
            try:
                if self._recv(0.0) is None:
                    break
            except ServoOperationError:   # an error frame already seen: keep draining
                continue

    def _special_all(self, code: int) -> None:
        self._flush()
        for k, joint in enumerate(self.joints):
            self._send(joint.id, frames.pack_special(code))
            self._pending.add(k)

    def _collect(self, check_faults: bool = True) -> None:
        """Every pending motor's reply before the deadline, decoded into self._state."""
        deadline = time.monotonic() + self.reply_timeout
        while self._pending:
            left = deadline - time.monotonic()
            msg = self._recv(max(0.0, left)) if left > 0 else None
            if msg is None:
                k = min(self._pending)
                joint = self.joints[k]
                self._pending.clear()
                raise ServoTimeoutError(joint.dof, joint.id, f"no reply within {self.reply_timeout * 1e3:g} ms "
                                                             f"on id 0x{joint.options['feedback_id']:X}")
            data = bytes(msg.data)
            known = False
            for dialect_name in {d.name for d in self.dialects} if data else ():
                dialect = DIALECTS[dialect_name]
                if len(data) not in dialect.reply_length:
                    continue
                k = self._route.get((msg.arbitration_id, dialect.reply_key(data)))
                if k is None or self.dialects[k] is not dialect:
                    continue
                known = True
                if k not in self._pending:
                    continue
                if dialect.registers and data[2] in (frames.REG_READ, frames.REG_WRITE) and \
                        data[0] | (data[1] << 8) == self.joints[k].id:
                    continue        # a register echo, not a state (damiao-motor mistakes it for one)
                reply = dialect.unpack(self.ranges[k], data)
                self._pending.discard(k)
                self._fresh = not self._pending
                self._state[k] = reply
                self.temperatures[k] = (reply.temperature, reply.temperature2)
                self.winding[k] = dialect.winding_temperature(reply)
                faults = dialect.faults(reply, self._torque_on) if check_faults else ()
                if faults:
                    self._pending.clear()
                    joint = self.joints[k]
                    raise ServoHardwareError(joint.dof, joint.id, reply.status, faults)
                break
            if not known and msg.arbitration_id in self._reply_ids:
                # on a reply id only the motors here speak: this is none of their frames
                self._pending.clear()
                raise ServoOperationError(
                    f"bus '{self.bus.name}': a frame on reply id 0x{msg.arbitration_id:X} that no motor here "
                    f"sends ({len(data)} bytes {data.hex() or '-'}): "
                    f"a corrupt reply, or another node on the id")

    # ---------------------------------------------------------------- the tick
    def _enable_torque(self, on: bool) -> None:
        # the answers to enter/exit may carry the state before the frame (the mini-cheetah firmware
        # packs its reply first): a disabled status there is no fault, a fault status is
        self._torque_on = False
        self._special_all(frames.ENTER if on else frames.EXIT)
        self._collect()
        self._torque_on = on

    def _stop(self) -> bool:
        """Exit motor mode on every motor: each is sent its frame even if another's send fails. On
        a port known gone (its adapter unplugged, its simulator ended) one send each, no waiting."""
        self._torque_on = False
        if not self.lost:
            self._flush()
        sent = True
        deadline = time.monotonic() + STOP_PATIENCE
        for k, joint in enumerate(self.joints):
            while True:
                try:
                    self._send(joint.id, frames.pack_special(frames.EXIT))
                    self._pending.add(k)
                    break
                except ServoError:
                    if self.lost:
                        return False
                    if time.monotonic() >= deadline:
                        sent = False
                        break
                    time.sleep(0.002)
        try:
            self._collect(check_faults=False)
        except ServoError:
            return False
        return sent

    def _read(self) -> JointState:
        if not self._pending and not self._fresh:
            # a read with no command since the last: ask again (every motor answers a special frame)
            self._special_all(frames.ENTER if self._torque_on else frames.EXIT)
        self._collect()
        self._fresh = False
        motor = np.array([(s.p, s.v, s.t) for s in self._state])
        q = (motor[:, 0] - self._offset) / self._scale
        qd = motor[:, 1] / self._scale
        tau = motor[:, 2] * self._scale
        # every reply carries the motors' temperatures: read every tick at no cost
        return JointState(t=time.monotonic(), q=q, qd=qd, current=tau / self.torque_per_amp, tau=tau,
                          temperature=self.winding.copy())

    def _write(self, command: JointCommand) -> None:
        if self._pending:
            self._collect()          # the previous tick's replies were never read: take them now
        p = self._scale * command.q + self._offset
        v = self._scale * command.qd
        t = command.tau_ff / self._scale
        gear2 = self._gear ** 2
        for k, joint in enumerate(self.joints):
            r = self.ranges[k]
            data, clamped = frames.pack_command(r, p[k], v[k], command.kp[k] / gear2[k], command.kd[k] / gear2[k], t[k])
            self.stats.limited[k] += clamped != 0
            sent = frames.unpack_command(r, data)
            self.sent[k] = (sent.p, sent.v, sent.kp, sent.kd, sent.t)
            self._send(joint.id, data)
            self._pending.add(k)

    @property
    def sent_torque(self) -> np.ndarray:
        """The joint torque feed-forward the last frames carried, as the motors decode it."""
        return self.sent[:, 4] * self._scale

