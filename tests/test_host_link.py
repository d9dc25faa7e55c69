"""The host link (docs/host-link.md): the Python codec (servodyn.hal.link) against the firmware's C one
(firmware/link/link.c, built here as a shared library in both precisions with -DLINK_TEXT), message by
message and byte for byte; the decoders on corrupt streams; the retransmit rule over a simulated 2 Mbps
line with corrupt and lost bytes (the C controller's side, the Python host's); a version mismatch; a
robot loaded over the link and checked by the core's checks on the controller; the bandwidth figure."""

from __future__ import annotations

import ctypes
import math
import random
import re
import shutil
import struct
import subprocess
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from servodyn.hal.link import frame as fr
from servodyn.hal.link import messages as ms
from servodyn.hal.link.sender import LinkTimeoutError, LinkVersionError, Sender

ROOT = Path(__file__).resolve().parent.parent
SOURCES = [ROOT / "firmware" / "link" / "link.c", ROOT / "hal" / "dynamixel" / "c" / "dxl.c",
           *sorted((ROOT / "firmware" / "core").glob("*.c"))]
EXECUTE, REPEAT, REFUSE = 1, 2, 3


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


# one example of every message, values float32-exact where the wire is float32
EXAMPLES = {
    "hello": ms.Hello(nonce=0x1234),
    "hello_reply": ms.HelloReply(nonce=0xBEEF, link_version=1, fw_major=0, fw_minor=1, fw_patch=0, board="netduino",
                                 real_bytes=4, max_body=8, max_dof=8, knot_slots=64, max_payload=240, window=8,
                                 buses=6, state=1),
    "load_robot": ms.RobotHead(nbody=7, ndof=7, free_root=0, mode=1, contact=1, contact_debounce=3, reaction=0,
                               update_ticks=10, host_timeout_ms=100, period_us=1000, gravity=(0.0, 0.0, _f32(-9.81)),
                               friction_speed=_f32(0.05), stall_time=_f32(0.1), stall_speed=_f32(0.05),
                               stall_share=_f32(0.95), contact_arm_time=0.25, reaction_time=1.0),
    "load_body": ms.Body(index=3, parent=-1, dofnum=1, ball=0, pos=(0.5, -0.25, 0.125), rot=(1, 0, 0, 0, 1, 0, 0, 0, 1),
                         mass=1.5, com=(0.0, 0.0625, 0.0), inertia=(_f32(0.01), _f32(0.02), _f32(0.03), 0.0, 0.0, -0.0)),
    "load_joint": ms.Joint(index=6, bus=2, id=0x21, model_number=1120, dof_rot=(0, -1, 0, 1, 0, 0, 0, 0, 1),
                           **{name: _f32((k + 1) / 7) * (-1 if k % 3 == 0 else 1)
                              for k, name in enumerate(ms.JOINT_REALS)}),
    "commit": ms.Commit(),
    "command": ms.Command(command=ms.COMMANDS["home"], arg=2500),
    "result": ms.Result(seq=200, type=ms.COMMIT, stage=1, code=-6, index=3, credits=31),
    "telemetry": ms.Telemetry(tick=123456, work_us=87, missed=2, state=3, fault=0, fault_joint=255, flags=1,
                              credits=12, njoint=7, joints=tuple(
                                  ms.JointTelemetry(q=k * 0.25 - 1, qd=k * 1.5, q_d=k * 0.25 - 0.5, tau=-0.5 * k,
                                                    effort=-100 * k, command=37 * k, residual=0.015625 * k)
                                  for k in range(7))),
    "knots": ms.knots(40, [ms.Knot(t_us=1000 * i, q=tuple(0.25 * (i + d) for d in range(7)),
                                   qd=tuple(-0.5 * d for d in range(7)), qdd=(2.0,) * 7) for i in range(2)]),
    "knots_gains": ms.knots(41, [ms.Knot(t_us=5000, q=(0.5,) * 7, qd=(0.0,) * 7, qdd=(0.0,) * 7, kp=(8.0,) * 7,
                                         kd=(0.125,) * 7)], last=True),
}


def build_link(directory: Path, single: bool) -> ctypes.CDLL:
    """firmware/link with the core and the CRC as a shared library, -DLINK_TEXT (its host helpers)."""
    cc = shutil.which("cc")
    if cc is None:
        pytest.fail("no C compiler: `cc` is not on PATH (make test installs one)", pytrace=False)
    lib = directory / ("liblink32.so" if single else "liblink.so")
    command = [cc, "-shared", "-fPIC", "-O2", "-std=c11", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off",
               "-DLINK_TEXT", *(["-DSD_SINGLE"] if single else []), f"-I{ROOT / 'firmware' / 'link'}",
               f"-I{ROOT / 'firmware' / 'core' / 'include'}", f"-I{ROOT / 'hal' / 'dynamixel' / 'c'}",
               f"-I{ROOT / 'hal' / 'can' / 'c'}", "-o", str(lib),
               *map(str, SOURCES), "-lm"]
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0, f"the link did not build: {done.stderr[-2000:]}"
    c = ctypes.CDLL(str(lib))
    u8p, szp = ctypes.c_char_p, ctypes.POINTER(ctypes.c_size_t)
    c.link_host_recode.argtypes = [ctypes.c_uint8, u8p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t,
                                   ctypes.c_char_p, ctypes.c_size_t, szp]
    c.link_host_sizeof.restype = ctypes.c_size_t
    c.link_frame.restype = ctypes.c_size_t
    c.link_frame.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint8, ctypes.c_uint8, ctypes.c_uint8, u8p,
                             ctypes.c_size_t]
    c.link_host_feed.argtypes = [ctypes.c_void_p, u8p, ctypes.c_size_t, szp, ctypes.c_char_p, ctypes.c_char_p,
                                 ctypes.POINTER(ctypes.c_uint16)]
    c.link_host_accept.argtypes = [ctypes.c_void_p, ctypes.c_uint8, ctypes.c_uint8, ctypes.c_char_p]
    c.link_host_done.argtypes = [ctypes.c_void_p, u8p, ctypes.c_size_t]
    c.link_host_expected.argtypes = [ctypes.c_void_p]
    c.link_host_expected.restype = ctypes.c_uint8
    c.link_host_robot.argtypes = [ctypes.c_void_p, ctypes.c_uint8, u8p, ctypes.c_size_t, ctypes.c_uint8,
                                  ctypes.c_char_p]
    for name in ("link_decoder_reset", "link_server_reset", "link_ring_pop"):
        getattr(c, name).argtypes = [ctypes.c_void_p]
    c.link_ring_reset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int]
    c.link_ring_free.argtypes = [ctypes.c_void_p]
    c.link_ring_free.restype = ctypes.c_uint16
    c.link_ring_at.argtypes = [ctypes.c_void_p, ctypes.c_int]
    c.link_ring_at.restype = ctypes.POINTER(ctypes.c_uint32)     # a link_knot, t_us first
    c.link_host_ring_push.argtypes = [ctypes.c_void_p, u8p, ctypes.c_size_t, ctypes.c_char_p]
    c.link_host_ring_push.restype = ctypes.c_uint16
    return c


@pytest.fixture(scope="module", params=["double", "float"])
def lib(request, tmp_path_factory):
    return build_link(tmp_path_factory.mktemp("link"), request.param == "float")


def c_recode(lib, type_: int, payload: bytes) -> tuple[int, str, bytes]:
    text = ctypes.create_string_buffer(8192)
    out = ctypes.create_string_buffer(fr.MAX_PAYLOAD)
    n = ctypes.c_size_t(0)
    rc = lib.link_host_recode(type_, payload, len(payload), text, len(text), out, len(out), ctypes.byref(n))
    return rc, text.value.decode(), out.raw[:n.value]


def c_frame(lib, seq, ack, type_, payload) -> bytes:
    out = ctypes.create_string_buffer(fr.MAX_WIRE)
    n = lib.link_frame(out, len(out), seq, ack, type_, payload, len(payload))
    return out.raw[:n]


def python_fields(message) -> list[tuple[str, tuple]]:
    """A message's fields in layout order, as link_host_recode writes them."""
    t = ms.TYPES[type(message)]
    out = [(name, getattr(message, name)) for name, _, _ in ms.LAYOUTS[t][1]]
    if t == ms.TELEMETRY:
        for j in message.joints:
            out += [(name, getattr(j, name)) for name, _, _ in ms.JOINT_TELEMETRY]
    if t == ms.KNOTS:
        for k in message.knots:
            out += [("t_us", k.t_us), ("q", k.q), ("qd", k.qd), ("qdd", k.qdd)]
            if k.kp is not None:
                out += [("kp", k.kp), ("kd", k.kd)]
    return [(name, v if isinstance(v, tuple) else (v,)) for name, v in out]


def c_fields(text: str) -> list[tuple[str, tuple]]:
    out = []
    for token in text.split(" ") if text else []:
        name, value = token.split("=", 1)
        parts = value.split(",")
        try:
            out.append((name, tuple(float(p) for p in parts)))
        except ValueError:
            out.append((name, (value,)))
    return out


def same(a, b) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return str(a) == str(b)
    return (math.isnan(a) and math.isnan(b)) or float(a) == float(b)


# ---------------------------------- every message, both ways ------------------------------------


@pytest.mark.parametrize("name", EXAMPLES)
def test_every_message_round_trips_between_c_and_python_byte_for_byte(lib, name):
    """Python packs; C unpacks, names every field with the same value, packs the same bytes; the
    frame C builds is the frame Python builds; Python unpacks C's bytes to the same message."""
    message = EXAMPLES[name]
    type_, payload = ms.pack(message)
    rc, text, again = c_recode(lib, type_, payload)
    assert rc == 0, f"C refused the Python {name}: code {rc}"
    assert again == payload, f"{name}: C packs {again.hex(' ')}, Python {payload.hex(' ')}"
    mine, theirs = python_fields(ms.unpack(type_, payload)), c_fields(text)
    assert [n for n, _ in theirs] == [n for n, _ in mine], f"{name}: C's fields differ from the layout"
    for (field, a), (_, b) in zip(mine, theirs):
        assert len(a) == len(b) and all(same(x, y) for x, y in zip(a, b)), f"{name}.{field}: Python {a}, C {b}"
    assert ms.unpack(type_, again) == ms.unpack(type_, payload), "Python reads C's bytes back to the same message"
    for seq, ack in ((0, 0), (255, 17), (0x7F, 0xFF)):
        assert c_frame(lib, seq, ack, type_, payload) == fr.encode(seq, ack, type_, payload), "same frame"


def test_every_message_type_has_an_example():
    assert {ms.TYPES[type(m)] for m in EXAMPLES.values()} == set(ms.LAYOUTS), "a message without a round trip"


def test_c_refuses_a_payload_of_the_wrong_length(lib):
    for name, message in EXAMPLES.items():
        type_, payload = ms.pack(message)
        for bad in (payload + b"\x00", payload[:-1]):
            if type_ == ms.COMMIT and not bad:
                continue
            rc, _, _ = c_recode(lib, type_, bad)
            assert rc == -2, f"{name} of {len(bad)} bytes: C says {rc}, expected LINK_E_PAYLOAD (-2)"
            with pytest.raises(fr.LinkError):
                ms.unpack(type_, bad)


def test_telemetry_saturates_and_carries_nan_as_c_does(lib):
    t = ms.Telemetry(njoint=2, flags=0, joints=(ms.JointTelemetry(q=9.0, qd=-100.0, q_d=math.nan, tau=0.5 / 512),
                                               ms.JointTelemetry(q=-0.5 / 4096, residual=math.inf)))
    type_, payload = ms.pack(t)
    back = ms.unpack(type_, payload)
    assert back.flags == ms.TM_SATURATED, "a clamped value sets SATURATED"
    assert back.joints[0].q == 32767 / 4096 and back.joints[0].qd == -32767 / 512, "clamped to the largest codes"
    assert math.isnan(back.joints[0].q_d), "NaN travels as NaN"
    assert back.joints[0].tau == 1 / 512 and back.joints[1].q == -1 / 4096, "half an LSB rounds away from zero"
    rc, _, again = c_recode(lib, type_, payload)
    assert rc == 0 and again == payload, "C reads and writes the same codes"


# ---------------------------------- framing -----------------------------------------------------


def _stream(rng: random.Random, nframes: int) -> tuple[bytes, list[bytes]]:
    payloads = [bytes(rng.choice((0, 0, 1, rng.randrange(256))) for _ in range(rng.randrange(0, 60)))
                for _ in range(nframes)]
    return b"".join(fr.encode(k, 0, ms.KNOTS, p) for k, p in enumerate(payloads)), payloads


def _c_feed(lib, data: bytes) -> list[tuple]:
    """The C decoder's verdicts on data, from a fresh decoder: (FRAME, seq, type, payload) or (verdict,)."""
    decoder = ctypes.create_string_buffer(lib.link_host_sizeof(0))
    lib.link_decoder_reset(decoder)
    return list(_c_feed_into(lib, decoder, data))


def _py_feed(data: bytes, pieces: int = 7) -> list[tuple]:
    decoder, out = fr.Decoder(), []
    cut = sorted(random.Random(len(data)).sample(range(len(data)), min(pieces, len(data))))
    for a, b in zip([0, *cut], [*cut, len(data)]):
        for f in decoder.feed(data[a:b]):
            out.append((f.verdict, f.seq, f.type, f.payload) if f.verdict == fr.FRAME else (f.verdict,))
    return out


@pytest.mark.parametrize("seed", range(4))
def test_decoders_agree_on_corrupt_and_cut_streams(lib, seed):
    """Random frames with bytes flipped, dropped, zeroed and junk runs: the Python decoder (fed in
    random pieces) gives the C decoder's verdicts, frame for frame, and no corrupt frame is taken."""
    rng = random.Random(seed)
    data, payloads = _stream(rng, 400)
    damaged = bytearray()
    for b in data:
        r = rng.random()
        if r < 0.002:
            continue                                   # lost
        damaged.append(b ^ rng.randrange(1, 256) if r < 0.004 else 0 if r < 0.005 else b)
        if r > 0.9995:
            damaged += bytes(rng.randrange(1, 256) for _ in range(rng.randrange(1, 300)))   # junk
    c, py = _c_feed(lib, bytes(damaged)), _py_feed(bytes(damaged))
    assert py == c, "the two decoders disagree"
    good = [e for e in c if e[0] == fr.FRAME]
    assert all(any(payloads[i] == e[3] for i in range(e[1], len(payloads), 256)) for e in good), \
        "every frame taken was sent, with its seq"
    assert len(good) > 300, f"most frames survive ({len(good)} of 400)"
    assert {e[0] for e in c} - {fr.FRAME} <= set(fr.VERDICTS), "every verdict is a known one"


def test_resynchronises_mid_stream(lib):
    """A decoder started at any byte of a stream takes every frame that begins after it: it loses at
    most the frame it started in."""
    data, payloads = _stream(random.Random(9), 20)
    begins = np.cumsum([0] + [len(fr.encode(k, 0, ms.KNOTS, p)) for k, p in enumerate(payloads)])[:-1]
    for start in range(len(data)):
        taken = [e[3] for e in _py_feed(data[start:]) if e[0] == fr.FRAME]
        assert taken == [p for p, b in zip(payloads, begins) if b >= start], f"started at byte {start}"
        assert _c_feed(lib, data[start:]) == _py_feed(data[start:]), "as the C decoder"


# ---------------------------------- versions ----------------------------------------------------


def test_a_version_mismatch_is_refused_with_one_line(lib):
    """The controller of another version: its frames stop the host with one line naming both versions;
    the host's frames are refused by a controller of another version as BAD_VERSION, seq readable."""
    sender = Sender(lambda data: None, clock=lambda: 0.0)
    sender.send(ms.Hello(nonce=1))
    _, payload = ms.pack(ms.Result(seq=0, type=ms.HELLO))
    with pytest.raises(LinkVersionError) as caught:
        sender.receive(fr.encode(0, 1, ms.RESULT, payload, version=2))
    text = str(caught.value)
    assert "\n" not in text and "version 2" in text and f"version {fr.VERSION}" in text, text
    assert caught.value.exit_code == 16, "exit code SETUP"
    sender = Sender(lambda data: None, clock=lambda: 0.0)
    sender.send(ms.Hello(nonce=1))
    reply = ms.pack(EXAMPLES["hello_reply"].__class__(**{**EXAMPLES["hello_reply"].__dict__, "link_version": 3,
                                                          "nonce": 1}))[1]
    with pytest.raises(LinkVersionError, match="controller speaks version 3"):
        sender.receive(fr.encode(0, 1, ms.HELLO_REPLY, reply))
    wire = fr.encode(9, 0, ms.HELLO, ms.pack(ms.Hello(nonce=7))[1], version=2)
    assert _c_feed(lib, wire) == [(fr.BAD_VERSION,)], "C's decoder refuses version 2 as such"


# ---------------------------------- the retransmit rule over a bad line --------------------------

BYTE_TIME = 10 / 2e6          # s a byte at 2 Mbps, 8N1


class Line:
    """One direction of a UART: bytes in order at BYTE_TIME each; some corrupted or lost."""

    def __init__(self, rng: np.random.Generator, corrupt: float, lose: float):
        self.rng, self.corrupt, self.lose = rng, corrupt, lose
        self.queue: deque = deque()
        self.free = 0.0
        self.hurt = 0

    def send(self, data: bytes, now: float) -> None:
        if not data:
            return
        raw = np.frombuffer(data, np.uint8).copy()
        r = self.rng.random(len(raw))
        flip = r < self.corrupt
        raw[flip] ^= self.rng.integers(1, 256, int(flip.sum()), dtype=np.uint8)
        lost = r >= 1 - self.lose
        keep = ~lost
        self.hurt += int(flip.sum() + lost.sum())
        start = max(self.free, now)
        times = start + BYTE_TIME * np.arange(1, len(raw) + 1)
        self.free = times[-1]
        self.queue.append((times[keep], raw[keep].tobytes()))

    def deliver(self, now: float) -> bytes:
        out = bytearray()
        while self.queue:
            times, data = self.queue[0]
            k = int(np.searchsorted(times, now, side="right"))
            out += data[:k]
            if k < len(data):
                self.queue[0] = (times[k:], data[k:])
                break
            self.queue.popleft()
        return bytes(out)


class Controller:
    """The controller's side, in C: the decoder and the retransmit rule (link_server); executes a
    request by recording it, answers it, and sends 7 joints' telemetry every tick. KNOTS go into the
    C knot buffer (link_ring) of `slots`, or with no slots are only recorded; once `start` knots came,
    each tick plays one (a tick that finds it empty before the last knot is starved)."""

    def __init__(self, lib, slots: int = 0, start: int = 16):
        self.lib = lib
        self.decoder = ctypes.create_string_buffer(lib.link_host_sizeof(0))
        self.server = ctypes.create_string_buffer(lib.link_host_sizeof(1))
        lib.link_decoder_reset(self.decoder)
        lib.link_server_reset(self.server)
        self.seq = 0
        self.executed: list[tuple[int, bytes]] = []
        self.slots, self.start = slots, start
        self.ring = ctypes.create_string_buffer(lib.link_host_sizeof(3))
        lib.link_ring_reset(self.ring, 7, slots)
        self.played: list[int] = []
        self.full = self.starved = 0
        self.playing = self.last = False

    def _send(self, type_: int, payload: bytes) -> bytes:
        wire = c_frame(self.lib, self.seq, self.lib.link_host_expected(self.server), type_, payload)
        self.seq = (self.seq + 1) & 0xFF
        return wire

    def receive(self, data: bytes) -> bytes:
        out = bytearray()
        for event in _c_feed_into(self.lib, self.decoder, data):
            if event[0] != fr.FRAME:
                continue
            _, seq, type_, payload = event
            reply = ctypes.create_string_buffer(8)
            action = self.lib.link_host_accept(self.server, seq, type_, reply)
            if action != EXECUTE:
                out += self._send(ms.RESULT, reply.raw)
                continue
            code = 0
            if type_ == ms.KNOTS and self.slots:
                pushed = ctypes.create_string_buffer(8)
                self.lib.link_host_ring_push(self.ring, payload, len(payload), pushed)
                code = ms.unpack(ms.RESULT, pushed.raw).code
                self.full += code == -4
                knots = ms.unpack(type_, payload)
                self.last |= code == 0 and bool(knots.flags & ms.KNOT_LAST)
                self.playing |= self.held >= self.start or self.last
            if code == 0:
                self.executed.append((type_, payload))
            result = ms.pack(ms.Result(seq=seq, type=type_, code=code, credits=self.credits))[1]
            self.lib.link_host_done(self.server, result, len(result))
            if type_ == ms.HELLO:
                hello = ms.unpack(type_, payload)
                out += self._send(ms.HELLO_REPLY, ms.pack(ms.HelloReply(nonce=hello.nonce, link_version=fr.VERSION))[1])
            else:
                out += self._send(ms.RESULT, result)
        return bytes(out)

    @property
    def credits(self) -> int:
        return self.lib.link_ring_free(self.ring) if self.slots else 0

    @property
    def held(self) -> int:
        return self.slots - self.credits

    def tick(self) -> bytes:
        if self.playing and self.held:
            self.played.append(self.lib.link_ring_at(self.ring, 0)[0] // 1000)   # its t_us: 1000 x its index
            self.lib.link_ring_pop(self.ring)
        elif self.playing and not self.last:
            self.starved += 1
        telemetry = ms.pack(ms.Telemetry(**{**EXAMPLES["telemetry"].__dict__, "credits": self.credits}))
        return self._send(ms.TELEMETRY, telemetry[1])


def _c_feed_into(lib, decoder, data: bytes):
    head, payload = ctypes.create_string_buffer(4), ctypes.create_string_buffer(fr.MAX_PAYLOAD)
    length, used = ctypes.c_uint16(0), ctypes.c_size_t(0)
    at = 0
    while at < len(data):
        v = lib.link_host_feed(decoder, data[at:], len(data) - at, ctypes.byref(used), head, payload,
                               ctypes.byref(length))
        at += used.value
        if v:
            yield (v, head.raw[1], head.raw[3], payload.raw[:length.value]) if v == 1 else (v,)


def _requests(n: int):
    """Commands and knots, each naming its index (COMMAND's arg, KNOTS' first)."""
    for i in range(n):
        if i % 3 == 2:
            yield ms.knots(i, [ms.Knot(t_us=i, q=(0.1 * i,) * 7, qd=(0.0,) * 7, qdd=(0.0,) * 7)] * 2)
        else:
            yield ms.Command(command=ms.COMMANDS["keepalive"], arg=i)


def run_link(lib, n: int, corrupt: float, lose: float, seed: int = 1, dt: float = 50e-6, todo=None,
             controller=None):
    """n requests (or those of `todo`, a function of the sender giving the next request or None to wait)
    from a Sender to the C controller over two simulated lines, telemetry every 1 ms: (the requests the
    controller executed, in order, the sender, the lines, telemetry frames received, seconds)."""
    rng = np.random.default_rng(seed)
    up, down = Line(rng, corrupt, lose), Line(rng, corrupt, lose)
    clock = [0.0]
    sender = Sender(lambda data: up.send(data, clock[0]), clock=lambda: clock[0])
    controller = controller or Controller(lib)
    hello = sender.send(ms.Hello(nonce=77))
    requests = _requests(n)
    todo = todo or (lambda sender: next(requests, None))
    pending = todo(sender)
    next_tick = 0.001
    telemetry = 0
    while clock[0] < 60.0:
        clock[0] += dt
        down.send(controller.receive(up.deliver(clock[0])), clock[0])
        if clock[0] >= next_tick:
            down.send(controller.tick(), clock[0])
            next_tick += 0.001
        telemetry += sum(isinstance(m, ms.Telemetry) for m in sender.receive(down.deliver(clock[0])))
        sender.poll()
        while pending is not None and hello.answer is not None and len(sender._queue) < 2:
            sender.send(pending)
            pending = todo(sender)
        if pending is None and hello.answer is not None:
            pending = todo(sender)
            if pending is None and sender.idle and todo is not None and getattr(todo, "done", True):
                break
    return controller.executed, sender, (up, down), telemetry, clock[0]


def _indices(executed) -> list[int]:
    out = []
    for type_, payload in executed[1:]:
        message = ms.unpack(type_, payload)
        out.append(message.arg if type_ == ms.COMMAND else message.first)
    return out


@pytest.mark.parametrize("corrupt, lose", [(1e-4, 0.0), (1e-3, 1e-3)])
def test_no_request_is_lost_or_done_twice_over_a_bad_line(lib, corrupt, lose):
    """1 corrupt byte in 10^4 each way (and 10 times that, with as many lost): every one of
    1500 requests is executed once, in order; telemetry flows at 1 kHz meanwhile."""
    n = 1500
    executed, sender, lines, telemetry, seconds = run_link(lib, n, corrupt, lose)
    assert executed[0][0] == ms.HELLO, "the session starts with HELLO"
    assert _indices(executed) == list(range(n)), "each request executed once, in order"
    assert sender.idle, "every request answered"
    hurt = sum(line.hurt for line in lines)
    if corrupt >= 1e-3:
        assert hurt > 20 and sender.retransmissions > 0, "the bad line did hurt, and the rule made it good"
    assert telemetry >= 0.8 * seconds * 1000 * (1 - 123 * (corrupt + lose)) - 5, "telemetry kept flowing"
    print(f"corrupt {corrupt:g}, lose {lose:g}: {n} requests in {seconds * 1000:.0f} ms, {hurt} bytes hurt, "
          f"{sender.retransmissions} retransmissions, {sender.naks} NAKs, {telemetry} telemetry frames")


def test_a_motion_longer_than_the_buffer_streams_without_a_gap(lib):
    """900 knots, one played a tick, through the C knot buffer of 32 over a line with 1 corrupt byte in
    10^4: the host sends knots within the credits the controller reports, so none is refused for want
    of room, every knot plays once and in order, and no tick after the first finds the buffer empty."""
    total, per_frame = 900, 2
    state = {"next": 0}

    def todo(sender):
        first = state["next"]
        count = min(per_frame, total - first)
        todo.done = count == 0 and sender.idle and controller.played[-1:] == [total - 1]
        if count == 0 or sender.knot_room() < count:
            return None
        state["next"] += count
        return ms.knots(first, [ms.Knot(t_us=1000 * (first + k), q=(0.001 * (first + k),) * 7, qd=(0.0,) * 7,
                                        qdd=(0.0,) * 7) for k in range(count)], last=first + count == total)

    todo.done = False
    controller = Controller(lib, slots=32, start=16)
    _, sender, lines, _, seconds = run_link(lib, 0, 1e-4, 0.0, todo=todo, controller=controller)
    assert controller.played == list(range(total)), "every knot played once, in order"
    assert controller.full == 0, "no KNOTS refused for want of room: the host kept within the credits"
    assert controller.starved == 0, "no tick found the buffer empty"
    assert seconds < 1.2, f"the 0.9 s motion took {seconds:.2f} s to stream and play"
    print(f"{total} knots through 32 slots in {seconds * 1000:.0f} ms, {sender.retransmissions} retransmissions, "
          f"{sum(line.hurt for line in lines)} bytes hurt")


def test_a_silent_controller_times_out(lib):
    """Nothing comes back: the request goes 1 + RETRIES times, TIMEOUT apart, then LinkTimeoutError
    (one line, exit code TIMEOUT)."""
    clock, sent = [0.0], []
    sender = Sender(sent.append, clock=lambda: clock[0])
    sender.send(ms.Hello(nonce=5))
    with pytest.raises(LinkTimeoutError, match="answered nothing over 9 sendings") as caught:
        for _ in range(1000):
            clock[0] += 0.005
            sender.poll()
    assert len(sent) == 9 and len(set(sent)) == 1, "the same frame, 9 times"
    assert clock[0] == pytest.approx(9 * 0.025, abs=0.006), "TIMEOUT apart"
    assert caught.value.exit_code == 10 and "\n" not in str(caught.value)


# ---------------------------------- a robot over the link ---------------------------------------


def replica_messages(config: str = "replica") -> list:
    """The replica's (or another configuration's) model (the host's set-up sd_model,
    servodyn.model.layout's reading of it), servos, gains and safety table as LOAD_ROBOT, LOAD_BODY
    and LOAD_JOINT messages (servodyn.loop.link_load)."""
    from servodyn.hal.config import load_config
    from servodyn.loop.link_load import plan
    return plan(load_config(config)).messages


def load(lib, messages, buses=1 << ms.BUSES["dynamixel"]) -> ms.Result:
    robot = ctypes.create_string_buffer(lib.link_host_sizeof(2))
    result = ctypes.create_string_buffer(8)
    for message in [*messages, ms.Commit()]:
        type_, payload = ms.pack(message)
        code = lib.link_host_robot(robot, type_, payload, len(payload), buses, result)
        outcome = ms.unpack(ms.RESULT, result.raw)
        if code:
            return outcome
    return outcome


def test_the_replica_loads_and_bad_robots_are_refused_with_the_reason(lib):
    """The replica over the link passes the core's checks on the controller; a body without mass, a
    negative gain, a bus the controller has not, a joint never sent: refused, each with its stage,
    the core's code and the body or joint, in one line."""
    messages = replica_messages()
    ok = load(lib, messages)
    assert (ok.stage, ok.code) == (0, 0), f"the replica refused: {ms.reason(ok)}"
    bodies = [m for m in messages if isinstance(m, ms.Body)]
    heavy = [m if m is not bodies[2] else ms.Body(**{**m.__dict__, "mass": 0.0}) for m in messages]
    refused = load(lib, heavy)
    assert (refused.stage, refused.code, refused.index) == (1, -6, 2), "sd_model_setup's SD_ERR_MASS, body 2"
    assert ms.reason(refused) == "model check code -6, body 2"
    joints = [m for m in messages if isinstance(m, ms.Joint)]
    greedy = [m if m is not joints[3] else ms.Joint(**{**m.__dict__, "kp": -1.0}) for m in messages]
    refused = load(lib, greedy)
    assert (refused.stage, refused.code) == (2, -4), "sd_control_check's SD_CONTROL_ERR_GAIN"
    refused = load(lib, messages, buses=1 << ms.BUSES["can"])
    assert (refused.stage, refused.code, refused.index) == (4, -1, 0), "no Dynamixel bus on this controller"
    assert "\n" not in ms.reason(refused) and "joint 0" in ms.reason(refused)
    refused = load(lib, [m for m in messages if m is not joints[5]])
    assert ms.reason(refused) == "link check code -10 (a joint was not sent), item 5"


# ---------------------------------- bandwidth ---------------------------------------------------


def test_seven_joints_telemetry_at_1khz_fits_a_2mbps_uart():
    """123 bytes a tick, 61.5 % of a 2 Mbps 8N1 line at 1 kHz (docs/host-link.md quotes both); the
    same fields as float32 would take 96.5 %, leaving no room for a retransmitted answer."""
    assert ms.telemetry_wire_bytes(7) == 123
    assert ms.line_share(7, 1000, 2_000_000) == pytest.approx(0.615, abs=1e-9)
    float32 = ms.SIZES[ms.TELEMETRY] + 7 * (5 * 4 + 2 * 2) + fr.OVERHEAD
    assert float32 * 10 * 1000 / 2e6 == pytest.approx(0.965, abs=1e-9)
    assert ms.telemetry_wire_bytes(ms.MAX_TELEMETRY_JOINT) <= fr.MAX_WIRE, "16 joints fit a frame"
    doc = (ROOT / "docs" / "host-link.md").read_text()
    assert "123 bytes" in doc and "61.5 %" in doc and "96.5 %" in doc, "the document quotes the figures"


def test_the_document_lists_every_field_of_every_message():
    """Each message's table in docs/host-link.md has the layout's fields in order, each with its bytes."""
    doc = (ROOT / "docs" / "host-link.md").read_text()
    kinds = {"u8": 1, "i8": 1, "u16": 2, "i16": 2, "u32": 4, "f32": 4, "fix_q": 2, "fix_qd": 2, "fix_tau": 2,
             "str12": 12}
    for t, (name, layout) in [*ms.LAYOUTS.items(), (None, ("JointTelemetry", ms.JOINT_TELEMETRY))]:
        section = re.search(rf"<a id=\"{name}\"></a>(.*?)(?=\n#|\Z)", doc, re.S)
        assert section, f"docs/host-link.md has no table of {name}"
        rows = re.findall(r"^\| *(\d+) *\| *`([a-z_0-9]+)` *\| *([a-z0-9_]+)(?:\[(\d+)\])? *\|", section.group(1), re.M)
        at, want = 0, []
        for field, kind, count in layout:
            want.append((str(at), field, kind, "" if count == 1 else str(count)))
            at += kinds[kind] * count
        assert rows == want, f"{name}'s table differs from its layout"
