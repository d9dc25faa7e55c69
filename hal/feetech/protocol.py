"""The Feetech STS/SMS wire format (FT-SCS protocol, framed as Dynamixel Protocol 1.0):

    instruction  FF FF ID LEN INST P1..PN CHK      LEN = N + 2
    status       FF FF ID LEN ERR  P1..PN CHK      CHK = ~(ID + LEN + INST/ERR + ΣP) & 0xFF

The instructions servodyn sends (PING, READ, WRITE, REG WRITE, ACTION, SYNC WRITE and the STS
SYNC READ 0x82, which Dynamixel 1.0 has not), the status packet, the STS sign-magnitude fields
(each register has its own sign bit: hal/feetech/table.py) and an incremental reader that finds
packets in bytes that come in any chunks, with garbage between them. Values are little-endian
(STS/SMS: the END byte at address 2 is 0). Facts: the Feetech SDK (scservo_sdk) and its wiki's
"Servo SCS Communication Protocol", both read for ../shared/notes/servos/feetech.md."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from ..errors import ProtocolError

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
MAX_ID = 0xFD              # 0..253 address a servo; 0xFE is broadcast
SCAN_MAX_ID = 0xFC         # the SDK scans 0..252
MAX_PARAMS = 250           # LEN is one byte: LEN = params + 2 <= 252 keeps it clear of 0xFF


class Instruction(IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    RECOVERY = 0x06          # every parameter but the ID back to the factory's
    RESTART = 0x08           # the servo restarts (as at power-up); no status packet
    RESET = 0x0A
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83


class StatusBit(IntEnum):
    """The status packet's error byte (and Status(65), Unloading/LED alarm conditions 19, 20)."""
    VOLTAGE = 0x01
    ENCODER = 0x02
    TEMPERATURE = 0x04
    CURRENT = 0x08
    OVERLOAD = 0x20


STATUS_FAULTS = {bit.name.lower(): bit for bit in StatusBit}     # "overload" -> bit


def status_faults(status: int) -> tuple[str, ...]:
    """The names of the bits set in an error byte ("voltage", "overload", ...)."""
    return tuple(name for name, bit in STATUS_FAULTS.items() if status & bit)


class PacketError(ProtocolError):
    """A frame the codec cannot take (a bad checksum, a length that does not fit, a wrong value)."""


def checksum(body: bytes) -> int:
    """~(ID + LEN + INST + ΣP) & 0xFF over the bytes after the header."""
    return ~sum(body) & 0xFF


def frame(packet_id: int, code: int, params: bytes = b"") -> bytes:
    """One packet: header, ID, LEN, instruction (or error byte), parameters, checksum."""
    if not 0 <= packet_id <= BROADCAST_ID:
        raise PacketError(f"packet ID {packet_id} is outside 0..{BROADCAST_ID}")
    if len(params) > MAX_PARAMS:
        raise PacketError(f"{len(params)} parameter bytes: a packet carries at most {MAX_PARAMS}")
    body = bytes((packet_id, len(params) + 2, code)) + bytes(params)
    return HEADER + body + bytes((checksum(body),))


# ----------------------------------------------------------------------------- sign-magnitude

def encode_sign_magnitude(value: int, sign_bit: int) -> int:
    """A register's raw value for `value`: its magnitude below `sign_bit`, that bit set when it is
    negative (the SDK's scs_toscs). PacketError if the magnitude does not fit below the bit."""
    value = int(value)
    if abs(value) >= 1 << sign_bit:
        raise PacketError(f"{value} does not fit a sign-magnitude field with its sign in bit {sign_bit} "
                          f"(magnitude at most {(1 << sign_bit) - 1})")
    return -value | 1 << sign_bit if value < 0 else value


def decode_sign_magnitude(raw: int, sign_bit: int) -> int:
    """The value of a register's raw sign-magnitude `raw` (the SDK's scs_tohost); bits above the
    sign are not the value's and are dropped."""
    magnitude = raw & ((1 << sign_bit) - 1)
    return -magnitude if raw & (1 << sign_bit) else magnitude


# ----------------------------------------------------------------------------- instructions

def ping(servo_id: int) -> bytes:
    return frame(servo_id, Instruction.PING)


def read(servo_id: int, address: int, length: int) -> bytes:
    return frame(servo_id, Instruction.READ, bytes((address, length)))


def write(servo_id: int, address: int, data: bytes) -> bytes:
    return frame(servo_id, Instruction.WRITE, bytes((address,)) + bytes(data))


def reg_write(servo_id: int, address: int, data: bytes) -> bytes:
    return frame(servo_id, Instruction.REG_WRITE, bytes((address,)) + bytes(data))


def restart(servo_id: int) -> bytes:
    """RESTART 0x08: the servo starts again from its EEPROM, as at power-up, and sends no status."""
    return frame(servo_id, Instruction.RESTART)


def action(servo_id: int = BROADCAST_ID) -> bytes:
    return frame(servo_id, Instruction.ACTION)


def sync_write(address: int, length: int, data_by_id: dict[int, bytes]) -> bytes:
    """FF FF FE LEN 83 ADDR L ID1 D1.. ID2 D2.. CHK: no servo answers."""
    params = bytearray((address, length))
    for servo_id, data in data_by_id.items():
        if len(data) != length:
            raise PacketError(f"sync write: servo {servo_id}'s data is {len(data)} bytes, not {length}")
        params += bytes((servo_id,)) + bytes(data)
    return frame(BROADCAST_ID, Instruction.SYNC_WRITE, bytes(params))


def sync_read(address: int, length: int, ids) -> bytes:
    """FF FF FE LEN 82 ADDR L ID1 ID2 .. CHK: each servo answers a status packet of `length`
    bytes, in the order of the IDs."""
    return frame(BROADCAST_ID, Instruction.SYNC_READ, bytes((address, length)) + bytes(ids))


def status(servo_id: int, error: int = 0, params: bytes = b"") -> bytes:
    """A servo's status packet (what the simulated servos answer)."""
    return frame(servo_id, error, params)


@dataclass(frozen=True)
class Packet:
    """One decoded frame: an instruction packet (code = the instruction) or a status packet
    (code = the error byte); which one is the caller's to know, as on the wire."""
    id: int
    code: int
    params: bytes

    @property
    def error(self) -> int:
        return self.code

    def encode(self) -> bytes:
        return frame(self.id, self.code, self.params)


def decode(data: bytes) -> Packet:
    """Exactly one frame, checked; PacketError otherwise."""
    events = PacketReader().feed(bytes(data))
    if len(events) != 1 or not isinstance(events[0], Packet):
        raise PacketError(f"not one whole packet: {bytes(data).hex(' ')}")
    return events[0]


@dataclass(frozen=True)
class BadFrame:
    """Bytes the reader dropped: outside any frame ("garbage") or a frame whose checksum failed
    ("checksum")."""
    fault: str
    raw: bytes


class PacketReader:
    """Feed it bytes in any chunks; it returns the packets (and BadFrame events) they complete.
    After garbage or a bad checksum it searches again from the next byte, so a packet that begins
    inside a broken one is still found. `expire()` drops an incomplete frame (a byte timeout)."""

    def __init__(self):
        self._buffer = bytearray()

    @property
    def pending(self) -> int:
        return len(self._buffer)

    def expire(self) -> list[BadFrame]:
        dropped, self._buffer = bytes(self._buffer), bytearray()
        return [BadFrame("truncated", dropped)] if dropped else []

    def feed(self, data: bytes) -> list:
        self._buffer += data
        events: list = []
        buf = self._buffer
        while True:
            start = buf.find(HEADER)
            if start < 0:                      # keep a last FF: it may begin a header
                keep = 1 if buf.endswith(b"\xff") else 0
                if len(buf) > keep:
                    events.append(BadFrame("garbage", bytes(buf[:len(buf) - keep])))
                    del buf[:len(buf) - keep]
                break
            # FF FF FF ...: the header is the last two FFs before a byte that is not FF
            while start + 2 < len(buf) and buf[start + 2] == 0xFF:
                start += 1
            if start:
                events.append(BadFrame("garbage", bytes(buf[:start])))
                del buf[:start]
            if len(buf) < 4:
                break
            length = buf[3]
            if length < 2 or buf[2] > BROADCAST_ID:
                events.append(BadFrame("garbage", bytes(buf[:2])))
                del buf[:2]
                continue
            end = 4 + length
            if len(buf) < end:
                break
            body = bytes(buf[2:end - 1])
            if checksum(body) != buf[end - 1]:
                events.append(BadFrame("checksum", bytes(buf[:2])))
                del buf[:2]                    # search again inside it
                continue
            events.append(Packet(body[0], body[2], body[3:]))
            del buf[:end]
        return events
