"""The host link's framing (docs/host-link.md), as the firmware's (firmware/link/link.c) byte for byte.

A frame on the wire is COBS(raw) followed by 00, raw being

    VER SEQ ACK TYPE LEN_L LEN_H | payload (LEN bytes) | CRC_H CRC_L

with the Dynamixel CRC-16 (the one implementation, servodyn.hal.dynamixel.protocol.crc16) of
VER..payload, high byte first, so that the CRC of the whole raw frame is 0. Every 00 on the line
ends a frame: a lost or corrupt byte costs the frame it falls in (and the next one when it is the
delimiter), and the decoder is back in step at the next 00.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..dynamixel.protocol import crc16
from ..errors import ProtocolError

VERSION = 1
HEADER = 6                       # VER SEQ ACK TYPE LEN(2)
CRC = 2
MAX_PAYLOAD = 240                # so a raw frame fits one COBS block of 254
MAX_RAW = HEADER + MAX_PAYLOAD + CRC
MAX_WIRE = MAX_RAW + 2           # + the COBS code byte + the 00 delimiter
OVERHEAD = HEADER + CRC + 2      # wire bytes of a frame besides its payload (payload <= MAX_PAYLOAD)

# the decoder's verdicts (link.h's link_feed_)
FRAME = 1
BAD_CRC = -1
BAD_SHORT = -2
BAD_LENGTH = -3
BAD_TOO_LONG = -4
BAD_VERSION = -5
VERDICTS = {FRAME: "frame", BAD_CRC: "bad CRC", BAD_SHORT: "short", BAD_LENGTH: "bad length",
            BAD_TOO_LONG: "too long", BAD_VERSION: "another version"}


class LinkError(ProtocolError):
    """Bytes or values the host link refuses, or a controller that broke the protocol."""


def cobs_encode(raw: bytes) -> bytes:
    """COBS without the delimiter: blocks of up to 254 non-zero bytes, each after its code byte."""
    out = bytearray()
    block = bytearray()
    for b in raw:
        if b == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
            continue
        block.append(b)
        if len(block) == 254:
            out.append(0xFF)
            out += block
            block.clear()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def encode(seq: int, ack: int, type_: int, payload: bytes = b"", version: int = VERSION) -> bytes:
    """One frame, COBS-encoded and ended by 00. `version` other than VERSION is for tests."""
    if len(payload) > MAX_PAYLOAD:
        raise LinkError(f"host link: a payload of {len(payload)} bytes is over the frame's {MAX_PAYLOAD}")
    raw = bytes((version, seq & 0xFF, ack & 0xFF, type_, len(payload) & 0xFF, len(payload) >> 8)) + payload
    crc = crc16(raw)
    return cobs_encode(raw + bytes((crc >> 8, crc & 0xFF))) + b"\x00"


@dataclass(frozen=True)
class Frame:
    """What the decoder made of the bytes up to a 00: a verdict, and the fields of a frame whose
    CRC was good (verdict FRAME, or BAD_VERSION)."""
    verdict: int
    version: int = 0
    seq: int = 0
    ack: int = 0
    type: int = 0
    payload: bytes = b""


def _cobs_decode(run: bytes) -> tuple[bytearray, bool]:
    """The raw bytes of a run between delimiters (at most MAX_RAW + 1 of them: more is too long),
    and whether its last block was whole."""
    raw = bytearray()
    at, code = 0, 0
    while at < len(run):
        if code and code != 0xFF:
            raw.append(0)
        code = run[at]
        block = run[at + 1:at + code]
        raw += block
        at += code
        if len(raw) > MAX_RAW:
            return raw, True
    return raw, at == len(run)


def _verdict(run: bytes) -> Frame:
    raw, whole = _cobs_decode(run)
    if len(raw) > MAX_RAW:
        return Frame(BAD_TOO_LONG)
    if not whole or len(raw) < HEADER + CRC:
        return Frame(BAD_SHORT)
    if crc16(raw) != 0:
        return Frame(BAD_CRC)
    version, seq, ack, type_ = raw[0], raw[1], raw[2], raw[3]
    length = raw[4] | raw[5] << 8
    payload = bytes(raw[HEADER:-CRC])
    if version != VERSION:
        return Frame(BAD_VERSION, version, seq, ack, type_, payload)
    if length != len(payload):
        return Frame(BAD_LENGTH)
    return Frame(FRAME, version, seq, ack, type_, payload)


class Decoder:
    """The streaming decoder: bytes in any pieces, a Frame out for every run ended by a 00 (an
    empty run, 00 00, is nothing), with the verdicts of firmware/link's link_decoder_feed."""

    def __init__(self):
        self._run = bytearray()
        self._dropping = False
        self.counts = {v: 0 for v in VERDICTS}

    def reset(self) -> None:
        self._run.clear()
        self._dropping = False

    def feed(self, data: bytes) -> list[Frame]:
        out = []
        start = 0
        while True:
            end = data.find(0, start)
            piece = data[start:] if end < 0 else data[start:end]
            if not self._dropping:
                self._run += piece
                if len(self._run) > MAX_WIRE:      # past any frame's COBS: too long however it decodes
                    self._dropping = True
                    self._run.clear()
            if end < 0:
                return out
            if self._dropping or self._run:
                frame = Frame(BAD_TOO_LONG) if self._dropping else _verdict(bytes(self._run))
                self.counts[frame.verdict] += 1
                out.append(frame)
            self.reset()
            start = end + 1
