"""The simulated STS servos of one bus answering the host's bytes: framing (the HAL's PacketReader),
the line speed (a servo hears only bytes sent at its own rate: the baud gate), dispatch by ID,
broadcast, SYNC WRITE and the STS SYNC READ (each listed servo answers in the order of the IDs)."""

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


class FeetechWire:
    def __init__(self, servos: Sequence[FeetechServo], clock: Callable[[], float] | None = None):
        self.servos = list(servos)
        self.reader = TimedReader()
        self.line_speed: int | None = None     # the host's bytes' speed (None: every servo hears them)
        self.on_command: Callable[[], None] | None = None    # told after each SYNC WRITE (lock-step)
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

    def servo(self, servo_id: int) -> FeetechServo:
        for servo in self.servos:
            if servo.id == servo_id:
                return servo
        raise KeyError(f"no Feetech servo with id {servo_id}")

    def tick(self) -> None:
        """The servos keep no clock of their own (no bus watchdog on an STS)."""

    def _hearing(self) -> list[FeetechServo]:
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
                for servo in (s for s in hearing if s.id == servo_id and not s.silent):
                    out += protocol.status(servo.id, servo.mem[65], servo.read(address, length))
            return bytes(out)
        for servo in hearing:
            if packet.id in (servo.id, protocol.BROADCAST_ID):
                reply = servo.execute(packet)
                if packet.id == protocol.BROADCAST_ID and packet.code != Instruction.PING:
                    reply = None
                if reply is not None and not servo.silent:
                    out += reply
        return bytes(out)
