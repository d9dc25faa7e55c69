"""The simulated arm: virtual Dynamixel servos wired to a servodyn model.

Behind the servos' control tables the configured arm moves by the C core's direct dynamics
(Armstrong-Green + RK4 at small_time_step): each servo's drive turns its goal registers into a
motor current, the current into a horn torque, and the joint torques into motion; the resulting
joint state goes back into the servos' Present Position, Velocity and Current. A `PtyServer`
puts the bus behind a pseudo-terminal so dynamixel-sdk, or any serial client, opens it as a port.

Two clocks: `realtime` advances the plant with the wall clock; `lockstep` advances it by one
control period whenever the host finishes a command transaction (a sync write), so a run is
deterministic and as fast as the host can go.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

import numpy as np

from servodyn.hal.config import RobotConfig
from servodyn.hal.dynamixel import BROADCAST_ID, Instruction, crc16
from .dynamixel import MODELS, Servo, VirtualBus
from .dynamixel.device import Exchange

SYNC_WRITE = 0x83
BULK_WRITE = 0x93
STATUS = Instruction.STATUS


class SimulatedArm:
    """Servos and plant of a robot configuration; q in the model's dof order."""

    def __init__(self, config: RobotConfig, *, small_time_step: float = 1e-3, q0=None,
                 integrator: str = "rk4"):
        self.config = config
        self.model = config.model
        self.joints = [next(j for j in config.joints if j.dof == name) for name in self.model.dof_names]
        self.units = config.units(self.joints)
        self.small_time_step = small_time_step
        self.integrator = integrator
        self.q = self.model.neutral_q() if q0 is None else np.array(q0, dtype=float)
        self.qd = np.zeros(self.model.nv)
        self.time = 0.0
        self.current = np.zeros(self.model.nv)
        self.silent: set[int] = set()           # servo IDs that stopped answering (fault injection)
        models = {m.name: m for m in MODELS.values()}
        self.servos = [Servo(models[j.servo.name], j.id, position=0.0, zero_ticks=0) for j in self.joints]
        # packets arrive whole through the pty; the plant clock may jump between two reads
        self.bus = VirtualBus(self.servos, clock=lambda: self.time, byte_timeout=None)
        self._publish()

    # the horn angle each servo sees: direction * gear * q + zero offset (hal.units' convention)
    def _horn(self, q, qd):
        u = self.units
        return u.direction * u.gear_ratio * q + u.zero_offset, u.direction * u.gear_ratio * qd

    def _publish(self) -> None:
        position, velocity = self._horn(self.q, self.qd)
        for servo, p, v, i in zip(self.servos, position, velocity, self.current):
            servo.set_present(float(p), float(v), float(i))

    def advance(self, duration: float) -> None:
        """Run the plant for `duration` seconds in small_time_step steps; the servos' drives are
        sampled once per step (their current held over it)."""
        steps = max(1, int(round(duration / self.small_time_step)))
        u = self.units
        for _ in range(steps):
            position, velocity = self._horn(self.q, self.qd)
            horn_torque = np.empty(len(self.servos))
            for k, servo in enumerate(self.servos):
                self.current[k] = servo.output_current(float(position[k]), float(velocity[k]),
                                                       self.small_time_step)
                horn_torque[k] = servo.output_torque(self.current[k], float(velocity[k]))
            tau = u.direction * u.gear_ratio * horn_torque
            self.q, self.qd = self.model.step(self.q, self.qd, tau, self.small_time_step, self.integrator)
            self.time += self.small_time_step
            self._publish()
        self.bus.tick(self.time)

    def handle(self, data: bytes) -> bytes:
        """Bytes from the host in, the replies out (servos in `silent` answer nothing)."""
        reply = self.bus.handle(data, self.time)
        if self.silent and reply:
            reply = _drop_from(reply, self.silent)
        return reply


def _drop_from(stream: bytes, silent: set[int]) -> bytes:
    """A reply stream as the chain puts it on the wire when the servos in `silent` say nothing:
    their own status packets are gone, and a fast sync/bulk read reply (one packet from 0xFE in
    which the servos answer in turn, each appending its block) stops where the first silent
    servo's block would begin. The servos before it answered, the ones after wait for it and
    never do; the header's LEN still counts every block, so the host sees a short packet. A
    silent first servo sends no header: nothing at all."""
    out, k = bytearray(), 0
    while k + 7 <= len(stream):
        length = stream[k + 5] | (stream[k + 6] << 8)
        end = k + 7 + length
        packet = stream[k:end]
        if packet[4] == BROADCAST_ID:
            out += packet[:_fast_reply_cut(packet, silent)]
        elif packet[4] not in silent:
            out += packet
        k = end
    return bytes(out)


def _fast_reply_cut(packet: bytes, silent: set[int]) -> int:
    """Bytes of a fast read reply that reach the host: up to the first silent servo's block."""
    blocks = _fast_blocks(packet)
    if blocks is None:          # not a fast reply this bus made: left as it is
        return len(packet)
    for start, servo_id in blocks:
        if servo_id in silent:
            return 0 if start == FAST_BLOCKS_START else start
    return len(packet)


FAST_BLOCKS_START = 8           # header(4) ID LEN(2) INST, then ERR ID DATA CRC(2) per servo


def _fast_blocks(packet: bytes) -> list[tuple[int, int]] | None:
    """(offset, servo ID) of each block of a fast read reply. The blocks' data lengths are not in
    the reply, but each block ends in the CRC of the packet up to there (the last one is the
    packet's CRC), so the boundaries are the places where the running CRC matches and the rest
    of the packet parses the same way to its end. None if there are none."""
    size = len(packet)

    def walk(k: int, crc: int):
        if k == size:
            return []
        running = crc16(packet[k:k + 2], crc)                  # ERR, ID
        for e in range(k + 3, size - 1):                       # at least one data byte
            running = crc16(packet[e - 1:e], running)          # CRC of packet[:e]
            if packet[e] | packet[e + 1] << 8 == running:
                rest = walk(e + 2, crc16(packet[e:e + 2], running))
                if rest is not None:
                    return [(k, packet[k + 1])] + rest
        return None

    if size < FAST_BLOCKS_START + 5 or packet[7] != STATUS:
        return None
    return walk(FAST_BLOCKS_START, crc16(packet[:FAST_BLOCKS_START]))


class PtyServer:
    """A SimulatedArm behind a pseudo-terminal, served by a background thread."""

    def __init__(self, arm: SimulatedArm, mode: str = "lockstep", control_period: float | None = None):
        if mode not in ("lockstep", "realtime"):
            raise ValueError("mode must be 'lockstep' or 'realtime'")
        self.arm, self.mode = arm, mode
        self.control_period = control_period or arm.small_time_step
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)                 # bytes pass untouched: no echo, no line editing
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._serve, name="servodyn-sim", daemon=True)
        self.transactions = 0
        if mode == "lockstep":
            arm.bus.on_instruction = self._after_instruction

    def __enter__(self) -> "PtyServer":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        self._thread.start()
        if self.mode == "realtime":
            threading.Thread(target=self._clock, name="servodyn-plant", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def _after_instruction(self, exchange: Exchange) -> None:
        # a command transaction ends the control period: the plant catches up by one period
        if exchange.request.instruction in (SYNC_WRITE, BULK_WRITE):
            self.transactions += 1
            self.arm.advance(self.control_period)

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.master], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(self.master, 4096)
            except OSError:
                return
            with self._lock:
                reply = self.arm.handle(data)
            if reply:
                try:
                    os.write(self.master, reply)
                except OSError:
                    return

    def _clock(self) -> None:
        period = self.arm.small_time_step
        start = time.perf_counter()
        while not self._stop.is_set():
            target = start + self.arm.time + period
            delay = target - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            with self._lock:
                self.arm.advance(period)
