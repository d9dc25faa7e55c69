"""The serial link bring-up speaks Dynamixel Protocol 2.0 on: the port opened with pyserial at
one rate, servodyn's own codec (hal.dynamixel.protocol / reader) on the bytes, waits in select().
Unlike the SDK's transactions, a wait ends when the line has been quiet long enough for the rate and
the adapter, so a scan of every rate over the whole ID range takes a fraction of a second instead of
Wizard's minutes, and a corrupt reply (two servos answering at once) is seen as corrupt, not as
silence. The operations over it are hal.dynamixel.bringup.

    with Link("/dev/ttyUSB0", 57600) as link:
        reply, bad = link.ping(1)
"""

from __future__ import annotations

import errno
import os
import select
import time
from collections.abc import Callable

from ..errors import ServoInitializationError, ServoOperationError
from ..port_access import claim_port, open_failure
from ..ports import is_pseudo_terminal
from . import instructions
from .control_table import BAUD_RATES, ITEMS, TABLE_SIZE
from .protocol import BROADCAST_ID, InstructionPacket, StatusPacket, pack_field, unpack_field
from .reader import BadFrame, PacketReader
from .spec import wire_seconds

FACTORY_ID, FACTORY_BAUD = ITEMS["id"].default, BAUD_RATES[ITEMS["baud_rate"].default]
ADAPTER_LATENCY = 0.020    # s: a USB adapter holds bytes up to its latency timer (16 ms by default)
STATUS_BYTES = 14          # a ping's status packet: header 4, ID, LEN 2, INST, ERR, model 2, firmware, CRC 2


def quiet_gap(baud: int) -> float:
    """How long the line must stay quiet after a reply before no more will come: the adapter's
    latency plus three status packets' time at the rate."""
    return ADAPTER_LATENCY + 3 * wire_seconds(STATUS_BYTES, baud)


# ---------------------------------------------------------------------------- the link

class Link:
    """A serial port at one baud rate with servodyn's Protocol 2.0 codec. `open_port` (tests,
    or hal.ports's lock) is how the port is opened: path, baud -> a pyserial Serial. `patience`:
    s a transaction with one servo waits for its first byte, when longer than the wire's (a
    simulated bus on a loaded machine; hal.ports.PTY_REPLY_TIMEOUT); a broadcast keeps the wire's."""

    def __init__(self, path: str, baud: int = FACTORY_BAUD, *, open_port: Callable | None = None,
                 patience: float = 0.0):
        self.path, self.baud, self.patience = path, baud, patience
        self._open_port = open_port or _open_serial
        self.serial = None

    def __enter__(self) -> "Link":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:
        if self.serial is None:
            self.serial = self._open_port(self.path, self.baud)

    def close(self) -> None:
        if self.serial is not None:
            try:
                self.serial.close()
            finally:
                self.serial = None

    def set_baud(self, baud: int) -> None:
        if baud != self.baud:
            self.serial.baudrate = baud
            self.baud = baud
        self.drain(0.0)

    def drain(self, quiet: float = 0.005) -> int:
        """Drop what arrives until the line is quiet for `quiet` s; the bytes dropped."""
        dropped = 0
        fd = self.serial.fileno()
        while select.select([fd], [], [], quiet)[0]:
            chunk = _read(fd)
            dropped += len(chunk)
        return dropped

    def send(self, packet: InstructionPacket) -> None:
        frame = packet.encode()
        fd = self.serial.fileno()
        sent = 0
        while sent < len(frame):
            select.select([], [fd], [], 0.1)
            sent += os.write(fd, frame[sent:])

    def exchange(self, packet: InstructionPacket, *, expect: int | None = 1,
                 first: float | None = None) -> tuple[list[StatusPacket], list[BadFrame]]:
        """Send `packet`, collect the status packets and bad frames that come back. Waits `first`
        s for a first byte (default: the adapter's latency plus the request's and a reply's wire
        time), then until `expect` packets came or the line is quiet for `quiet_gap`."""
        self.drain(0.0)
        self.send(packet)
        request = len(packet.encode())
        wait = first if first is not None else ADAPTER_LATENCY + wire_seconds(request + STATUS_BYTES, self.baud) + 0.01
        if first is None and expect is not None and packet.id != BROADCAST_ID:
            wait = max(wait, self.patience)
        gap = quiet_gap(self.baud)
        reader = PacketReader(None)
        packets: list[StatusPacket] = []
        bad: list[BadFrame] = []
        fd = self.serial.fileno()
        deadline = time.monotonic() + wait
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                break
            chunk = _read(fd)
            for event in reader.feed(chunk):
                if isinstance(event, StatusPacket):
                    packets.append(event)
                elif isinstance(event, BadFrame):
                    bad.append(event)
            if expect is not None and len(packets) >= expect and not reader.pending:
                break
            deadline = time.monotonic() + gap
        bad += reader.expire()
        return packets, bad

    # --- one servo ----------------------------------------------------------------------------
    def ping(self, servo_id: int) -> tuple[StatusPacket | None, list[BadFrame]]:
        packets, bad = self.exchange(instructions.ping(servo_id))
        return next((p for p in packets if p.id == servo_id), None), bad

    def read_table(self, servo_id: int, start: int = 0, length: int = TABLE_SIZE) -> bytes:
        """Bytes start..start+length of a servo's control table in one READ."""
        packets, bad = self.exchange(instructions.read(servo_id, start, length))
        reply = next((p for p in packets if p.id == servo_id), None)
        if reply is None:
            raise ServoOperationError(_silence(servo_id, self, bad, "a read"))
        if reply.error_number:
            raise ServoOperationError(f"id {servo_id} refused a read of {length} bytes at {start} "
                                      f"(error {reply.error_number})")
        if len(reply.params) != length:
            raise ServoOperationError(f"id {servo_id}: a read of {length} bytes returned {len(reply.params)}")
        return reply.params

    def read(self, servo_id: int, name: str) -> int:
        item = ITEMS[name]
        return unpack_field(self.read_table(servo_id, item.address, item.size), item.signed)

    def write(self, servo_id: int, name: str, value: int, *, answered: bool = True) -> None:
        """Write one item; with `answered` wait for the status and raise on an error byte."""
        item = ITEMS[name]
        packet = instructions.write(servo_id, item.address, pack_field(value, item.size, item.signed))
        if not answered or servo_id == BROADCAST_ID:
            self.drain(0.0)
            self.send(packet)
            return
        packets, bad = self.exchange(packet)
        reply = next((p for p in packets if p.id == servo_id), None)
        if reply is None:
            raise ServoOperationError(_silence(servo_id, self, bad, f"the write of {name}"))
        if reply.error_number:
            raise ServoOperationError(f"id {servo_id} refused {name} = {value} (error {reply.error_number}: "
                                      f"{_ERRORS.get(reply.error_number, 'unknown')})")

    def reboot(self, servo_id: int) -> bool:
        """REBOOT; True when the servo acknowledged it."""
        packets, _ = self.exchange(instructions.reboot(servo_id))
        return any(p.id == servo_id and not p.error_number for p in packets)


def _read(fd: int) -> bytes:
    """What a port that select() found readable holds. Nothing at all is a hang-up (the adapter
    unplugged, the simulator's end closed): the OS's EIO, as a lost port says elsewhere."""
    chunk = os.read(fd, 4096)
    if not chunk:
        raise OSError(errno.EIO, os.strerror(errno.EIO))
    return chunk


_ERRORS = {1: "result fail", 2: "instruction error", 3: "CRC error", 4: "data range error",
           5: "data length error", 6: "data limit error", 7: "access error (EEPROM needs torque off)"}


def _silence(servo_id: int, link: Link, bad: list, what: str) -> str:
    if bad:
        return f"id {servo_id} answered {what} with a corrupt packet at {link.baud} baud"
    return f"id {servo_id} did not answer {what} at {link.baud} baud"


def _open_serial(path: str, baud: int):
    """pyserial's port; on a real adapter ours alone and its latency timer asked down (hal.ports)."""
    import serial
    try:
        port = serial.Serial(path, baud, timeout=0, write_timeout=0.5)
    except (serial.SerialException, OSError, ValueError) as err:
        reason = err.errno if isinstance(getattr(err, "errno", None), int) else (getattr(err, "strerror", None) or err)
        raise ServoInitializationError(open_failure(path, reason)) from None
    if not is_pseudo_terminal(path):
        try:
            claim_port(port.fileno(), path, realtime=False)
        except ServoInitializationError:
            port.close()
            raise
    return port
