"""The simulated Protocol 1.0 servos of one Dynamixel bus answering the host's bytes: framing (the
HAL's PacketReader), the line speed (a servo hears only bytes sent at its own rate), dispatch by ID,
broadcast (a PING to 0xFE: the first servo alone answers, as on 1.0), SYNC WRITE and BULK READ
(each listed servo answers in the order listed; an AX-12A, which has no BULK READ, stays silent).

Lock-step: a tick's goals may take a SYNC WRITE per goal register (Goal Torque and Goal Position),
so `on_command` is told once every servo on the wire has had a goal by SYNC WRITE since it was last
told: once a tick."""

from __future__ import annotations

import time
from collections.abc import Sequence

from servodyn.hal.dynamixel import protocol1
from servodyn.hal.dynamixel.protocol1 import Instruction, Packet, PacketReader
from servodyn.hal.dynamixel.table1 import PRESENT_LENGTH

from ..faults import WireFault
from ..feetech.wire import StatusWire
from .servo1 import Dynamixel1Servo


class Dynamixel1Wire(StatusWire):
    device = "Dynamixel servo"

    def __init__(self, servos: Sequence[Dynamixel1Servo]):
        super().__init__(servos)
        self._commanded: set[int] = set()

    def _dispatch(self, packet: Packet) -> bytes:
        hearing = [s for s in self._hearing() if not s.silent]
        broadcast = packet.id == protocol1.BROADCAST_ID
        if broadcast and packet.code == Instruction.SYNC_WRITE and len(packet.params) >= 2:
            address, length, body = packet.params[0], packet.params[1], packet.params[2:]
            for k in range(0, len(body) - length, length + 1):
                for servo in (s for s in hearing if s.id == body[k]):
                    _, after = servo.write(address, body[k + 1:k + 1 + length])
                    if after is not None:
                        after()
                    self._commanded.add(servo.id)
            if self.on_command is not None and self._commanded >= {s.id for s in self.servos}:
                self._commanded.clear()
                self.on_command()
            return b""
        if broadcast and packet.code == Instruction.BULK_READ:
            out = bytearray()
            for servo_id, address, length in protocol1.bulk_read_entries(packet.params):
                servo = next((s for s in hearing if s.id == servo_id), None)
                if servo is None or not servo.model.bulk_read:
                    break                     # the next waits for this one's status: none comes
                out += protocol1.status(servo.id, servo.error, servo.read(address, length))
            return bytes(out)
        if broadcast and packet.code == Instruction.PING:
            return hearing[0].execute(packet) if hearing else b""
        out = bytearray()
        for servo in hearing:
            if packet.id in (servo.id, protocol1.BROADCAST_ID):
                reply = servo.execute(packet)
                if reply is not None and not broadcast:
                    out += reply
        return bytes(out)


class Wire1Fault(WireFault):
    """sim/faults.py's wire faults on 1.0 frames: `delayed_reply` holds back each reply to a tick's
    read (a status packet of a present span, PRESENT_LENGTH bytes or more; pings and writes are
    answered at once), `wrong_id` re-frames every status packet under the next ID (checksums
    valid); the others act on bytes alike on either protocol."""

    def apply(self, reply: bytes) -> bytes:
        packets = [e for e in PacketReader().feed(reply) if isinstance(e, Packet)] if reply else []
        if self.kind == "delayed_reply":
            if packets and len(packets[0].params) >= PRESENT_LENGTH:
                time.sleep(self.delay)
            return reply
        if self.kind == "wrong_id" and packets:
            return b"".join(protocol1.status((p.id + 1) % protocol1.BROADCAST_ID, p.error, p.params) for p in packets)
        return super().apply(reply)
