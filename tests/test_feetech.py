"""The Feetech STS codec against Feetech's own SDK (scservo_sdk, feetech-servo-sdk on PyPI) byte
for byte, the firmware's C codec (hal/feetech/c/sts.c) against the Python one, the sign-magnitude
fields at their edges, the memory table, the motor model's inversion, and the simulated STS servos
(sim/feetech) answering the SDK through a pseudo-terminal: the EEPROM lock, the baud gate, the
modes, overload protection."""

from __future__ import annotations

import ctypes
import random
import shutil
import subprocess
from pathlib import Path

import pytest

from servodyn.hal.feetech import protocol
from servodyn.hal.feetech.protocol import (BadFrame, Packet, PacketError, PacketReader, StatusBit,
                                           decode_sign_magnitude, encode_sign_magnitude)
from servodyn.hal.feetech.table import ITEM, SERVOS, STEP, STS3215_C001, Mode
from servodyn.sim.feetech import FeetechServo, FeetechWire

sdk = pytest.importorskip("scservo_sdk")


class CapturePort:
    """The SDK's port, as far as its packet builders use it: what they write is kept."""

    def __init__(self):
        self.is_using, self.sent = False, []

    def clearPort(self):
        pass

    def writePort(self, packet):
        self.sent.append(bytes(packet))
        return len(packet)

    def setPacketTimeout(self, length):
        self.is_using = False


def sdk_bytes(call) -> bytes:
    """What one SDK call puts on the wire (its Tx half)."""
    port, handler = CapturePort(), sdk.PacketHandler(0)
    call(port, handler)
    assert len(port.sent) == 1, "one packet per call"
    return port.sent[0]


# ------------------------------------------------------------------------------ the codec vs the SDK

def test_instructions_match_the_sdk_byte_for_byte():
    """Every instruction servodyn sends, as the SDK builds it: PING, READ, WRITE (1, 2, 4 bytes),
    REG WRITE, ACTION, SYNC WRITE, SYNC READ (0x82), over IDs and addresses at their edges."""
    rng = random.Random(33)
    for servo_id in (0, 1, 6, 0x7F, 0xFD):
        # the SDK's ping() waits for a reply: its frame is txPacket's over [.., ID, LEN, PING, ..]
        assert protocol.ping(servo_id) == sdk_bytes(lambda p, h: h.txPacket(p, [0, 0, servo_id, 2, sdk.INST_PING, 0]))
        for address, length in ((0, 1), (3, 2), (56, 15), (69, 2), (255, 4)):
            assert protocol.read(servo_id, address, length) == sdk_bytes(
                lambda p, h: h.readTx(p, servo_id, address, length))
        for size in (1, 2, 4):
            value = rng.randrange(1 << (8 * size))
            data = value.to_bytes(size, "little")
            write = {1: "write1ByteTxOnly", 2: "write2ByteTxOnly", 4: "write4ByteTxOnly"}[size]
            assert protocol.write(servo_id, 42, data) == \
                sdk_bytes(lambda p, h: getattr(h, write)(p, servo_id, 42, value))
            assert protocol.reg_write(servo_id, 42, data) == sdk_bytes(
                lambda p, h: h.regWriteTxOnly(p, servo_id, 42, size, list(data)))
    assert protocol.action(1) == sdk_bytes(lambda p, h: h.txPacket(p, [0, 0, 1, 2, sdk.INST_ACTION, 0]))
    for ids in ([1], [1, 2, 3, 4, 5, 6], list(range(0, 0xFD, 7))):
        assert protocol.sync_read(56, 15, ids) == sdk_bytes(
            lambda p, h: (lambda g: [g.addParam(i) for i in ids] and g.txPacket())(sdk.GroupSyncRead(p, h, 56, 15)))
        data = {i: rng.randrange(65536).to_bytes(2, "little") for i in ids}

        def group_write(p, h):
            g = sdk.GroupSyncWrite(p, h, 44, 2)
            for i, d in data.items():
                g.addParam(i, list(d))
            g.txPacket()
        assert protocol.sync_write(44, 2, data) == sdk_bytes(group_write)


def test_ping_frame_is_the_protocols_example():
    """The wiki's example: PING to ID 1 is FF FF 01 02 01 FB (checksum ~(1 + 2 + 1))."""
    assert protocol.ping(1) == bytes.fromhex("ff ff 01 02 01 fb")


def test_sign_magnitude_matches_the_sdk_at_every_edge():
    """scs_toscs / scs_tohost (SCS_TOSCS, SCS_TOHOST) against ours for each register's sign bit (15
    position and speed, 11 homing offset, 10 PWM goal and load), at 0, ±1 and the largest
    magnitude; one past it is refused (the SDK would set the sign bit silently: a wrong value)."""
    for bit in (10, 11, 15):
        top = (1 << bit) - 1
        for value in (0, 1, -1, top, -top, top // 2, -(top // 2)):
            raw = encode_sign_magnitude(value, bit)
            assert raw == sdk.SCS_TOSCS(value, bit)
            assert decode_sign_magnitude(raw, bit) == sdk.SCS_TOHOST(raw, bit) == value
        with pytest.raises(PacketError, match="does not fit"):
            encode_sign_magnitude(top + 1, bit)
        assert encode_sign_magnitude(-top, bit) == (1 << (bit + 1)) - 1      # every bit up to the sign set
    # -0: the sign bit alone reads 0; a bit above the sign is not the value's
    assert decode_sign_magnitude(1 << 15, 15) == 0
    assert decode_sign_magnitude(0x0800 | 5, 10) == 5 and decode_sign_magnitude(0x0400 | 5, 10) == -5


def test_registers_carry_their_own_sign_bits():
    """The table's sign bits: what LeRobot's encodings table lists (Present_Load 10, Homing_Offset
    11, positions and speeds 15) and the two it misses (Goal_Time 10 for mode 2, Present_Current 15)."""
    assert {name: ITEM[name].sign_bit for name in ("present_load", "homing_offset", "goal_position", "goal_velocity",
                                                   "present_position", "present_velocity", "goal_time",
                                                   "present_current")} == \
        {"present_load": 10, "homing_offset": 11, "goal_position": 15, "goal_velocity": 15, "present_position": 15,
         "present_velocity": 15, "goal_time": 10, "present_current": 15}
    assert ITEM["lock"].address == 55 and not ITEM["lock"].eeprom and ITEM["operating_mode"].eeprom


def test_reader_resynchronises_on_garbage():
    """Packets split anywhere, with garbage, a lone FF, an impossible LEN and a bad checksum between
    them: each good packet comes out once, in order, and nothing else does."""
    good = [protocol.status(1, 0, bytes(range(15))), protocol.status(2, 0x20, b"\x01\x02"), protocol.ping(0xFE)]
    corrupt = bytearray(protocol.status(3, 0, b"\x10\x20"))
    corrupt[-1] ^= 0xFF
    stream = b"\x00\x13\xff" + good[0] + b"\xff\xff\x05\x00" + bytes(corrupt) + good[1] + b"\xff" + good[2]
    for split in (1, 2, 3, 7, len(stream)):
        reader, packets = PacketReader(), []
        for k in range(0, len(stream), split):
            packets += [e for e in reader.feed(stream[k:k + split]) if isinstance(e, Packet)]
        assert [p.encode() for p in packets] == good
    events = PacketReader().feed(bytes(corrupt))
    assert all(isinstance(e, BadFrame) for e in events) and any(e.fault == "checksum" for e in events)


def test_a_packet_inside_a_truncated_one_is_found():
    """A frame cut short (its LEN promises more) that a whole packet follows: the checksum fails, the
    reader searches again from inside it and finds the packet."""
    cut = protocol.status(1, 0, bytes(15))[:9]
    good = protocol.status(2, 0, b"\x07")
    found = [e for e in PacketReader().feed(cut + good + bytes(30)) if isinstance(e, Packet)]
    assert [p.id for p in found] == [2]


def test_duty_inverts_the_motor_model():
    """The servo's motor (hal.motor's model with BAM's constants): the duty for a torque gives that
    torque back to 1e-12 N m; at stall (ω = 0) full duty gives kt·V/R (BAM's STS3215 at 7.4 V:
    3.35 N m, feetech.md §5's DERIVED figure, to 0.01), of which the bridge gives 97 %."""
    s, m = STS3215_C001, STS3215_C001.motor
    assert (m.torque_constant, m.ke, m.resistance) == (s.motor_kt, s.motor_ke, s.motor_resistance)
    for tau, omega in ((0.5, 0.0), (-1.2, 2.0), (0.0, -3.0)):
        duty = m.duty_for_current(tau / m.torque_constant, 7.4, omega)
        assert m.torque(duty, 7.4, omega) == pytest.approx(tau, abs=1e-12)
    assert m.torque(1.0, 7.4, 0.0) == pytest.approx(3.35, abs=0.01)
    assert m.stall_torque(7.4) == pytest.approx(0.97 * 3.35, abs=0.01)
    assert set(SERVOS) == {"STS3215-C001", "STS3215-C018", "STS3215-C044", "STS3215-C046", "STS3250"}
    assert SERVOS["STS3215-C044"].armature == pytest.approx(s.armature * (191 / 345) ** 2, rel=1e-12)
    assert all(not spec.current_control and spec.kind == "feetech" and spec.source for spec in SERVOS.values())


# ------------------------------------------------------------------------------ the simulated servos


def exchange(wire: FeetechWire, frame: bytes) -> list[Packet]:
    return [e for e in PacketReader().feed(wire.handle(frame)) if isinstance(e, Packet)]


def test_factory_state_and_the_inverted_eeprom_lock():
    """A factory-fresh STS3215: ID 1, 1 Mbps, position mode, Lock 1 at power-on. With Lock = 1 a
    new ID acts at once but is gone after a power cycle; with Lock = 0 (unlocked: inverted) it stays."""
    servo = FeetechServo.factory_fresh()
    wire = FeetechWire([servo])
    assert (servo.id, servo.baud, servo.get("operating_mode"), servo.get("lock")) == (1, 1_000_000, 0, 1)
    [reply] = exchange(wire, protocol.write(1, ITEM["id"].address, b"\x07"))
    assert reply.id == 1 and reply.error == 0                 # answered under the old ID
    assert [p.id for p in exchange(wire, protocol.ping(7))] == [7]
    servo.power_cycle()
    assert servo.id == 1, "Lock = 1: the EEPROM write lasted until power-off only"
    exchange(wire, protocol.write(1, ITEM["lock"].address, b"\x00"))
    exchange(wire, protocol.write(1, ITEM["id"].address, b"\x07"))
    servo.power_cycle()
    assert servo.id == 7 and servo.get("lock") == 1, "Lock = 0: kept across the power cycle; Lock back to 1"


def test_baud_gate():
    """A servo hears only bytes at its own rate; a new Baud_Rate acts once the write's status is sent
    (answered at the old rate)."""
    servo = FeetechServo(STS3215_C001, 3)
    wire = FeetechWire([servo])
    wire.line_speed = 500_000
    assert exchange(wire, protocol.ping(3)) == []
    wire.line_speed = 1_000_000
    assert [p.id for p in exchange(wire, protocol.write(3, ITEM["baud_rate"].address, b"\x01"))] == [3]
    assert servo.baud == 500_000 and exchange(wire, protocol.ping(3)) == []
    wire.line_speed = 500_000
    assert [p.id for p in exchange(wire, protocol.ping(3))] == [3]


def test_modes_and_the_pwm_sign_bit():
    """Mode 2: Goal_Time 500 is +50 % duty, 0x400 | 500 is -50 % (bit 10), so the held-shaft current
    is ±V/2/R (BAM's R, 7.4 V: 1.383 A); Present Load reads the duty back with its sign. Mode 0: the
    P loop pushes towards the goal. Mode 1: a speed goal at that speed draws only friction's share."""
    servo = FeetechServo(STS3215_C001, 1, supply_voltage=7.4)
    wire = FeetechWire([servo])
    for address, value in ((33, Mode.PWM), (40, 1)):
        exchange(wire, protocol.write(1, address, bytes((value,))))
    expected = 7.4 * 0.5 / STS3215_C001.motor_resistance
    for raw, sign in ((500, 1), (0x400 | 500, -1)):
        exchange(wire, protocol.sync_write(44, 2, {1: raw.to_bytes(2, "little")}))
        assert servo.output_current(0.0, 0.0, 1e-3) == pytest.approx(sign * expected, rel=1e-12)
        [reply] = exchange(wire, protocol.read(1, 60, 2))
        assert decode_sign_magnitude(int.from_bytes(reply.params, "little"), 10) == sign * 500
    exchange(wire, protocol.write(1, 33, bytes((Mode.POSITION,))))
    exchange(wire, protocol.write(1, 42, (2100).to_bytes(2, "little")))
    assert servo.output_current(2048 * STEP, 0.0, 1e-3) > 0 > servo.output_current(2200 * STEP, 0.0, 1e-3)
    exchange(wire, protocol.write(1, 33, bytes((Mode.SPEED,))))
    exchange(wire, protocol.write(1, 46, (1000).to_bytes(2, "little")))
    at_speed = servo.output_current(0.0, 1000 * STEP, 1e-3)
    assert abs(at_speed) < 1e-9, "at the goal speed the duty is the back-EMF's alone"


def test_overload_protection_trips_after_protection_time():
    """Mode 2 at 90 % duty (over Overload_Torque 80 %) for Protection_Time 2 s: the overload bit
    (0x20) is in Status and the error byte, and the output falls to Protective_Torque 20 %, until
    the torque is switched off and on. 1.99 s is not enough."""
    servo = FeetechServo(STS3215_C001, 1, supply_voltage=7.4)
    wire = FeetechWire([servo])
    for address, value in ((33, Mode.PWM), (40, 1)):
        exchange(wire, protocol.write(1, address, bytes((value,))))
    exchange(wire, protocol.write(1, 44, (900).to_bytes(2, "little")))
    for _ in range(1990):
        servo.output_current(0.0, 0.0, 1e-3)
    assert not servo.get("status") & StatusBit.OVERLOAD
    for _ in range(20):
        amps = servo.output_current(0.0, 0.0, 1e-3)
    assert amps == pytest.approx(7.4 * 0.2 / STS3215_C001.motor_resistance, rel=1e-12)
    [reply] = exchange(wire, protocol.ping(1))
    assert reply.error & StatusBit.OVERLOAD
    exchange(wire, protocol.write(1, 40, b"\x00"))
    exchange(wire, protocol.write(1, 40, b"\x01"))
    assert servo.output_current(0.0, 0.0, 1e-3) == pytest.approx(7.4 * 0.9 / STS3215_C001.motor_resistance)


def test_simulated_so101_answers_the_sdk_through_a_pty():
    """The SO-101's simulated bus behind a pseudo-terminal, spoken to by Feetech's SDK: PING with the
    model number (777, the STS3215's), a READ, the STS SYNC READ of the six servos' Present
    Position (2048 at q = 0: zero_offset pi) and a WRITE the SDK sees answered."""
    from servodyn.hal.config import load_config
    from servodyn.sim.robot import SimulatedRobot
    from servodyn.sim.transport.pty import PtyServer

    robot = SimulatedRobot(load_config("so101"))
    with PtyServer(robot.port("arm"), "lockstep") as server:
        port, handler = sdk.PortHandler(server.path), sdk.PacketHandler(0)
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            for servo_id in range(1, 7):
                model, result, error = handler.ping(port, servo_id)
                assert (model, result, error) == (777, sdk.COMM_SUCCESS, 0)
            value, result, _ = handler.read1ByteTxRx(port, 3, ITEM["max_temperature_limit"].address)
            assert (value, result) == (70, sdk.COMM_SUCCESS)
            group = sdk.GroupSyncRead(port, handler, 56, 2)
            for servo_id in range(1, 7):
                group.addParam(servo_id)
            assert group.txRxPacket() == sdk.COMM_SUCCESS
            positions = [sdk.SCS_TOHOST(group.getData(i, 56, 2), 15) for i in range(1, 7)]
            assert all(abs(p - 2048) <= 1 for p in positions), positions
            assert handler.write1ByteTxRx(port, 2, ITEM["torque_enable"].address, 1)[0] == sdk.COMM_SUCCESS
            assert robot.servo(2).torque_enabled
            assert handler.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT      # no servo 9
        finally:
            port.closePort()


# ------------------------------------------------------------------------------ the C codec (firmware)

CODEC = Path(__file__).resolve().parent.parent / "hal" / "feetech" / "c"
u8p, size_t, u8 = ctypes.POINTER(ctypes.c_uint8), ctypes.c_size_t, ctypes.c_uint8
C_SIGNATURES = {
    "sts_ping": (size_t, [u8p, size_t, u8]),
    "sts_read": (size_t, [u8p, size_t, u8, u8, u8]),
    "sts_write": (size_t, [u8p, size_t, u8, u8, u8p, u8]),
    "sts_reg_write": (size_t, [u8p, size_t, u8, u8, u8p, u8]),
    "sts_action": (size_t, [u8p, size_t, u8]),
    "sts_sync_write": (size_t, [u8p, size_t, u8, u8, u8p, size_t, u8p]),
    "sts_sync_read": (size_t, [u8p, size_t, u8, u8, u8p, size_t]),
    "sts_encode_sm": (ctypes.c_int, [ctypes.c_int32, ctypes.c_uint, ctypes.POINTER(ctypes.c_uint16)]),
    "sts_decode_sm": (ctypes.c_int32, [ctypes.c_uint16, ctypes.c_uint]),
    "sts_reader_reset": (None, [ctypes.c_void_p]),
    "sts_reader_feed": (ctypes.c_int, [ctypes.c_void_p, u8]),
    "sts_reader_next": (ctypes.c_int, [ctypes.c_void_p]),
}


class CReader(ctypes.Structure):
    _fields_ = [("buf", ctypes.c_uint8 * 259), ("n", ctypes.c_size_t), ("id", ctypes.c_uint8),
                ("code", ctypes.c_uint8), ("nparam", ctypes.c_uint8), ("param", ctypes.c_uint8 * 253)]


@pytest.fixture(scope="module")
def sts(tmp_path_factory):
    """sts.c built with the system C compiler (warnings as errors) and loaded through ctypes."""
    cc = shutil.which("cc")
    if cc is None:
        pytest.fail("no C compiler: `cc` is not on PATH", pytrace=False)
    lib = tmp_path_factory.mktemp("sts_c") / "libsts.so"
    command = [cc, "-shared", "-fPIC", "-O2", "-std=c11", "-Wall", "-Wextra", "-Werror", "-o", str(lib),
               str(CODEC / "sts.c")]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        pytest.fail(f"building the C codec failed: {' '.join(command)}\n{done.stderr}", pytrace=False)
    so = ctypes.CDLL(str(lib))
    for name, (restype, argtypes) in C_SIGNATURES.items():
        getattr(so, name).restype, getattr(so, name).argtypes = restype, argtypes
    return so


def c_bytes(data) -> ctypes.Array:
    return (ctypes.c_uint8 * max(1, len(data)))(*data)


def built(call) -> bytes:
    out = (ctypes.c_uint8 * 512)()
    n = call(out, 512)
    return bytes(out[:n])


def test_c_builders_match_the_python_codec(sts):
    """Every instruction the C codec builds equals the Python codec's (itself the SDK's, above), over
    random IDs, addresses and data; a frame that does not fit its buffer or an ID past 0xFE is 0."""
    rng = random.Random(3215)
    for _ in range(300):
        servo_id, address = rng.randrange(0xFF), rng.randrange(256)
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 9)))
        assert built(lambda o, c: sts.sts_ping(o, c, servo_id)) == protocol.ping(servo_id)
        assert built(lambda o, c: sts.sts_read(o, c, servo_id, address, len(data))) == \
            protocol.read(servo_id, address, len(data))
        assert built(lambda o, c: sts.sts_write(o, c, servo_id, address, c_bytes(data), len(data))) == \
            protocol.write(servo_id, address, data)
        assert built(lambda o, c: sts.sts_reg_write(o, c, servo_id, address, c_bytes(data), len(data))) == \
            protocol.reg_write(servo_id, address, data)
        assert built(lambda o, c: sts.sts_action(o, c, servo_id)) == protocol.action(servo_id)
        ids = rng.sample(range(0xFD), rng.randrange(1, 12))
        size = rng.randrange(1, 5)
        per = {i: bytes(rng.randrange(256) for _ in range(size)) for i in ids}
        flat = b"".join(per[i] for i in ids)
        assert built(lambda o, c: sts.sts_sync_write(o, c, address, size, c_bytes(ids), len(ids), c_bytes(flat))) == \
            protocol.sync_write(address, size, per)
        assert built(lambda o, c: sts.sts_sync_read(o, c, address, size, c_bytes(ids), len(ids))) == \
            protocol.sync_read(address, size, ids)
    assert sts.sts_ping((ctypes.c_uint8 * 5)(), 5, 1) == 0 and sts.sts_ping((ctypes.c_uint8 * 6)(), 6, 0xFF) == 0


def test_c_sign_magnitude_matches_at_every_edge(sts):
    raw = ctypes.c_uint16()
    for bit in (10, 11, 15):
        top = (1 << bit) - 1
        for value in (0, 1, -1, top, -top, 77, -77):
            assert sts.sts_encode_sm(value, bit, ctypes.byref(raw)) == 1
            assert raw.value == encode_sign_magnitude(value, bit)
            assert sts.sts_decode_sm(raw.value, bit) == decode_sign_magnitude(raw.value, bit) == value
        assert sts.sts_encode_sm(top + 1, bit, ctypes.byref(raw)) == 0
        assert sts.sts_encode_sm(-(top + 1), bit, ctypes.byref(raw)) == 0
    for raw_value in (0x8000, 0x0C05, 0x0805, 0xFFFF):
        for bit in (10, 11, 15):
            assert sts.sts_decode_sm(raw_value, bit) == decode_sign_magnitude(raw_value, bit)


def test_c_reader_finds_what_the_python_reader_finds(sts):
    """Random streams of status packets, garbage, lone FFs, truncated frames and flipped bytes, fed
    byte by byte to the C reader: the packets (ID, error, parameters) the Python reader finds in the
    same bytes, in the same order."""
    rng = random.Random(101)
    reader = CReader()
    for _ in range(200):
        pieces = []
        for _ in range(rng.randrange(1, 8)):
            frame = bytearray(protocol.status(rng.randrange(0xFE), rng.choice((0, 0x20)),
                                              bytes(rng.randrange(256) for _ in range(rng.randrange(16)))))
            kind = rng.random()
            if kind < 0.15:
                frame = frame[:rng.randrange(2, len(frame))]
            elif kind < 0.3:
                frame[rng.randrange(2, len(frame))] ^= 1 << rng.randrange(8)
            elif kind < 0.45:
                frame = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 6))) + b"\xff" + frame
            pieces.append(bytes(frame))
        stream = b"".join(pieces)
        expected = [(p.id, p.code, p.params) for p in PacketReader().feed(stream) if isinstance(p, Packet)]
        found = []
        sts.sts_reader_reset(ctypes.byref(reader))
        for byte in stream:
            state = sts.sts_reader_feed(ctypes.byref(reader), byte)
            while state == 1:
                found.append((reader.id, reader.code, bytes(reader.param[:reader.nparam])))
                state = sts.sts_reader_next(ctypes.byref(reader))
        assert found == expected
