"""DYNAMIXEL Protocol 1.0 (AX and MX servos with their 1.0 firmware), the wire format:

    instruction  FF FF ID LEN INST P1..PN CHK      LEN = N + 2
    status       FF FF ID LEN ERR  P1..PN CHK      CHK = ~(ID + LEN + INST/ERR + ΣP) & 0xFF

The same framing and checksum as Feetech's FT-SCS (hal.feetech.protocol, whose frame, checksum
and incremental PacketReader this module uses: one codec for both); Dynamixel 1.0's own are the
instruction set (no SYNC READ: a BULK READ 0x92 on MX, nothing batched on AX) and the status error
byte's bits. Facts: ROBOTIS e-manual `dxl/protocol1` and dynamixel-sdk's Protocol1PacketHandler,
read for ../shared/notes/servos/protocol1.md §1-§2.

The SDK's GroupBulkRead cannot send a 1.0 BULK READ (dynamixel-sdk 3.8.2 to 4.1.0 at least):
its txPacket calls `ph.bulkReadTx(port, param, n*3, False)` with the fast-bulk-read flag that
Protocol1PacketHandler.bulkReadTx(port, param, param_length) does not take -> TypeError. The bus
sends `bulk_read(...)` below itself and takes each servo's status packet in turn.
"""

from __future__ import annotations

from enum import IntEnum

# the framing, and the PING, READ, WRITE and SYNC WRITE packets, are Feetech's: the same bytes, codes
# included (its instruction set is 1.0's with SYNC READ and RESTART added)
from ..feetech.protocol import (BROADCAST_ID, HEADER, Packet, PacketError, PacketReader, checksum, decode, frame, ping,
                                read, sync_write, write)

MAX_ID = 0xFD               # 0..253 address a servo; 0xFE is broadcast
STATUS_OVERHEAD = 6         # FF FF ID LEN ERR .. CHK
__all__ = ["BROADCAST_ID", "HEADER", "MAX_ID", "ErrorBit", "Instruction", "Packet", "PacketError", "PacketReader",
           "bulk_read", "checksum", "decode", "error_faults", "frame", "ping", "read", "status", "sync_write",
           "write"]


class Instruction(IntEnum):
    """The Protocol 1.0 instruction set (dynamixel-sdk robotis_def's 1.0 codes)."""
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    SYNC_WRITE = 0x83
    BULK_READ = 0x92          # MX only: "the bulkread function doesn't work with the AX series"


class ErrorBit(IntEnum):
    """The status packet's error byte (the SDK's ERRBIT_*); bit 7 is never set."""
    INPUT_VOLTAGE = 0x01
    ANGLE_LIMIT = 0x02
    OVERHEATING = 0x04
    RANGE = 0x08
    CHECKSUM = 0x10
    OVERLOAD = 0x20
    INSTRUCTION = 0x40


ERROR_NAMES = {bit.name.lower().replace("_", " "): bit for bit in ErrorBit}   # "input voltage" -> bit
FAULT_BITS = ErrorBit.INPUT_VOLTAGE | ErrorBit.OVERHEATING | ErrorBit.OVERLOAD   # the servo's own faults
# the names the 2.0 simulator gives its hardware faults, as 1.0's bits where 1.0 has one (a 1.0
# servo reports no encoder or electrical-shock fault: it has no such bit)
HARDWARE_FAULTS = {"input voltage": ErrorBit.INPUT_VOLTAGE, "overheating": ErrorBit.OVERHEATING,
                   "overload": ErrorBit.OVERLOAD}


def error_faults(error: int) -> tuple[str, ...]:
    """The names of the bits set in an error byte ("input voltage", "overload", ...)."""
    return tuple(name for name, bit in ERROR_NAMES.items() if error & bit)


def bulk_read(entries) -> bytes:
    """FF FF FE LEN 92 00 [L ID ADDR]... CHK (LEN = 3N + 3): each listed servo answers a status
    packet of its L bytes, in the order listed, each after the one before it. `entries`:
    (id, address, length) per servo, each ID once (a servo named twice answers once)."""
    params = bytearray((0,))
    seen = set()
    for servo_id, address, length in entries:
        if servo_id in seen:
            raise PacketError(f"bulk read: servo {servo_id} is listed twice (it would answer once)")
        seen.add(servo_id)
        params += bytes((length, servo_id, address))
    return frame(BROADCAST_ID, Instruction.BULK_READ, bytes(params))


def bulk_read_entries(params: bytes) -> list[tuple[int, int, int]]:
    """(id, address, length) of a BULK READ's parameters, the first of each ID."""
    out, seen = [], set()
    for k in range(1, len(params) - 2, 3):
        length, servo_id, address = params[k], params[k + 1], params[k + 2]
        if servo_id not in seen:
            seen.add(servo_id)
            out.append((servo_id, address, length))
    return out


def status(servo_id: int, error: int = 0, params: bytes = b"") -> bytes:
    """A servo's status packet (what the simulated servos answer)."""
    return frame(servo_id, error & 0x7F, params)
