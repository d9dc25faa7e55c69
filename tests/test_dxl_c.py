"""The firmware's Dynamixel codec in C (hal/dynamixel/c/dxl.c) against the Python codec: packets
built in C equal the Python encoding byte for byte, the C reader gives the fields the Python
decoder gives (stuffed status packets, instruction echoes, fast read replies from the Python side
and from the simulated bus), and it refuses corrupted frames. The C source is built here with the
system C compiler into a shared library and called through ctypes."""

import ctypes
import random
import shutil
import subprocess
from pathlib import Path

import pytest

from servodyn.hal.dynamixel import (BROADCAST_ID, FastReadBlock, InstructionPacket, PacketError,
                                    PacketReader, StatusPacket, decode_frame, encode_fast_reply,
                                    pack_field, split_fast_reply)
from servodyn.hal.dynamixel import instructions as inst
from servodyn.sim.dynamixel import Servo, DynamixelWire
from servodyn.hal.dynamixel.control_table import VELOCITY_UNIT
from test_dynamixel_protocol import (EMANUAL_FAST_BULK_REPLY, EMANUAL_FAST_SYNC_REPLY,
                                     EMANUAL_INSTRUCTIONS, EMANUAL_STATUS)

CODEC = Path(__file__).resolve().parent.parent / "hal" / "dynamixel" / "c"
BUF = 4096
MORE, PACKET = 0, 1
VALID_IDS = list(range(0xFD)) + [BROADCAST_ID]

# Exposes the reader's layout to Python without mirroring the struct by hand.
SHIM = r"""
#include <stddef.h>
#include "dxl.h"
size_t shim_reader_size(void) { return sizeof(dxl_reader); }
size_t shim_offset(int field) {
  switch (field) {
    case 0: return offsetof(dxl_reader, id);
    case 1: return offsetof(dxl_reader, instruction);
    case 2: return offsetof(dxl_reader, error);
    case 3: return offsetof(dxl_reader, nparam);
    default: return offsetof(dxl_reader, param);
  }
}
size_t shim_block_size(void) { return sizeof(dxl_block); }
size_t shim_max_param(void) { return DXL_MAX_PARAM; }
// All of the reader's state but tail, which only a stuffed frame reads: in a fast reply the fast
// path leaves it 0 while the byte path keeps shifting bytes in, and the next frame clears it.
void shim_state(const dxl_reader* r, uint32_t* out) {
  out[0] = r->state;
  out[1] = r->window;
  out[2] = r->crc;
  out[3] = r->remain;
  out[4] = r->nbody;
  out[5] = r->raw;
  out[6] = r->crc_low;
  out[7] = r->raw ? 0 : r->tail;
}
"""

u8p, u16p, size_t = ctypes.POINTER(ctypes.c_uint8), ctypes.POINTER(ctypes.c_uint16), ctypes.c_size_t
u8, u16 = ctypes.c_uint8, ctypes.c_uint16


class Block(ctypes.Structure):
    _fields_ = [("id", ctypes.c_uint8), ("error", ctypes.c_uint8), ("data", ctypes.c_void_p)]


SIGNATURES = {
    "dxl_crc": (u16, [u16, u8p, size_t]),
    "dxl_packet": (size_t, [u8p, size_t, u8, u8, u8p, size_t]),
    "dxl_ping": (size_t, [u8p, size_t, u8]),
    "dxl_read": (size_t, [u8p, size_t, u8, u16, u16]),
    "dxl_write": (size_t, [u8p, size_t, u8, u16, u8p, u16]),
    "dxl_reboot": (size_t, [u8p, size_t, u8]),
    "dxl_sync_write": (size_t, [u8p, size_t, u16, u16, u8p, size_t, u8p]),
    "dxl_sync_read": (size_t, [u8p, size_t, u16, u16, u8p, size_t]),
    "dxl_fast_sync_read": (size_t, [u8p, size_t, u16, u16, u8p, size_t]),
    "dxl_bulk_read": (size_t, [u8p, size_t, u8p, u16p, u16p, size_t]),
    "dxl_fast_bulk_read": (size_t, [u8p, size_t, u8p, u16p, u16p, size_t]),
    "dxl_reader_reset": (None, [ctypes.c_void_p]),
    "dxl_reader_feed": (ctypes.c_int, [ctypes.c_void_p, u8]),
    "dxl_reader_feed_bytes": (ctypes.c_int, [ctypes.c_void_p, u8p, size_t, ctypes.POINTER(size_t)]),
    "dxl_fast_reply_split": (ctypes.c_int, [ctypes.c_void_p, u16, u8p, size_t, ctypes.POINTER(Block)]),
    "dxl_fast_bulk_reply_split": (ctypes.c_int, [ctypes.c_void_p, u16p, u8p, size_t,
                                                 ctypes.POINTER(Block)]),
    "shim_reader_size": (size_t, []),
    "shim_offset": (size_t, [ctypes.c_int]),
    "shim_block_size": (size_t, []),
    "shim_max_param": (size_t, []),
    "shim_state": (None, [ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint32)]),
}


@pytest.fixture(scope="session")
def dxl(tmp_path_factory):
    """dxl.c built with `cc -shared -fPIC -O2` and loaded; the shim adds the reader's layout."""
    cc = shutil.which("cc")
    if cc is None:
        pytest.fail("no C compiler: `cc` is not on PATH. `make test` installs one "
                    "(scripts/install/install-host-deps.sh), or install gcc and run again.", pytrace=False)
    build = tmp_path_factory.mktemp("dxl_c")
    shim = build / "shim.c"
    shim.write_text(SHIM)
    lib = build / "libdxl.so"
    command = [cc, "-shared", "-fPIC", "-O2", "-std=c11", "-Wall", "-Wextra", "-Werror",
               f"-I{CODEC}", "-o", str(lib), str(CODEC / "dxl.c"), str(shim)]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        pytest.fail(f"building the C codec failed: {' '.join(command)}\n{done.stderr}", pytrace=False)
    so = ctypes.CDLL(str(lib))
    for name, (restype, argtypes) in SIGNATURES.items():
        getattr(so, name).restype = restype
        getattr(so, name).argtypes = argtypes
    assert so.shim_block_size() == ctypes.sizeof(Block), "dxl_block as ctypes sees it"
    return Codec(so)


def _bytes(data) -> ctypes.Array:
    return (ctypes.c_uint8 * max(1, len(data))).from_buffer_copy(bytes(data) or b"\0")


def _words(values) -> ctypes.Array:
    return (ctypes.c_uint16 * max(1, len(values)))(*values)


class Codec:
    """The C functions with Python arguments: each builder returns the frame as bytes."""

    def __init__(self, so):
        self.so = so

    def _build(self, name, *args, cap=BUF) -> bytes:
        out = (ctypes.c_uint8 * max(cap, 1))()
        n = getattr(self.so, name)(out, cap, *args)
        return bytes(out[:n])

    def packet(self, packet_id, instruction, params=b"", cap=BUF):
        return self._build("dxl_packet", packet_id, instruction, _bytes(params), len(params), cap=cap)

    def ping(self, packet_id):
        return self._build("dxl_ping", packet_id)

    def read(self, packet_id, address, size):
        return self._build("dxl_read", packet_id, address, size)

    def write(self, packet_id, address, data):
        return self._build("dxl_write", packet_id, address, _bytes(data), len(data))

    def reboot(self, packet_id):
        return self._build("dxl_reboot", packet_id)

    def sync_write(self, address, size, ids, data, cap=BUF):
        return self._build("dxl_sync_write", address, size, _bytes(ids), len(ids), _bytes(data), cap=cap)

    def sync_read(self, address, size, ids, fast=False):
        name = "dxl_fast_sync_read" if fast else "dxl_sync_read"
        return self._build(name, address, size, _bytes(ids), len(ids))

    def bulk_read(self, requests, fast=False):
        ids, addresses, sizes = zip(*requests)
        name = "dxl_fast_bulk_read" if fast else "dxl_bulk_read"
        return self._build(name, _bytes(ids), _words(addresses), _words(sizes), len(ids))

    def crc(self, data):
        return self.so.dxl_crc(0, _bytes(data), len(data))

    def reader(self):
        return Reader(self.so)


class Reader:
    """A dxl_reader in a ctypes buffer; fields read at the offsets the compiler chose."""

    def __init__(self, so):
        self.so = so
        self.buffer = ctypes.create_string_buffer(so.shim_reader_size())
        self.offset = [so.shim_offset(k) for k in range(5)]
        so.dxl_reader_reset(self.buffer)

    def reset(self):
        self.so.dxl_reader_reset(self.buffer)

    def fields(self):
        raw = self.buffer.raw
        nparam = int.from_bytes(raw[self.offset[3]:self.offset[3] + 2], "little")
        return (raw[self.offset[0]], raw[self.offset[1]], raw[self.offset[2]],
                raw[self.offset[4]:self.offset[4] + nparam])

    def feed(self, data):
        """Byte by byte; every result other than DXL_MORE, a packet as (id, INST, ERR, params)."""
        events = []
        for byte in data:
            code = self.so.dxl_reader_feed(self.buffer, byte)
            if code == PACKET:
                events.append(self.fields())
            elif code != MORE:
                events.append(code)
        return events

    def packets(self, data):
        return [e for e in self.feed(data) if isinstance(e, tuple)]

    def feed_byte(self, byte) -> int:
        return self.so.dxl_reader_feed(self.buffer, byte)

    def feed_bytes(self, data) -> tuple[int, int]:
        """One dxl_reader_feed_bytes call: (result, used)."""
        used = ctypes.c_size_t(0xDEAD)
        code = self.so.dxl_reader_feed_bytes(self.buffer, _bytes(data), len(data), ctypes.byref(used))
        return code, used.value

    def state(self) -> tuple:
        """The public fields and the rest of the state (all but tail, see shim_state)."""
        out = (ctypes.c_uint32 * 8)()
        self.so.shim_state(self.buffer, out)
        return self.fields() + tuple(out)

    def split(self, size, ids, sizes=None):
        """dxl_fast_reply_split (or the bulk one with sizes): (result, [(id, error, data)])."""
        blocks = (Block * max(1, len(ids)))()
        if sizes is None:
            got = self.so.dxl_fast_reply_split(self.buffer, size, _bytes(ids), len(ids), blocks)
        else:
            got = self.so.dxl_fast_bulk_reply_split(self.buffer, _words(sizes), _bytes(ids), len(ids),
                                                    blocks)
        lengths = sizes or [size] * len(ids)
        return got, [(b.id, b.error, ctypes.string_at(b.data, n)) for b, n in zip(blocks[:got], lengths)]


def fields_of(packet) -> tuple:
    """A Python packet as the C reader reports it."""
    if isinstance(packet, StatusPacket):
        return (packet.id, 0x55, packet.error, packet.params)
    return (packet.id, packet.instruction, 0, packet.params)


def python_packets(data) -> list[tuple]:
    return [fields_of(e) for e in PacketReader(byte_timeout=None).feed(data)
            if isinstance(e, (StatusPacket, InstructionPacket))]


# --- random material that needs stuffing ---------------------------------------------------------

def stuffable(rng: random.Random, n: int) -> bytes:
    """Bytes that often contain FF FF FD (and whole headers FF FF FD 00)."""
    return bytes(rng.choice(b"\xFF\xFF\xFD\x00") if rng.random() < 0.75 else rng.randrange(256)
                 for _ in range(n))


def word(rng: random.Random) -> int:
    return int.from_bytes(stuffable(rng, 2), "little")


def status_packet(rng: random.Random, packet_id=None) -> StatusPacket:
    packet_id = rng.choice(VALID_IDS[:-1]) if packet_id is None else packet_id
    return StatusPacket(packet_id, stuffable(rng, 1)[0], stuffable(rng, rng.randrange(40)))


def fast_reply(rng: random.Random, count=None, size=None) -> tuple[bytes, list[FastReadBlock]]:
    count = count or rng.randrange(1, 6)
    ids = rng.sample(VALID_IDS[:-1], count)
    size = size or rng.choice([1, 2, 4, 6, 10])
    blocks = [FastReadBlock(i, stuffable(rng, 1)[0], stuffable(rng, size)) for i in ids]
    return encode_fast_reply(blocks), blocks


def garbage(rng: random.Random, alphabet=b"\x00\x01\xFD\x55\x80") -> bytes:
    return bytes(rng.choice(alphabet) for _ in range(rng.randrange(12)))


# --- e-manual vectors -------------------------------------------------------------------------------

@pytest.mark.parametrize("name, packet, expected", EMANUAL_INSTRUCTIONS, ids=[e[0] for e in EMANUAL_INSTRUCTIONS])
def test_emanual_instruction_packets(dxl, name, packet, expected):
    assert dxl.packet(packet.id, packet.instruction, packet.params) == bytes.fromhex(expected), \
        f"{name}: dxl_packet gives the e-manual's bytes"


def test_emanual_packets_from_the_builders(dxl):
    frames = dict((name, bytes.fromhex(expected)) for name, _, expected in EMANUAL_INSTRUCTIONS)
    assert dxl.ping(1) == frames["ping ID 1"]
    assert dxl.ping(BROADCAST_ID) == frames["broadcast ping"]
    assert dxl.read(1, 132, 4) == frames["read Present Position"]
    assert dxl.write(1, 116, pack_field(512, 4)) == frames["write Goal Position 512"]
    assert dxl.reboot(1) == frames["reboot"]
    assert dxl.sync_read(132, 4, [1, 2]) == frames["sync read ID 1, 2"]
    assert dxl.sync_write(116, 4, [1, 2], pack_field(150, 4) + pack_field(170, 4)) == \
        frames["sync write 150, 170"]
    assert dxl.sync_read(132, 4, [3, 7, 4], fast=True) == frames["fast sync read ID 3, 7, 4"]
    assert dxl.bulk_read([(1, 144, 2), (2, 146, 1)]) == frames["bulk read"]
    assert dxl.bulk_read([(3, 132, 4), (7, 124, 2), (4, 146, 1)], fast=True) == frames["fast bulk read"]


@pytest.mark.parametrize("packet, expected", EMANUAL_STATUS, ids=[e[1][:20] for e in EMANUAL_STATUS])
def test_emanual_status_packets(dxl, packet, expected):
    frame = bytes.fromhex(expected)
    assert dxl.packet(packet.id, 0x55, bytes([packet.error]) + packet.params) == frame, "same bytes"
    assert dxl.reader().feed(frame) == [fields_of(packet)], "read back to the same fields"


@pytest.mark.parametrize("reply, sizes", [(EMANUAL_FAST_SYNC_REPLY, [4, 4, 4]), (EMANUAL_FAST_BULK_REPLY, [4, 2, 1])],
                         ids=["fast sync", "fast bulk"])
def test_emanual_fast_replies(dxl, reply, sizes):
    frame = bytes.fromhex(reply)
    reader = dxl.reader()
    assert len(reader.packets(frame)) == 1, "one good packet"
    blocks = split_fast_reply(decode_frame(frame), sizes)
    ids = [b.id for b in blocks]
    assert reader.split(0, ids, sizes) == (3, [(b.id, b.error, b.data) for b in blocks]), \
        "the C split gives the Python split's blocks"


# --- builders ----------------------------------------------------------------------------------------

def test_builders_equal_the_python_encoding(dxl):
    rng = random.Random(20240611)
    stuffed = 0
    for trial in range(400):
        packet_id = rng.choice(VALID_IDS)
        address, size = word(rng), rng.randrange(1, 9)
        data = stuffable(rng, size)
        ids = rng.sample(VALID_IDS[:-1], rng.randrange(1, 8))
        block_data = stuffable(rng, size * len(ids))
        requests = [(i, word(rng), word(rng)) for i in ids]
        params = stuffable(rng, rng.randrange(60))
        instruction = rng.randrange(256)
        read_size = word(rng) if trial % 2 else size
        twin = (StatusPacket(packet_id, params[0], params[1:]) if instruction == 0x55 and params
                else InstructionPacket(packet_id, instruction, params))
        pairs = [
            (dxl.ping(packet_id), inst.ping(packet_id)),
            (dxl.read(packet_id, address, read_size), inst.read(packet_id, address, read_size)),
            (dxl.write(packet_id, address, data), inst.write(packet_id, address, data)),
            (dxl.reboot(packet_id), inst.reboot(packet_id)),
            (dxl.sync_write(address, size, ids, block_data),
             inst.sync_write(address, size, {i: block_data[k * size:(k + 1) * size] for k, i in enumerate(ids)})),
            (dxl.sync_read(address, size, ids), inst.sync_read(address, size, ids)),
            (dxl.sync_read(address, size, ids, fast=True), inst.fast_sync_read(address, size, ids)),
            (dxl.bulk_read(requests), inst.bulk_read(requests)),
            (dxl.bulk_read(requests, fast=True), inst.fast_bulk_read(requests)),
            (dxl.packet(packet_id, instruction, params), twin),
        ]
        for k, (c_bytes, packet) in enumerate(pairs):
            expected = packet.encode()
            assert c_bytes == expected, f"trial {trial}, builder {k}: C {c_bytes.hex(' ')} != Python {expected.hex(' ')}"
            stuffed += b"\xFF\xFF\xFD\xFD" in c_bytes[7:-2]
    assert stuffed > 400, "hundreds of the 4000 packets needed stuffing"


def test_status_from_broadcast_is_unstuffed_like_python(dxl):
    rng = random.Random(5)
    for _ in range(200):
        packet = status_packet(rng, BROADCAST_ID)
        assert dxl.packet(BROADCAST_ID, 0x55, bytes([packet.error]) + packet.params) == packet.encode(), \
            "a status packet from 0xFE is sent as it is, on both sides"


def test_bad_ids_and_short_buffers_give_zero(dxl):
    for bad in (0xFD, 0xFF):
        with pytest.raises(PacketError):
            inst.ping(bad).encode()
        assert dxl.ping(bad) == b"", f"ID {bad:#x}: Python refuses it, C returns 0"
    frame = dxl.sync_write(116, 4, [1, 2], b"\xFF\xFF\xFD\x00" * 2)
    assert len(frame) == 7 + 1 + 4 + 10 + 2 + 2, "two stuffed bytes"
    for cap in range(len(frame)):
        assert dxl.sync_write(116, 4, [1, 2], b"\xFF\xFF\xFD\x00" * 2, cap=cap) == b"", f"cap {cap}: 0"
    assert dxl.sync_write(116, 4, [1, 2], b"\xFF\xFF\xFD\x00" * 2, cap=len(frame)) == frame, "exact fit"


# --- the reader ------------------------------------------------------------------------------------

def test_reader_gives_the_python_fields(dxl):
    rng = random.Random(11)
    reader = dxl.reader()
    for trial in range(1500):
        kind = trial % 3
        if kind == 0:
            packet = status_packet(rng)
        elif kind == 1:
            # any INST but 0x55, which makes it a status packet (built above)
            instruction = rng.choice([i for i in range(256) if i != 0x55])
            packet = InstructionPacket(rng.choice(VALID_IDS), instruction, stuffable(rng, rng.randrange(30)))
        else:
            frame, _ = fast_reply(rng)
            packet = decode_frame(frame)
        frame = packet.encode() if kind < 2 else frame
        assert reader.feed(garbage(rng) + frame) == [fields_of(decode_frame(frame))], \
            f"trial {trial}: {frame.hex(' ')}"


def test_reader_agrees_with_python_on_streams(dxl):
    rng = random.Random(3)
    for alphabet in (b"\x00\x01\xFD\x55\x80", b"\xFF\xFD\x00\x01\x55"):   # without FF, then with
        for trial in range(40):
            stream, sent = bytearray(), []
            for _ in range(rng.randrange(1, 12)):
                frame = (status_packet(rng).encode() if rng.random() < 0.6
                         else fast_reply(rng)[0] if rng.random() < 0.5
                         else inst.write(rng.choice(VALID_IDS), word(rng), stuffable(rng, 6)).encode())
                stream += garbage(rng, alphabet) + frame
                sent.append(fields_of(decode_frame(frame)))
            found = dxl.reader().packets(stream)
            assert found == python_packets(stream), f"{alphabet.hex()} trial {trial}: same packets as Python"
            if b"\xFF" not in alphabet:
                assert found == sent, f"trial {trial}: every packet sent, in order"


def test_reader_rejects_corrupted_frames(dxl):
    rng = random.Random(17)
    reader = dxl.reader()
    ping = inst.ping(9).encode()
    for trial in range(1500):
        frame = bytearray(status_packet(rng).encode() if trial % 2 else fast_reply(rng)[0])
        at = rng.randrange(len(frame))
        frame[at] ^= 1 << rng.randrange(8)
        events = reader.feed(bytes(frame))
        assert all(not isinstance(e, tuple) for e in events), \
            f"trial {trial}: byte {at} damaged in {frame.hex(' ')}, yet a packet came out"
        assert python_packets(bytes(frame)) == [], "the Python reader refuses it too"
        reader.reset()          # as after the e-manual's 1.5 ms of silence
        assert reader.feed(ping) == [(9, 0x01, 0, b"")], "the next packet is read"


def test_reader_refuses_what_does_not_fit(dxl):
    reader = dxl.reader()
    big = StatusPacket(1, 0, bytes(300)).encode()
    assert reader.feed(big + inst.ping(2).encode()) == [-2, (2, 0x01, 0, b"")], \
        "DXL_TOO_LONG for 300 params (DXL_MAX_PARAM 256), then the next packet"


# --- fast read replies ---------------------------------------------------------------------------

def test_fast_replies_split_like_python(dxl):
    rng = random.Random(23)
    reader = dxl.reader()
    outcomes = set()
    for trial in range(600):
        frame, blocks = fast_reply(rng)
        size = len(blocks[0].data)
        ids = [b.id for b in blocks]
        frame = bytearray(frame)
        if trial % 2:   # damage one byte inside the blocks, then make the packet CRC good again
            at = rng.randrange(8, len(frame) - 2)
            frame[at] ^= 1 << rng.randrange(8)
            frame[-2:] = pack_field(dxl.crc(frame[:-2]), 2)
        packets = reader.packets(bytes(frame))
        assert len(packets) == 1, "the frame itself is good"
        got, c_blocks = reader.split(size, ids)
        try:
            expected = [(b.id, b.error, b.data)
                        for b in split_fast_reply(decode_frame(bytes(frame)), [size] * len(ids))]
        except PacketError:
            expected = None
        # the Python split takes no ids; the C one also checks them, so a damaged last ID (the one
        # a block CRC does not cover) is a refusal here
        if expected is not None and [b[0] for b in expected] != ids:
            expected = None
        if expected is None:
            assert got < len(ids), f"trial {trial}: Python refuses the reply, C names block {got}"
        else:
            assert (got, c_blocks) == (len(ids), expected), f"trial {trial}: same blocks"
        outcomes.add(expected is None)
    assert outcomes == {True, False}, "good and damaged replies both met"


def test_fast_reads_through_the_simulated_bus(dxl):
    """C requests to the simulated servos; C reads their replies, stuffing-prone values included."""
    rng = random.Random(29)
    ids = [3, 1, 7, 2]
    servos = [Servo(servo_id=i) for i in ids]
    bus = DynamixelWire(servos, clock=lambda: 0.0)
    reader = dxl.reader()
    for trial in range(60):
        for servo in servos:
            # Present Current -1 (FF FF) then Present Velocity -3 (FD FF FF FF) when the dice say so
            current = -1 if rng.random() < 0.5 else rng.randrange(-300, 300)
            velocity = -3 if rng.random() < 0.5 else rng.randrange(-200, 200)
            servo.set_present(rng.uniform(-3, 3), velocity * VELOCITY_UNIT,
                              current * servo.model.current_unit)
        truth = {s.id: s.read(126, 10) for s in servos}

        reply = bus.handle(dxl.sync_read(126, 10, ids, fast=True))
        assert len(reader.packets(reply)) == 1, "one reply from 0xFE"
        assert reader.split(10, ids) == (4, [(i, 0, truth[i]) for i in ids]), f"trial {trial}: fast sync read"

        requests = [(3, 126, 2), (1, 128, 4), (7, 132, 4), (2, 140, 8)]   # the last: past the table
        reply = bus.handle(dxl.bulk_read(requests, fast=True))
        assert len(reader.packets(reply)) == 1, "one reply"
        got, blocks = reader.split(0, [r[0] for r in requests], [r[2] for r in requests])
        expected = [(i, 0, truth[i][a - 126:a - 126 + n]) for i, a, n in requests[:3]] + [(2, 7, bytes(8))]
        assert (got, blocks) == (4, expected), "fast bulk read; an access error in the last block"

        replies = reader.packets(bus.handle(dxl.sync_read(126, 10, ids)))
        assert replies == [(i, 0x55, 0, truth[i]) for i in ids], "a plain sync read: one status each"


def test_sync_write_from_c_reaches_the_simulated_servos(dxl):
    servos = [Servo(servo_id=i) for i in (1, 2)]
    bus = DynamixelWire(servos, clock=lambda: 0.0)
    bus.handle(dxl.write(BROADCAST_ID, 64, b"\x01"))
    goals = pack_field(1000, 4) + pack_field(3000, 4)
    assert bus.handle(dxl.sync_write(116, 4, [1, 2], goals)) == b"", "no reply to a sync write"
    assert [s.get("goal_position") for s in servos] == [1000, 3000], "each servo got its goal"


# --- dxl_reader_feed_bytes: the same reader, many bytes a call -----------------------------------

# a whole header, the bytes a fast reply's data may hold that must not start a frame
HEADER_BYTES = b"\xFF\xFF\xFD\x00"
FAST_IDS, FAST_SIZE = [1, 2, 3, 4, 5, 6, 7], 10   # the swing's fast sync read: 7 servos x 10 bytes


def fast_sync_reply(rng: random.Random, count=len(FAST_IDS), header_inside=False) -> bytes:
    """encode_fast_reply of count servos x 10 bytes; with header_inside, some data hold FF FF FD 00."""
    blocks = []
    for k in range(count):
        data = bytearray(stuffable(rng, FAST_SIZE))
        if header_inside and rng.random() < 0.5:
            at = rng.randrange(FAST_SIZE - 3)
            data[at:at + 4] = HEADER_BYTES
        blocks.append(FastReadBlock(FAST_IDS[k % len(FAST_IDS)] + 7 * (k // len(FAST_IDS)),
                                    stuffable(rng, 1)[0] if rng.random() < 0.2 else 0, bytes(data)))
    return encode_fast_reply(blocks)


def stream_piece(rng: random.Random, max_param: int) -> bytes:
    """One piece of a bus stream: good frames of every kind, garbage, cut and corrupted frames."""
    kind = rng.randrange(10)
    if kind == 0:
        return fast_sync_reply(rng)
    if kind == 1:
        return fast_sync_reply(rng, header_inside=True)
    if kind == 2:
        return status_packet(rng).encode()          # params that often need stuffing
    if kind == 3:
        return garbage(rng, rng.choice([b"\x00\x01\xFD\x55\x80", b"\xFF\xFD\x00\x01\x55\xFE"]))
    if kind == 4:   # cut short: a status packet, a fast reply, an instruction echo
        frame = rng.choice([status_packet(rng).encode(), fast_sync_reply(rng, header_inside=True),
                            inst.write(rng.choice(VALID_IDS), word(rng), stuffable(rng, 8)).encode()])
        return frame[:rng.randrange(1, len(frame))]
    if kind == 5:   # the CRC damaged
        frame = bytearray(rng.choice([status_packet(rng).encode(), fast_sync_reply(rng, header_inside=True)]))
        frame[rng.randrange(len(frame) - 2, len(frame))] ^= 1 << rng.randrange(8)
        return bytes(frame)
    if kind == 6:   # any byte damaged, the CRC too or not
        frame = bytearray(rng.choice([status_packet(rng).encode(), fast_sync_reply(rng)]))
        frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
        return bytes(frame)
    if kind == 7:   # a fast reply around DXL_MAX_PARAM: fits, too long for param, too long for LEN
        if rng.random() < 0.5:
            return fast_sync_reply(rng, count=rng.choice([18, 19, 24, 25]), header_inside=True)
        nparam = max_param + rng.choice([-1, 0, 1, 2, 40, 86, 87, 100])
        return StatusPacket(BROADCAST_ID, 0, stuffable(rng, nparam)).encode()
    if kind == 8:
        return inst.fast_sync_read(132, FAST_SIZE, FAST_IDS).encode()   # the request's echo
    return inst.write(rng.choice(VALID_IDS), word(rng), stuffable(rng, rng.randrange(12))).encode()


def random_cuts(rng: random.Random, n: int) -> list[int]:
    """Chunk boundaries 0 = c0 <= c1 <= ... = n: chunks of 0, a few, tens of bytes, or all the rest."""
    cuts = [0]
    while cuts[-1] < n:
        size = rng.choice([0, 1, 1, 2, 3, 5, 8, rng.randrange(1, 40), rng.randrange(1, 200), n])
        cuts.append(min(n, cuts[-1] + size))
    return cuts


def feed_both(dxl, stream: bytes, cuts: list[int]) -> list[tuple]:
    """stream to one reader with dxl_reader_feed a byte at a time, and to another with
    dxl_reader_feed_bytes over the chunks stream[cuts[k]:cuts[k + 1]] (called again on the rest of a
    chunk after a result). Every call's result must be the byte path's at byte at + used - 1, with
    DXL_MORE on all bytes before it, and both readers must then be in the same state.
    Returns the results as (byte index, code, fields)."""
    one, many = dxl.reader(), dxl.reader()
    events = []

    def where(at):
        return f"byte {at} of {len(stream)}, near {stream[max(0, at - 12):at + 12].hex(' ')}"

    for start, end in zip(cuts, cuts[1:]):
        at = start
        while True:
            code, used = many.feed_bytes(stream[at:end])
            assert 0 <= used <= end - at, f"used {used} of a {end - at}-byte chunk at {where(at)}"
            if code == MORE:
                assert used == end - at, f"DXL_MORE after {used} of {end - at} bytes at {where(at)}"
            else:
                assert used >= 1, f"result {code} from no byte at {where(at)}"
            for k in range(at, at + used):
                byte_code = one.feed_byte(stream[k])
                last = k == at + used - 1
                want = code if last else MORE
                assert byte_code == want, (f"{where(k)}: the byte path gives {byte_code}, "
                                           f"feed_bytes {'gives ' + str(code) if last else 'goes past it'}")
            assert many.state() == one.state(), f"the readers differ after {where(at + used)}"
            at += used
            if code == MORE:
                break
            events.append((at - 1, code, many.fields() if code == PACKET else None))
    return events


def test_feed_bytes_equals_feeding_byte_by_byte_on_random_streams(dxl):
    rng = random.Random(20240917)
    max_param = dxl.so.shim_max_param()
    fast_params = len(FAST_IDS) * (FAST_SIZE + 4) - 3
    seen = {code: 0 for code in (PACKET, -1, -2, -3)}
    fast_packets = fast_with_header = 0
    for trial in range(300):
        stream = b"".join(stream_piece(rng, max_param) for _ in range(rng.randrange(1, 14)))
        cuts = random_cuts(rng, len(stream))
        try:
            events = feed_both(dxl, stream, cuts)
        except AssertionError as failure:
            raise AssertionError(f"trial {trial}, chunks {[b - a for a, b in zip(cuts, cuts[1:])]}: "
                                 f"{failure}") from None
        for _, code, fields in events:
            seen[code] += 1
            if fields and fields[:2] == (BROADCAST_ID, 0x55) and len(fields[3]) == fast_params:
                fast_packets += 1
                fast_with_header += HEADER_BYTES in fields[3]
    assert min(seen.values()) >= 20, f"every result met often: {seen}"
    assert fast_packets >= 150 and fast_with_header >= 40, \
        f"{fast_packets} whole 7 x 10 fast replies, {fast_with_header} with FF FF FD 00 in the data"


@pytest.mark.slow
def test_feed_bytes_in_chunks_of_every_size(dxl):
    rng = random.Random(41)
    max_param = dxl.so.shim_max_param()
    ping = inst.ping(9).encode()
    cut = fast_sync_reply(rng)[:50]   # LEN promises 106 bytes: 56 more are taken as its data
    stream = (garbage(rng) + fast_sync_reply(rng, header_inside=True) + status_packet(rng).encode()
              + fast_too_long() + ping + StatusPacket(BROADCAST_ID, 0, bytes(max_param)).encode()
              + cut + ping + bytes(60 - len(ping)) + ping)
    expected = None
    for size in range(1, len(stream) + 2):
        events = feed_both(dxl, stream, list(range(0, len(stream), size)) + [len(stream)])
        assert expected is None or events == expected, f"chunks of {size}: the same results"
        expected = events
    assert [e[1] for e in expected] == [PACKET, PACKET, -2, PACKET, PACKET, -1, PACKET], \
        "two packets, a 19-servo reply too long, the ping, a reply of DXL_MAX_PARAM params, " \
        "the cut reply's bad CRC (a ping inside it is data), the ping after it"
    assert feed_both(dxl, stream, [0, len(stream)]) == expected, "and all in one chunk"


def fast_too_long(count=19) -> bytes:
    """A fast sync read reply of count servos x 10 bytes; no FF in it, so no header after a refusal.
    19 servos: 19 * 14 - 3 = 263 params, more than DXL_MAX_PARAM, with a LEN (267) that passes."""
    reply = encode_fast_reply([FastReadBlock(k, 0, bytes([k]) * FAST_SIZE) for k in range(count)])
    assert b"\xFF\xFF" not in reply[7:], "no header can start inside it"
    return reply


def test_feed_bytes_refuses_a_fast_reply_too_long_like_the_byte_path(dxl):
    max_param = dxl.so.shim_max_param()
    ping = inst.ping(2).encode()
    cases = [
        # 19 servos x 10 bytes: 19 * 14 - 3 = 263 params, LEN 267 passes the LEN check
        (fast_too_long(), 7 + 2 + max_param),
        (StatusPacket(BROADCAST_ID, 0, bytes(max_param + 1)).encode(), 7 + 2 + max_param),
        # LEN past what any frame with DXL_MAX_PARAM params can be: refused on LEN's high byte
        (StatusPacket(BROADCAST_ID, 0, bytes(max_param + 87)).encode(), 6),
    ]
    for frame, at in cases:
        assert dxl.reader().feed(frame + ping) == [-2, (2, 0x01, 0, b"")], "the byte path"
        for size in (1, 2, 3, 7, 64, 255, 256, 257, len(frame), len(frame) + len(ping)):
            reader = dxl.reader()
            data = frame + ping
            assert reader.feed_bytes(data[:size]) == ((-2, at + 1) if size > at else (MORE, size)), \
                f"LEN {len(frame) - 7}, first call of {size} bytes"
            events = feed_both(dxl, data, list(range(0, len(data), size)) + [len(data)])
            assert events == [(at, -2, None), (len(data) - 1, PACKET, (2, 0x01, 0, b""))], \
                f"LEN {len(frame) - 7}, chunks of {size}: DXL_TOO_LONG on byte {at}, then the ping"
    params = (HEADER_BYTES * max_param)[:max_param]
    fits = StatusPacket(BROADCAST_ID, 0x80, params).encode()
    assert feed_both(dxl, fits, [0, len(fits)]) == [(len(fits) - 1, PACKET, (BROADCAST_ID, 0x55, 0x80, params))], \
        "DXL_MAX_PARAM params fit, headers and all"


def test_feed_bytes_stops_at_each_result(dxl):
    rng = random.Random(13)
    status = status_packet(rng, 4)
    reply = fast_sync_reply(rng, header_inside=True)
    frames = [status.encode(), reply, inst.ping(3).encode()]
    data = b"".join(frames)
    reader, at = dxl.reader(), 0
    for frame in frames:
        assert reader.feed_bytes(data[at:]) == (PACKET, len(frame)), "one packet a call"
        assert reader.fields() == fields_of(decode_frame(frame)), "its fields, as Python decodes them"
        at += len(frame)
    assert reader.feed_bytes(b"") == (MORE, 0), "nothing fed, nothing used"
    reader = dxl.reader()
    assert reader.so.dxl_reader_feed_bytes(reader.buffer, _bytes(reply), len(reply), None) == PACKET, \
        "used may be NULL"
    got = reader.split(FAST_SIZE, FAST_IDS)
    python = split_fast_reply(decode_frame(reply), [FAST_SIZE] * len(FAST_IDS))
    assert got == (7, [(b.id, b.error, b.data) for b in python]), "and the split reads all 7 blocks"
