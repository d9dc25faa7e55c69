"""DYNAMIXEL Protocol 2.0 framing: fields, CRC-16, byte stuffing, packets and their errors.

A frame is ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params | CRC_L CRC_H``. LEN counts the
instruction, the (stuffed) parameters and the CRC. The CRC covers every byte before it, stuffing
included. A status packet is a frame whose INST is 0x55 and whose first parameter is the ERR byte.
Written from the ROBOTIS e-manual, "DYNAMIXEL Protocol 2.0".
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from . import _dxl
from ..errors import ProtocolError

HEADER = b"\xFF\xFF\xFD\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
ALERT_BIT = 0x80
MIN_LENGTH = 3                 # INST + CRC: the smallest LEN field
FRAME_OVERHEAD = 7             # header(4) + ID + LEN(2): bytes not counted by LEN


class Instruction(IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrorNumber(IntEnum):
    """Low seven bits of a status packet's ERR byte."""
    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


# --- exceptions ------------------------------------------------------------------------------------

class FieldRangeError(ProtocolError, ValueError):
    """A value does not fit the control-table field it is packed into."""


class PacketError(ProtocolError):
    """Bytes that are not a well-formed frame, or parameters that do not fit their instruction."""


class CrcMismatch(PacketError):
    """The CRC of a frame does not match its contents."""


class StatusError(ProtocolError):
    """A servo answered with a nonzero error number (or a simulated servo refuses an instruction)."""

    def __init__(self, error: int, servo_id: int | None = None):
        self.error = error
        self.servo_id = servo_id
        number = error & ~ALERT_BIT
        name = ErrorNumber(number).name if number <= ErrorNumber.ACCESS else "UNKNOWN"
        alert = ", alert" if error & ALERT_BIT else ""
        super().__init__(f"servo {servo_id}: error {number} ({name}){alert}")

    @property
    def error_number(self) -> int:
        return self.error & ~ALERT_BIT


# --- little-endian control-table fields ----------------------------------------------------------

def pack_field(value: int, size: int, signed: bool = False) -> bytes:
    """``value`` as a 1, 2 or 4-byte little-endian field."""
    if size not in (1, 2, 4):
        raise FieldRangeError(f"field size {size}: only 1, 2 or 4 bytes exist")
    try:
        return int(value).to_bytes(size, "little", signed=signed)
    except OverflowError:
        kind = "signed" if signed else "unsigned"
        raise FieldRangeError(f"{value} does not fit a {size}-byte {kind} field") from None


def unpack_field(data: bytes, signed: bool = False) -> int:
    """The integer in a 1, 2 or 4-byte little-endian field."""
    if len(data) not in (1, 2, 4):
        raise FieldRangeError(f"field size {len(data)}: only 1, 2 or 4 bytes exist")
    return int.from_bytes(data, "little", signed=signed)


# --- CRC-16 (poly 0x8005, init 0, MSB first, no reflection) ------------------------------------
# One implementation: the firmware's (hal/dynamixel/c/dxl.c), through servodyn.hal.dynamixel._dxl.

def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16 of ``data``, continuing from ``crc``."""
    return _dxl.crc16(data if isinstance(data, (bytes, bytearray, memoryview)) else bytes(data), crc)


# --- byte stuffing ---------------------------------------------------------------------------------
# "FF FF FD" cannot overlap itself, so a plain replace is exactly the e-manual's procedure.

def stuff(body: bytes) -> bytes:
    """Insert FD after every FF FF FD of instruction + parameters."""
    return bytes(body).replace(b"\xFF\xFF\xFD", b"\xFF\xFF\xFD\xFD")


def unstuff(body: bytes) -> bytes:
    """Remove the FD that stuffing inserted after every FF FF FD."""
    return bytes(body).replace(b"\xFF\xFF\xFD\xFD", b"\xFF\xFF\xFD")


# --- packets ---------------------------------------------------------------------------------------

def encode_frame(packet_id: int, body: bytes, stuffed: bool = True) -> bytes:
    """A complete frame around ``body`` (INST + parameters), stuffed unless told otherwise."""
    if not (0 <= packet_id <= MAX_ID or packet_id == BROADCAST_ID):
        raise PacketError(f"packet id {packet_id}: 0..252 or 254 (broadcast)")
    if stuffed:
        body = stuff(body)
    frame = HEADER + bytes([packet_id]) + pack_field(len(body) + 2, 2) + body
    return frame + pack_field(crc16(frame), 2)


@dataclass(frozen=True)
class InstructionPacket:
    """A host → servo packet; ``params`` unstuffed."""
    id: int
    instruction: int
    params: bytes = b""

    def encode(self) -> bytes:
        return encode_frame(self.id, bytes([self.instruction]) + self.params)


@dataclass(frozen=True)
class StatusPacket:
    """A servo → host packet (INST 0x55): the whole ERR byte and the unstuffed parameters.

    A status packet from ID 0xFE is a fast sync/bulk read reply, which the e-manual says is never
    stuffed; ``encode`` and the decoder follow that rule.
    """
    id: int
    error: int = 0
    params: bytes = b""

    @property
    def alert(self) -> bool:
        return bool(self.error & ALERT_BIT)

    @property
    def error_number(self) -> int:
        return self.error & ~ALERT_BIT

    def raise_for_error(self) -> None:
        if self.error_number:
            raise StatusError(self.error, self.id)

    def encode(self) -> bytes:
        body = bytes([Instruction.STATUS, self.error]) + self.params
        return encode_frame(self.id, body, stuffed=self.id != BROADCAST_ID)


Packet = InstructionPacket | StatusPacket


def frame_length(head: bytes) -> int:
    """Total bytes of the frame whose first seven bytes are ``head``; PacketError if impossible."""
    if head[:4] != HEADER:
        raise PacketError(f"no header: {head[:4].hex(' ')}")
    if not (head[4] <= MAX_ID or head[4] == BROADCAST_ID):
        raise PacketError(f"packet id {head[4]}: 0..252 or 254 (broadcast)")
    length = head[5] | head[6] << 8
    if length < MIN_LENGTH:
        raise PacketError(f"LEN {length} < {MIN_LENGTH}")
    return FRAME_OVERHEAD + length


def decode_frame(frame: bytes) -> Packet:
    """The packet in one complete frame: check length and CRC over the stuffed bytes, then unstuff."""
    frame = bytes(frame)
    if len(frame) < FRAME_OVERHEAD + MIN_LENGTH or len(frame) != frame_length(frame):
        raise PacketError(f"frame of {len(frame)} bytes does not match its LEN field")
    if crc16(frame[:-2]) != unpack_field(frame[-2:]):
        raise CrcMismatch(f"CRC {frame[-2:].hex(' ')} does not match {crc16(frame[:-2]):04X}")
    packet_id, body = frame[4], frame[7:-2]
    if not (body[0] == Instruction.STATUS and packet_id == BROADCAST_ID):
        body = unstuff(body)
    if body[0] != Instruction.STATUS:
        return InstructionPacket(packet_id, body[0], body[1:])
    if len(body) < 2:
        raise PacketError("status packet without ERR byte")
    return StatusPacket(packet_id, body[1], body[2:])
