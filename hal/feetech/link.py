"""A serial port speaking the Feetech STS protocol for bring-up (hal.feetech.bringup): one servo at a
time or a broadcast, at any rate, with every reply collected and the bytes it cost counted. The
run's backend (backend.FeetechBus) keeps its own port: it knows its servos; this link knows none.

    with Link("/dev/ttyACM0", 1_000_000) as link:
        packets, suspects = link.exchange(protocol.ping(BROADCAST_ID), window=0.03)
        model = link.read_item(1, "model_number")

`exchange` listens after a request until the line has been quiet for `quiet` s once something came
(or for `window` s when nothing did), or until the replies it expects are in: a reply that does not
check leaves the IDs readable in it as suspects (several servos answering at one ID collide).
`patience` (s) lengthens every wait: a simulated bus (`servodyn sim`) on a loaded machine answers
far later than a servo does.
"""

from __future__ import annotations

import os
import select
import time

from ..errors import ServoInitializationError, ServoOperationError
from ..port_access import open_failure
from . import protocol
from .protocol import HEADER, BadFrame, Packet, PacketReader
from .spec import BITS_PER_BYTE, STATUS_OVERHEAD
from .table import ITEM, item_raw, item_value

REPLY_TIMEOUT = 0.05      # s beyond the wire time a servo's reply may take (the SDK's LATENCY_TIMER, 50 ms)
QUIET = 0.01              # s of silence after a reply that ends an open-ended listen on a real adapter


class Link:
    def __init__(self, path: str, baud: int, patience: float = 0.0, retries: int = 2):
        self.path, self.baud, self.patience, self.retries = path, int(baud), patience, retries
        self.serial = None
        self._fd = -1
        self._reader = PacketReader()
        self.transactions = 0      # instructions sent
        self.sent = 0              # bytes sent
        self.received = 0          # bytes received
        self.heard = b""           # the last listen's bytes

    def __enter__(self) -> "Link":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:
        import serial
        try:
            self.serial = serial.Serial(self.path, self.baud, timeout=0)
        except Exception as err:      # pyserial raises its own kinds, most with the OS's errno
            reason = err.errno if isinstance(getattr(err, "errno", None), int) else err
            raise ServoInitializationError(open_failure(self.path, reason)) from None
        self._fd = self.serial.fileno()

    def close(self) -> None:
        if self.serial is not None:
            self.serial.close()
            self.serial = None

    def set_baud(self, baud: int) -> None:
        if int(baud) != self.baud:
            self.baud = int(baud)
            self.serial.baudrate = self.baud

    def wire_time(self, nbytes: int) -> float:
        return nbytes * BITS_PER_BYTE / self.baud

    # ---------------------------------------------------------------- the wire
    def send(self, frame: bytes) -> None:
        self.serial.reset_input_buffer()
        os.write(self._fd, frame)
        self.transactions += 1
        self.sent += len(frame)

    def listen(self, window: float, quiet: float, want: set[int] | None = None,
               patience: float | None = None) -> tuple[list[Packet], bytes]:
        """The status packets that come (the first of each ID) and every byte heard: until `want`'s
        IDs are in, or `quiet` s pass without a byte once one came, or `window` s pass with none
        (each lengthened by `patience`, default the link's)."""
        patience = self.patience if patience is None else patience
        self._reader.expire()
        got: dict[int, Packet] = {}
        heard = bytearray()
        deadline = time.monotonic() + window + patience
        while want is None or not want <= got.keys():
            left = deadline - time.monotonic()
            if heard:                     # replies come back to back: a pause after bytes ends them
                left = min(left, quiet + patience / 10)
            if left <= 0:
                break
            if not select.select([self._fd], [], [], left)[0]:
                break
            data = os.read(self._fd, 4096)
            heard += data
            for event in self._reader.feed(data):
                if isinstance(event, Packet) and event.id not in got:
                    got[event.id] = event
        self.received += len(heard)
        self.heard = bytes(heard)
        return list(got.values()), self.heard

    def exchange(self, frame: bytes, expect: set[int] | None = None, window: float | None = None,
                 quiet: float = QUIET, patience: float | None = None) -> tuple[list[Packet], set[int]]:
        """Send `frame`, listen (`listen`): the packets, and the IDs read in bytes that did not make a
        packet (collided or corrupt replies)."""
        self.send(frame)
        wait = window if window is not None else self.wire_time(len(frame) + STATUS_OVERHEAD) + REPLY_TIMEOUT
        packets, heard = self.listen(wait, quiet, expect, patience)
        return packets, suspects(heard, packets)

    # ---------------------------------------------------------------- one servo
    def ping(self, servo_id: int) -> tuple[Packet | None, bool]:
        """The servo's status packet to a PING (None: none), and whether corrupt replies came."""
        packets, bad = self.exchange(protocol.ping(servo_id), {servo_id})
        reply = next((p for p in packets if p.id == servo_id), None)
        return reply, bool(bad) and reply is None

    def _transact(self, servo_id: int, frame: bytes, size: int, what: str) -> Packet:
        for _ in range(self.retries + 1):
            packets, _ = self.exchange(frame, {servo_id}, self.wire_time(len(frame) + STATUS_OVERHEAD + size)
                                       + REPLY_TIMEOUT)
            reply = next((p for p in packets if p.id == servo_id), None)
            if reply is not None and len(reply.params) == size:
                return reply
        raise ServoOperationError(f"{self.path}: the servo at ID {servo_id} did not answer {what} at {self.baud} baud")

    def read(self, servo_id: int, address: int, length: int) -> tuple[bytes, int]:
        """`length` bytes of its table from `address`, and its status byte."""
        reply = self._transact(servo_id, protocol.read(servo_id, address, length), length,
                               f"a read of {length} bytes at {address}")
        return reply.params, reply.error

    def write(self, servo_id: int, address: int, data: bytes) -> int:
        """Bytes written to its table (Response_Status_Level 1: it answers); its status byte."""
        return self._transact(servo_id, protocol.write(servo_id, address, data), 0, f"a write at {address}").error

    def read_item(self, servo_id: int, name: str) -> int:
        item = ITEM[name]
        data, _ = self.read(servo_id, item.address, item.size)
        return item_value(name, int.from_bytes(data, "little"))

    def write_item(self, servo_id: int, name: str, value: int) -> int:
        item = ITEM[name]
        return self.write(servo_id, item.address, item_raw(name, value).to_bytes(item.size, "little"))

    def broadcast_item(self, name: str, value: int) -> None:
        """A WRITE to every servo at this rate (none answers a broadcast)."""
        item = ITEM[name]
        self.send(protocol.write(protocol.BROADCAST_ID, item.address,
                                 item_raw(name, value).to_bytes(item.size, "little")))

    def restart(self, servo_id: int) -> None:
        """RESTART (0x08): it starts again from its EEPROM; no status packet."""
        self.send(protocol.restart(servo_id))


def suspects(heard: bytes, packets: list[Packet]) -> set[int]:
    """The IDs after a header in `heard` that no good packet carries: replies that collided or broke."""
    good = {p.id for p in packets}
    out, at = set(), heard.find(HEADER)
    while 0 <= at < len(heard) - 2:
        servo_id = heard[at + 2]
        if servo_id != 0xFF and servo_id <= protocol.MAX_ID and servo_id not in good:
            out.add(servo_id)
        at = heard.find(HEADER, at + 2)
    return out


__all__ = ["Link", "BadFrame", "suspects"]
