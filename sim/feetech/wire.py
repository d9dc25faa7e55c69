"""The simulated STS servos of one bus answering the host's bytes: framing (the HAL's PacketReader),
the line speed (a servo hears only bytes sent at its own rate: the baud gate), dispatch by ID,
broadcast, SYNC WRITE and the STS SYNC READ (each listed servo answers in the order of the IDs).

Collisions: servos sharing an ID (factory-fresh ones all say ID 1) answer one instruction at once
and talk over each other on the half-duplex wire: the host receives the bitwise AND of their bytes
(a low bit wins; past the shorter one the line idles high), whose checksum never checks (`collide`:
identical replies get their checksum inverted, as two UARTs never start on the same bit). Replies
of different IDs to a broadcast PING do not collide here: they come one after another in the order
of the IDs (an assumption: whether an STS servo staggers its answer to a broadcast PING by its ID,
as a Dynamixel does, is not documented; `staggered = False` makes them collide, and bring-up's
scan then reads by SYNC READ, which the servos answer in turn)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from servodyn.hal.feetech import protocol
from servodyn.hal.feetech.protocol import Instruction, Packet, PacketReader
from servodyn.hal.feetech.table import SIMULATOR_CLOCKS

from .servo import FeetechServo


class TimedReader(PacketReader):
    """The HAL's reader with a receiver's byte timeout (None: none): a frame whose bytes come more
    than that apart is dropped."""
    byte_timeout: float | None = None


class StatusWire:
    """The servos of one bus with Protocol 1.0 framing (Feetech STS, Dynamixel 1.0) answering the
    host's bytes: the baud gate, the receiver's byte timeout, the simulator's clock each servo
    serves; a subclass dispatches each packet (`_dispatch`) and names its servos (`device`)."""
    device = "servo"

    def __init__(self, servos: Sequence):
        self.servos = list(servos)
        self.reader = TimedReader()
        self.line_speed: int | None = None     # the host's bytes' speed (None: every servo hears them)
        self.on_command: Callable[[], None] | None = None    # told once a tick's goals are in (lock-step)
        self.wire_clock = time.monotonic
        self._heard_at: float | None = None
        self._clock = "none"

    @property
    def served_clock(self) -> str:
        return self._clock

    @served_clock.setter
    def served_clock(self, mode: str) -> None:
        self._clock = mode
        answer = next((code for code, name in SIMULATOR_CLOCKS.items() if name == mode), 0)
        for servo in self.servos:
            servo.clock_answer = answer

    def servo(self, servo_id: int):
        for servo in self.servos:
            if servo.id == servo_id:
                return servo
        raise KeyError(f"no {self.device} with id {servo_id}")

    def tick(self) -> None:
        """The servos keep no clock servodyn reads (no bus watchdog on an STS or a 1.0 servo)."""

    def _hearing(self) -> list:
        return [s for s in self.servos if self.line_speed is None or s.baud == self.line_speed]

    def handle(self, data: bytes) -> bytes:
        now = self.wire_clock()
        timeout = self.reader.byte_timeout
        late = timeout is not None and self._heard_at is not None and now - self._heard_at > timeout
        if late and self.reader.pending:
            self.reader.expire()
        self._heard_at = now
        reply = bytearray()
        for event in self.reader.feed(data):
            if isinstance(event, Packet):
                reply += self._dispatch(event)
        return bytes(reply)

    def _dispatch(self, packet: Packet) -> bytes:
        raise NotImplementedError


class FeetechWire(StatusWire):
    device = "Feetech servo"

    def __init__(self, servos: Sequence[FeetechServo]):
        super().__init__(servos)
        self.staggered = True          # replies of different IDs to a broadcast PING come in turn

    def _dispatch(self, packet: Packet) -> bytes:
        hearing = self._hearing()
        out = bytearray()
        if packet.id == protocol.BROADCAST_ID and packet.code == Instruction.SYNC_WRITE:
            address, length, body = packet.params[0], packet.params[1], packet.params[2:]
            for k in range(0, len(body) - length, length + 1):
                for servo in (s for s in hearing if s.id == body[k] and not s.silent):
                    after = servo.write(address, body[k + 1:k + 1 + length])
                    if after is not None:
                        after()
            if self.on_command is not None:
                self.on_command()
            return b""
        if packet.id == protocol.BROADCAST_ID and packet.code == Instruction.SYNC_READ:
            address, length = packet.params[0], packet.params[1]
            for servo_id in packet.params[2:]:
                replies = [protocol.status(s.id, s.mem[65], s.read(address, length))
                           for s in hearing if s.id == servo_id and not s.silent]
                out += (replies[0] if len(replies) == 1 else collide(replies)) if replies else b""
            return bytes(out)
        by_id: dict[int, list[bytes]] = {}
        for servo in hearing:
            if packet.id in (servo.id, protocol.BROADCAST_ID):
                answering = servo.id
                reply = servo.execute(packet)
                if packet.id == protocol.BROADCAST_ID and packet.code != Instruction.PING:
                    reply = None
                if reply is not None and not servo.silent:
                    by_id.setdefault(answering, []).append(reply)
        if not self.staggered and packet.id == protocol.BROADCAST_ID and len(by_id) > 1:
            return collide([r for replies in by_id.values() for r in replies])
        for servo_id in sorted(by_id):
            replies = by_id[servo_id]
            out += replies[0] if len(replies) == 1 else collide(replies)
        return bytes(out)


def collide(packets: list[bytes]) -> bytes:
    """What the host receives when servos send `packets` at once: their bytes ANDed, and the packet
    the result announces never checks (the module's docstring)."""
    size = max(len(p) for p in packets)
    wire = -1
    for packet in packets:
        wire &= int.from_bytes(bytes(packet).ljust(size, b"\xff"), "big")
    out = bytearray(wire.to_bytes(size, "big"))
    if size >= 6:
        end = 4 + out[3]
        if 6 <= end <= size and protocol.checksum(bytes(out[2:end - 1])) == out[end - 1]:
            out[end - 1] ^= 0xFF
    return bytes(out)
