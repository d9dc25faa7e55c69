"""What the simulated servos put on the wire: status replies and when a servo answers (its Status
Return Level, a fault), replies that collide on the half-duplex line (`collide`: the wire.py
docstring says how), and the reply to a fast read, one packet that several servos fill in turn.
The instruction dispatch that asks for them is wire.py's."""

from __future__ import annotations

from dataclasses import dataclass

from servodyn.hal.dynamixel import (ALERT_BIT, BROADCAST_ID, ErrorNumber, Instruction, InstructionPacket,
                                    StatusError, StatusPacket, crc16)
from servodyn.hal.dynamixel.control_table import FAST_READ_FIRMWARE
from servodyn.hal.dynamixel.instructions import seal_fast_reply

from .servo import Servo

READS = frozenset({Instruction.READ, Instruction.SYNC_READ, Instruction.FAST_SYNC_READ,
                   Instruction.BULK_READ, Instruction.FAST_BULK_READ})


@dataclass(frozen=True)
class Reply:
    servo_id: int              # 0xFE for a fast read reply
    data: bytes                # the encoded status packet
    delay: float               # the servo's Return Delay Time, s (metadata)


@dataclass(frozen=True)
class Exchange:
    """One instruction packet and what the bus answered; passed to ``on_instruction``."""
    request: InstructionPacket
    replies: tuple[Reply, ...]
    time: float


class Policy:
    """A servo's reply settings as the instruction arrived (a reboot or reset answers first)."""

    def __init__(self, servo: Servo):
        self.level = servo.status_return_level
        self.alert = ALERT_BIT if servo.alert else 0
        self.delay = servo.return_delay
        self.silent = servo.silent

    def answers(self, instruction: int) -> bool:
        return answers(self.silent, self.level, instruction)


def answers(silent: bool, level: int, instruction: int) -> bool:
    """Whether a servo answers an instruction, by its Status Return Level."""
    if silent:
        return False
    if instruction == Instruction.PING:
        return True
    return level == 2 or (level == 1 and instruction in READS)


def collide(packets: list[bytes]) -> bytes:
    """What the host receives when servos send `packets` at once (the module's docstring): their
    bytes ANDed, and the packet the result announces never checks."""
    size = max(len(p) for p in packets)
    wire = -1
    for packet in packets:
        wire &= int.from_bytes(bytes(packet).ljust(size, b"\xFF"), "big")
    out = bytearray(wire.to_bytes(size, "big"))
    if size >= 7:
        end = 7 + (out[5] | out[6] << 8)
        if 9 <= end <= size and crc16(bytes(out[:end - 2])) == out[end - 2] | out[end - 1] << 8:
            out[end - 1] ^= 0xFF
    return bytes(out)


def collided(replies: list[Reply]) -> list[Reply]:
    """The replies of one instruction with those of one ID (several servos holding it) collided."""
    by_id: dict[int, list[Reply]] = {}
    for reply in replies:
        by_id.setdefault(reply.servo_id, []).append(reply)
    if len(by_id) == len(replies):
        return replies
    return [group[0] if len(group) == 1 else Reply(servo_id, collide([r.data for r in group]), group[0].delay)
            for servo_id, group in by_id.items()]


def fast_replies(servos: list[Servo], plain: bool, instruction: int, requests: list[tuple[int, int, int]],
                 frame: bytearray, starts: list[int]) -> list[Reply]:
    """The answer of `servos` to a fast read of `requests` (the reply laid out in `frame`, its
    blocks at `starts`; `plain`: no ID shared and every firmware takes fast reads): one packet, and none when a listed servo is missing or does not answer reads. A silent
    servo (a fault) cuts the reply where its block would begin, as on a chain: the servos
    before it answered, the ones after wait for it and never do, and the header's LEN still
    counts every block, so the host sees a short packet (nothing at all if the first is
    silent). The reply is filled in place in `frame`."""
    if not plain:
        return _fast_replies_apart(servos, instruction, requests, frame, starts)
    answering = []
    present = [servo.id for servo in servos]
    for servo_id, _, _ in requests:
        servo = servos[present.index(servo_id)] if servo_id in present else None
        if servo is not None and servo.silent:
            break
        if servo is None or not answers(False, servo.status_return_level, instruction):
            return []
        answering.append(servo)
    if not answering:
        return []
    return [Reply(BROADCAST_ID, fill_fast_reply(frame, starts, answering, requests), answering[0].return_delay)]

def _fast_replies_apart(servos: list[Servo], instruction: int, requests: list[tuple[int, int, int]],
                        frame: bytearray, starts: list[int]) -> list[Reply]:
    """fast_replies on a bus where an ID is shared or a firmware predates fast reads. A servo of
    Firmware Version below FAST_READ_FIRMWARE does not know the instruction: it answers an
    Instruction Error status of its own (Status Return Level permitting), and for the chain it
    is a silent servo (the fast reply is cut where its block would begin). The holders of a
    shared ID each fill its block (one version of the reply per holder). Whatever goes out at
    once collides (`collide`)."""
    holders = [[s for s in servos if s.id == servo_id] for servo_id, _, _ in requests]
    refusals = [servo for group in holders for servo in group
                if servo.get("firmware_version") < FAST_READ_FIRMWARE and not servo.silent
                and answers(False, servo.status_return_level, instruction)]
    sent = [StatusPacket(servo.id, ErrorNumber.INSTRUCTION | (ALERT_BIT if servo.alert else 0)).encode()
            for servo in refusals]
    answering: list[list[Servo]] = []
    for group in holders:
        if any(s.silent or s.get("firmware_version") < FAST_READ_FIRMWARE for s in group):
            break
        if not group or not all(answers(False, s.status_return_level, instruction) for s in group):
            answering = []
            break
        answering.append(group)
    if answering:
        versions = max(len(group) for group in answering)
        sent += [fill_fast_reply(frame, starts, [group[min(v, len(group) - 1)] for group in answering], requests)
                 for v in range(versions)]
    if not sent:
        return []
    first = answering[0][0] if answering else refusals[0]
    servo_id = BROADCAST_ID if answering else refusals[0].id
    return [Reply(servo_id, sent[0] if len(sent) == 1 else collide(sent), first.return_delay)]


def fill_fast_reply(frame: bytearray, starts: list[int], answering: list[Servo],
                    requests: list[tuple[int, int, int]]) -> bytes:
    """The fast read reply laid out in `frame` filled by `answering`, the servos of the first
    requests in order: the whole frame, or up to where the next one's block would begin."""
    for servo, (_, address, length), start in zip(answering, requests, starts):
        alert = ALERT_BIT if servo.alert else 0
        try:
            servo.read_into(frame, start + 2, address, length)
            error = 0
        except StatusError as refused:
            frame[start + 2:start + 2 + length] = bytes(length)
            error = refused.error
        frame[start] = error | alert
    seal_fast_reply(frame, [length for _, _, length in requests[:len(answering)]])
    return bytes(memoryview(frame)[:starts[len(answering)]])
