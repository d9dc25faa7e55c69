"""Incremental frame reader: bytes in arbitrary chunks → packets and fault events.

It follows the e-manual's reception order: find the header FF FF FD 00 (stuffed data never contains
it), read LEN more bytes, check the CRC over the stuffed bytes, then unstuff. After a bad frame it
drops only the header and searches again, so a good packet that arrived inside the bytes of a
truncated one is still found. It never raises on input and never waits: an incomplete frame stays
buffered until more bytes come, the caller expires it, or the byte-to-byte timeout passes.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from .protocol import FRAME_OVERHEAD, HEADER, CrcMismatch, Packet, PacketError, decode_frame, frame_length

BYTE_TIMEOUT = 1.5e-3          # e-manual: a gap over 1.5 ms between bytes abandons the packet
MAX_FRAME = 1024               # largest frame accepted (the SDK's buffer size)


class Fault(Enum):
    GARBAGE = "garbage"        # bytes outside any frame
    HEADER = "header"          # a header with an impossible ID or LEN
    CRC = "crc"                # a complete frame whose CRC does not match
    TRUNCATED = "truncated"    # an incomplete frame abandoned (timeout or expire())


@dataclass(frozen=True)
class BadFrame:
    """A fault event: what went wrong, the bytes concerned and, when readable, ID and instruction."""
    fault: Fault
    raw: bytes
    id: int | None = None
    instruction: int | None = None


Event = Packet | BadFrame


class PacketReader:
    """Feed it bytes; it returns the packets and fault events completed by them, in order."""

    def __init__(self, byte_timeout: float | None = BYTE_TIMEOUT, max_frame: int = MAX_FRAME):
        self.byte_timeout = byte_timeout
        self.max_frame = max_frame
        self._buffer = bytearray()
        self._last_time: float | None = None
        # by instruction byte, the last chunk that was one whole packet of that instruction
        self._whole: dict[int, tuple[bytes, Packet]] = {}

    @property
    def pending(self) -> int:
        """Bytes held back, waiting for the rest of a frame."""
        return len(self._buffer)

    def feed(self, data: bytes, now: float | None = None) -> list[Event]:
        """Add ``data``. With ``now`` (seconds), a pending frame older than the byte timeout is
        abandoned first, as a servo does."""
        events: list[Event] = []
        if (now is not None and self._last_time is not None and self.byte_timeout is not None
                and self._buffer and now - self._last_time > self.byte_timeout):
            events += self.expire()
        if now is not None:
            self._last_time = now
        if self._buffer:
            self._buffer += data
        else:
            # a chunk that is one whole packet, as the last such chunk of its instruction was (a
            # request repeated every tick): the same packet, not parsed again (packets are immutable)
            whole = self._whole.get(data[7]) if len(data) > 7 else None
            if whole is not None and data == whole[0]:
                events.append(whole[1])
                return events
            self._buffer += data
            if not events:
                while self._step(events):
                    pass
                if not self._buffer and len(events) == 1 and not isinstance(events[0], BadFrame):
                    self._whole[data[7]] = (bytes(data), events[0])
                return events
        while self._step(events):
            pass
        return events

    def expire(self) -> list[Event]:
        """Abandon whatever is buffered."""
        if not self._buffer:
            return []
        raw = bytes(self._buffer)
        self._buffer.clear()
        fault = Fault.TRUNCATED if raw.startswith(HEADER[:len(raw)]) else Fault.GARBAGE
        return [BadFrame(fault, raw, *_id_and_instruction(raw))]

    def _step(self, events: list[Event]) -> bool:
        """Consume one frame or one run of garbage; False when more bytes are needed."""
        buffer = self._buffer
        start = buffer.find(HEADER)
        if start < 0:
            start = len(buffer) - _partial_header(buffer)   # keep what may begin a header
        if start > 0:
            events.append(BadFrame(Fault.GARBAGE, bytes(buffer[:start])))
            del buffer[:start]
            return True
        if len(buffer) < FRAME_OVERHEAD:
            return False
        try:
            size = frame_length(buffer[:FRAME_OVERHEAD])
            if size > self.max_frame:
                raise PacketError(f"frame of {size} bytes > {self.max_frame}")
        except PacketError:
            events.append(BadFrame(Fault.HEADER, bytes(buffer[:FRAME_OVERHEAD]), buffer[4]))
            del buffer[:len(HEADER)]
            return True
        if len(buffer) < size:
            return False
        frame = bytes(buffer[:size])
        try:
            events.append(decode_frame(frame))
        except CrcMismatch:
            events.append(BadFrame(Fault.CRC, frame, frame[4], frame[7]))
            del buffer[:len(HEADER)]       # a real header may start inside this frame
            return True
        except PacketError:                # a status frame too short for its ERR byte
            events.append(BadFrame(Fault.HEADER, frame, frame[4], frame[7]))
        del buffer[:size]
        return True


def _partial_header(buffer: bytearray) -> int:
    """Length of the longest tail of ``buffer`` that is a start of the header."""
    for n in range(min(len(HEADER) - 1, len(buffer)), 0, -1):
        if buffer[-n:] == HEADER[:n]:
            return n
    return 0


def _id_and_instruction(raw: bytes) -> tuple[int | None, int | None]:
    return (raw[4] if len(raw) > 4 else None), (raw[7] if len(raw) > 7 else None)
