"""Faults of the wire between the simulated servos and the host, for the fault-injection soak
(servodyn.tools.soak) and the tests: from the moment one is injected, every reply the simulated
bus puts on the wire goes through it.

    flipped_byte    one bit of one byte of each reply inverted (its CRC no longer matches)
    garbage         each reply replaced by a burst of random bytes of its length and more
    delayed_reply   each fast read reply held back for `delay` s, past the host's reply timeout
                    (the chain waits for a slow servo; pings and writes are answered at once)
    wrong_id        each reply carries another servo's ID (frames and CRCs otherwise valid)
    stall           the whole bus paused for `delay` s, once (no reply, no plant time)

They act on bytes only: the servos' registers and the plant are untouched, as on a real bus
whose cable, transceiver or adapter fails. On a Feetech STS bus (`protocol="feetech"`) a read reply
is any status packet that carries data (a READ's or a SYNC READ's), and `wrong_id` re-frames each
status packet under the next ID with a valid checksum."""

from __future__ import annotations

import random
import time

from servodyn.hal.dynamixel import BROADCAST_ID, FastReadBlock, PacketError, StatusPacket, decode_frame
from servodyn.hal.dynamixel.instructions import FAST_BLOCKS_START, encode_fast_reply
from servodyn.hal.dynamixel.protocol import FRAME_OVERHEAD, frame_length
from servodyn.hal.can.frames import CAN_ERR_BUSOFF, CAN_ERR_PROT
from servodyn.hal.feetech import protocol as sts

WIRE_FAULTS = ("flipped_byte", "garbage", "delayed_reply", "wrong_id", "stall")
# s the simulator pauses for a stall, and a delayed reply waits: past the patience a swing gives the
# simulated bus (hal/ports.py's PTY_REPLY_TIMEOUT, 1 s for Dynamixel; tests/test_soak.py checks),
# or the host rightly rides through them (a 0.3 s pause did, once that patience grew from 0.25 s)
STALL = 1.5
DELAY = 1.5
STS_BARE_STATUS = 6      # bytes of an STS status packet without data (a PING's or a WRITE's)


class WireFault:
    """One wire fault, applied to every reply from now on (`stall`: once). `nservos` lets a fast
    read reply be cut into its blocks, for `wrong_id`; `seed` makes the bytes reproducible."""

    def __init__(self, kind: str, nservos: int, seed: int = 0, delay: float | None = None,
                 protocol: str = "dynamixel"):
        if kind not in WIRE_FAULTS:
            raise ValueError(f"unknown wire fault {kind!r} (one of {', '.join(WIRE_FAULTS)})")
        self.kind, self.nservos, self.protocol = kind, nservos, protocol
        self.rng = random.Random(seed)
        self.delay = delay if delay is not None else STALL if kind == "stall" else DELAY
        self.stalled = False

    def apply(self, reply: bytes) -> bytes:
        """The bytes the host receives instead of `reply` (the caller holds the bus meanwhile)."""
        if self.kind == "stall":
            if not self.stalled:
                self.stalled = True
                time.sleep(self.delay)
            return reply
        if self.kind == "delayed_reply":
            read = len(reply) > STS_BARE_STATUS if self.protocol == "feetech" else reply[4:5] == bytes([BROADCAST_ID])
            if read:
                time.sleep(self.delay)
            return reply
        if not reply:
            return reply
        if self.kind == "flipped_byte":
            at = self.rng.randrange(len(reply))
            return reply[:at] + bytes([reply[at] ^ (1 << self.rng.randrange(8))]) + reply[at + 1:]
        if self.kind == "garbage":
            return bytes(self.rng.randrange(256) for _ in range(len(reply) + self.rng.randrange(64)))
        if self.protocol == "feetech":
            return b"".join(sts.status((p.id + 1) % sts.BROADCAST_ID, p.error, p.params) if isinstance(p, sts.Packet)
                            else p.raw for p in sts.PacketReader().feed(reply))
        return b"".join(self._other_id(frame) for frame in _frames(reply))

    def _other_id(self, frame: bytes) -> bytes:
        try:
            packet = decode_frame(frame)
        except PacketError:
            return frame
        if not isinstance(packet, StatusPacket):
            return frame
        if packet.id != BROADCAST_ID:
            return StatusPacket((packet.id + 1) % BROADCAST_ID, packet.error, packet.params).encode()
        # a fast read reply: one block (the first) answers under its neighbour's ID
        body = len(frame) - FRAME_OVERHEAD - 1          # LEN counts INST, the blocks and CRC
        size = body // self.nservos - 4 if body % self.nservos == 0 else -1
        if size < 0:
            return frame
        blocks, at = [], FAST_BLOCKS_START
        for _ in range(self.nservos):
            blocks.append(FastReadBlock(frame[at + 1], frame[at], frame[at + 2:at + 2 + size]))
            at += size + 4
        first = blocks[0]
        blocks[0] = FastReadBlock((first.id + 1) % BROADCAST_ID, first.error, first.data)
        return encode_fast_reply(blocks)


def _frames(data: bytes) -> list[bytes]:
    """The simulated bus's reply cut into its frames (it writes whole frames, one after another)."""
    out, at = [], 0
    while at < len(data):
        try:
            n = frame_length(data[at:at + FRAME_OVERHEAD])
        except (PacketError, IndexError):
            n = None
        if not n or at + n > len(data):
            out.append(data[at:])
            break
        out.append(data[at:at + n])
        at += n
    return out


# ---------------------------------------------------------------------------------------------------
# Faults of a simulated CAN bus (sim/can/network.py applies them to one motor's frames). CAN's own CRC
# drops a frame corrupted on the wire and every node sees an error frame; what reaches a host with a
# valid CRC but wrong content comes from a node that misbehaves.
#
#   garbage       each reply of the motor replaced by a frame on its reply id of random length (0-8)
#                 and random bytes (a babbling node: its CRC is valid, its content is not a reply)
#   wrong_id      each reply names another motor (the motor id in byte 0 / Damiao's low nibble, + 1)
#   error_frame   each reply lost to a bit error: the host's controller reports an error frame
#   bus_off       the host's controller goes bus-off once: an error frame (bus-off), and every send
#                 fails for BUS_OFF s until it rejoins the bus (Linux can's restart-ms)

CAN_WIRE_FAULTS = ("garbage", "wrong_id", "error_frame", "bus_off")
# an error frame among a network's answers: a negative arbitration id, minus its error class
# (linux/can/error.h, which socketcan puts in an error frame's id)
BUS_OFF = 0.05                 # s the host's controller stays off the bus


class CanWireFault:
    """One CAN fault on one motor's reply frames, from now on (`bus_off`: once, on the bus)."""

    def __init__(self, kind: str, seed: int = 0):
        if kind not in CAN_WIRE_FAULTS:
            raise ValueError(f"unknown CAN fault {kind!r} (one of {', '.join(CAN_WIRE_FAULTS)})")
        self.kind = kind
        self.rng = random.Random(seed)

    def apply(self, frames: list[tuple[int, bytes]], dialect: str) -> list[tuple[int, bytes]]:
        """The frames the host receives instead of the motor's `frames` [(arbitration id, data)]."""
        out = []
        for arbitration_id, data in frames:
            if self.kind == "garbage":
                out.append((arbitration_id, bytes(self.rng.randrange(256) for _ in range(self.rng.randrange(9)))))
            elif self.kind == "wrong_id":
                if dialect == "damiao":
                    data = bytes([(data[0] & 0xF0) | ((data[0] + 1) & 0x0F)]) + data[1:]
                else:
                    data = bytes([(data[0] + 1) & 0xFF]) + data[1:]
                out.append((arbitration_id, data))
            elif self.kind == "error_frame":
                out.append((-CAN_ERR_PROT, bytes(8)))
            else:
                out.append((arbitration_id, data))
        return out
