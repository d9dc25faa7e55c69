"""Every Protocol 2.0 instruction: builders (host side), parameter parsers (servo side) and the
fast sync/bulk read reply, which packs all servos' answers into one status packet from ID 0xFE.

Addresses and lengths are 2-byte little-endian fields. Parsers raise ``BadParameters`` when the
parameters do not fit the instruction's layout (a servo answers that with a data length error).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum

from . import _dxl
from .protocol import (BROADCAST_ID, FRAME_OVERHEAD, HEADER, CrcMismatch, Instruction,
                       InstructionPacket, PacketError, StatusPacket, crc16, pack_field, unpack_field)

CLEAR_MULTI_TURN = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])   # Clear option 1 and its fixed key


class ResetOption(IntEnum):
    """Factory Reset parameter: what survives the reset."""
    ALL = 0xFF
    EXCEPT_ID = 0x01
    EXCEPT_ID_AND_BAUD = 0x02


class BadParameters(PacketError):
    """Parameters that do not fit their instruction's layout."""


def _word(value: int) -> bytes:
    return pack_field(value, 2)


# --- builders --------------------------------------------------------------------------------------

def ping(servo_id: int = BROADCAST_ID) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.PING)


def read(servo_id: int, address: int, length: int) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.READ, _word(address) + _word(length))


def write(servo_id: int, address: int, data: bytes) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.WRITE, _word(address) + bytes(data))


def reg_write(servo_id: int, address: int, data: bytes) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.REG_WRITE, _word(address) + bytes(data))


def action(servo_id: int = BROADCAST_ID) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.ACTION)


def factory_reset(servo_id: int, option: ResetOption = ResetOption.EXCEPT_ID) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.FACTORY_RESET, bytes([option]))


def reboot(servo_id: int) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.REBOOT)


def clear_multi_turn(servo_id: int) -> InstructionPacket:
    return InstructionPacket(servo_id, Instruction.CLEAR, CLEAR_MULTI_TURN)


def sync_read(address: int, length: int, ids: Iterable[int], fast: bool = False) -> InstructionPacket:
    inst = Instruction.FAST_SYNC_READ if fast else Instruction.SYNC_READ
    return InstructionPacket(BROADCAST_ID, inst, _word(address) + _word(length) + bytes(ids))


def fast_sync_read(address: int, length: int, ids: Iterable[int]) -> InstructionPacket:
    return sync_read(address, length, ids, fast=True)


def sync_write(address: int, length: int, data_by_id: Mapping[int, bytes]) -> InstructionPacket:
    params = bytearray(_word(address) + _word(length))
    for servo_id, data in data_by_id.items():
        if len(data) != length:
            raise BadParameters(f"sync write to {servo_id}: {len(data)} bytes, expected {length}")
        params += bytes([servo_id]) + bytes(data)
    return InstructionPacket(BROADCAST_ID, Instruction.SYNC_WRITE, bytes(params))


def bulk_read(requests: Iterable[tuple[int, int, int]], fast: bool = False) -> InstructionPacket:
    """``requests``: (id, address, length) per servo, each id once."""
    inst = Instruction.FAST_BULK_READ if fast else Instruction.BULK_READ
    params = b"".join(bytes([i]) + _word(a) + _word(n) for i, a, n in requests)
    return InstructionPacket(BROADCAST_ID, inst, params)


def fast_bulk_read(requests: Iterable[tuple[int, int, int]]) -> InstructionPacket:
    return bulk_read(requests, fast=True)


def bulk_write(writes: Iterable[tuple[int, int, bytes]]) -> InstructionPacket:
    """``writes``: (id, address, data) per servo, each id once."""
    params = b"".join(bytes([i]) + _word(a) + _word(len(d)) + bytes(d) for i, a, d in writes)
    return InstructionPacket(BROADCAST_ID, Instruction.BULK_WRITE, params)


# --- parsers (servo side) ----------------------------------------------------------------------------

def parse_read(params: bytes) -> tuple[int, int]:
    """READ parameters → (address, length)."""
    if len(params) != 4:
        raise BadParameters(f"read takes 4 parameter bytes, got {len(params)}")
    return unpack_field(params[:2]), unpack_field(params[2:])


def parse_write(params: bytes) -> tuple[int, bytes]:
    """WRITE / REG WRITE parameters → (address, data)."""
    if len(params) < 3:
        raise BadParameters(f"write takes an address and at least 1 data byte, got {len(params)} bytes")
    return unpack_field(params[:2]), params[2:]


def parse_sync_read(params: bytes) -> tuple[int, int, list[int]]:
    """(FAST) SYNC READ parameters → (address, length, ids in request order)."""
    if len(params) < 5:
        raise BadParameters(f"sync read takes address, length and ids, got {len(params)} bytes")
    return unpack_field(params[:2]), unpack_field(params[2:4]), list(params[4:])


def parse_sync_write(params: bytes) -> tuple[int, list[tuple[int, bytes]]]:
    """SYNC WRITE parameters → (address, [(id, data)])."""
    if len(params) < 4:
        raise BadParameters(f"sync write takes address and length first, got {len(params)} bytes")
    address, length = unpack_field(params[:2]), unpack_field(params[2:4])
    body = params[4:]
    if length == 0 or not body or len(body) % (1 + length):
        raise BadParameters(f"sync write body of {len(body)} bytes is not whole (id + {length}) blocks")
    step = 1 + length
    return address, [(body[k], body[k + 1:k + step]) for k in range(0, len(body), step)]


def parse_bulk_read(params: bytes) -> list[tuple[int, int, int]]:
    """(FAST) BULK READ parameters → [(id, address, length)]."""
    if not params or len(params) % 5:
        raise BadParameters(f"bulk read body of {len(params)} bytes is not whole 5-byte blocks")
    return [(params[k], unpack_field(params[k + 1:k + 3]), unpack_field(params[k + 3:k + 5]))
            for k in range(0, len(params), 5)]


def parse_bulk_write(params: bytes) -> list[tuple[int, int, bytes]]:
    """BULK WRITE parameters → [(id, address, data)]."""
    writes, k = [], 0
    while k < len(params):
        if len(params) - k < 6:
            raise BadParameters(f"bulk write block at byte {k} is cut short")
        servo_id, address = params[k], unpack_field(params[k + 1:k + 3])
        length = unpack_field(params[k + 3:k + 5])
        data = params[k + 5:k + 5 + length]
        if length == 0 or len(data) != length:
            raise BadParameters(f"bulk write to {servo_id}: {len(data)} data bytes, LEN field says {length}")
        writes.append((servo_id, address, data))
        k += 5 + length
    if not writes:
        raise BadParameters("bulk write without blocks")
    return writes


# --- fast sync / bulk read reply ---------------------------------------------------------------------
# One status packet from ID 0xFE: INST 0x55, then per servo ERR ID DATA CRC(2). Each block's CRC is
# the CRC of the whole packet up to it (previous blocks' CRCs included), so the last block's CRC is
# the packet CRC. Never stuffed. (Checked against the e-manual's fast sync and fast bulk examples.)

@dataclass(frozen=True)
class FastReadBlock:
    id: int
    error: int
    data: bytes


def encode_fast_reply(blocks: Sequence[FastReadBlock]) -> bytes:
    out = fast_reply_frame([b.id for b in blocks], [len(b.data) for b in blocks])
    k = FAST_BLOCKS_START
    for block in blocks:
        out[k] = block.error
        out[k + 2:k + 2 + len(block.data)] = block.data
        k += len(block.data) + 4
    seal_fast_reply(out, [len(b.data) for b in blocks])
    return bytes(out)


FAST_BLOCKS_START = 8       # header(4) ID LEN(2) INST, then ERR ID DATA CRC(2) per servo


def fast_reply_frame(ids: Sequence[int], lengths: Sequence[int]) -> bytearray:
    """A fast read reply laid out, to be filled in place: header, LEN (every block counted), INST,
    then per servo its ERR (0), ID, `lengths[i]` data bytes (0) and room for its CRC. A server
    that answers the same request every tick builds it once; seal_fast_reply writes the CRCs."""
    out = bytearray(HEADER + bytes([BROADCAST_ID]) + pack_field(1 + sum(n + 4 for n in lengths), 2)
                    + bytes([Instruction.STATUS]))
    for servo_id, n in zip(ids, lengths):
        out += bytes([0, servo_id]) + bytes(n + 2)
    return out


def seal_fast_reply(frame: bytearray, lengths: Sequence[int]) -> None:
    """Write the running CRC of each of the first len(lengths) blocks of a fast read reply laid
    out in `frame`: the CRC of every byte before it, earlier blocks' CRCs included (the
    firmware's codec in C, servodyn.hal.dynamixel._dxl; ValueError if the blocks do not fit the frame)."""
    _dxl.fast_reply_seal(frame, lengths)


def fast_reply_size(lengths: Sequence[int]) -> int:
    """Bytes of a whole fast read reply whose blocks hold `lengths` data bytes (unstuffed)."""
    return FAST_BLOCKS_START + sum(n + 4 for n in lengths)


def fast_reply_blocks(frame: bytes, lengths: Sequence[int], ids: Sequence[int] | None = None) -> list[FastReadBlock]:
    """The whole blocks at the start of a fast read reply frame, which may be cut short: block i
    holds lengths[i] data bytes and ends in the CRC of the frame up to there (the last block's is
    the packet's). The walk stops at the first block that is incomplete, fails its CRC, or (with
    ``ids``) comes from another servo than ids[i] — on a chain, where the reply stopped."""
    blocks, k = [], FAST_BLOCKS_START
    crc = crc16(frame[:k])
    for i, n in enumerate(lengths):
        end = k + 2 + n
        if end + 2 > len(frame) or (ids is not None and frame[k + 1] != ids[i]):
            break
        crc = crc16(frame[k:end], crc)
        if crc != unpack_field(frame[end:end + 2]):
            break
        blocks.append(FastReadBlock(frame[k + 1], frame[k], bytes(frame[k + 2:end])))
        crc = crc16(frame[end:end + 2], crc)
        k = end + 2
    return blocks


def split_fast_reply(packet: StatusPacket, lengths: Sequence[int]) -> list[FastReadBlock]:
    """The per-servo blocks of a fast read reply; ``lengths`` are the data lengths in request order."""
    if packet.id != BROADCAST_ID:
        raise PacketError(f"fast read reply comes from ID 0xFE, not {packet.id}")
    expected = 1 + sum(n + 4 for n in lengths)
    # rebuild the frame so that every block's running CRC can be checked; the decoder has checked
    # the packet CRC (the last block's) already, so it is recomputed here
    frame = (HEADER + bytes([BROADCAST_ID]) + pack_field(expected, 2)
             + bytes([Instruction.STATUS, packet.error]) + packet.params)
    frame += pack_field(crc16(frame), 2)
    if len(frame) != FRAME_OVERHEAD + expected:
        raise PacketError(f"fast read reply LEN {len(frame) - FRAME_OVERHEAD}, expected {expected}")
    blocks = fast_reply_blocks(frame, lengths)
    if len(blocks) < len(lengths):
        k = FAST_BLOCKS_START + sum(n + 4 for n in lengths[:len(blocks)])
        raise CrcMismatch(f"fast read block of servo {frame[k + 1]}: CRC mismatch")
    return blocks
