"""The Dynamixel backend (hal/dynamixel/backend.py) through dynamixel-sdk on the simulated bus
(sim/robot.py, lock-step): one fast sync read and one sync write per tick and their bytes on the
wire, a silent servo's truncated fast reply, values that need byte stuffing, hardware errors."""

import math
import os
import select
import time

import numpy as np
import pytest

from servodyn.hal import BusStallError, JointCommand, ServoHardwareError, ServoOperationError, ServoTimeoutError, make_bus
from servodyn.hal.config import load_config
from servodyn.hal.dynamixel import (BROADCAST_ID, FastReadBlock, Instruction, InstructionPacket, PacketReader,
                                    StatusPacket, crc16, decode_frame, encode_fast_reply, split_fast_reply)
from servodyn.hal.dynamixel import instructions as inst
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.pty import PtyServer
from servodyn.sim.dynamixel import HardwareError

from helpers import wait_until

sdk = pytest.importorskip("dynamixel_sdk")

CONFIG = load_config("replica")
IDS = [j.id for j in CONFIG.joints]                    # 1..7, shoulder out
PRESENT = (126, 10)                                     # Present Current(2), Velocity(4), Position(4)


def h(text: str) -> bytes:
    return bytes.fromhex(text)


class Sim:
    """The replica's simulated bus behind a pty in lock-step, the DynamixelBus open on it, and a
    record of every chunk the host sent and what the bus answered."""

    def __init__(self):
        self.arm = SimulatedRobot(CONFIG).port()
        self.server = PtyServer(self.arm, "lockstep")
        self.wire: list[tuple[bytes, bytes]] = []
        handle = self.arm.handle

        def recorded(data: bytes) -> bytes:
            reply = handle(data)
            self.wire.append((bytes(data), reply))
            return reply
        self.arm.handle = recorded
        self.server.start()
        self.bus = make_bus(CONFIG, port=self.server.path, reply_timeout=0.25)   # patient on a loaded machine
        self.bus.open()

    def sent(self) -> bytes:
        return b"".join(data for data, _ in self.wire)

    def received(self) -> bytes:
        return b"".join(reply for _, reply in self.wire)

    def instructions(self) -> list[InstructionPacket]:
        return [p for p in PacketReader(None).feed(self.sent()) if isinstance(p, InstructionPacket)]

    def until(self, count: int, timeout: float = 2.0) -> list[InstructionPacket]:
        """The instructions recorded once there are `count` of them: a sync write gets no answer,
        so the host goes on before the bus has taken it."""
        wait_until(lambda: len(self.instructions()) >= count, timeout, every=1e-3)
        return self.instructions()

    def servo(self, servo_id: int):
        return self.arm.bus.servo(servo_id)

    def close(self):
        try:
            self.bus.stop()
        finally:
            self.server.stop()


@pytest.fixture
def sim():
    served = Sim()
    yield served
    served.close()


# --- one tick on the wire ----------------------------------------------------------------------

def test_tick_is_one_fast_sync_read_and_one_sync_write(sim):
    """A tick sends a 21-byte fast sync read and a 35-byte sync write and gets one 106-byte reply;
    the measured state is the plant's to half an encoder tick."""
    bus = sim.bus
    bus.enable_torque(True)
    bus.read_state()
    bus.write(JointCommand.torque(np.zeros(7)))
    bus.read_state()                                     # a round trip: the bus has taken the write
    sim.wire.clear()
    state = bus.read_state()
    q_plant = sim.arm.q.copy()
    bus.write(JointCommand.torque(np.full(7, 0.05)))
    packets = sim.until(2)
    assert [p.instruction for p in packets] == [Instruction.FAST_SYNC_READ, Instruction.SYNC_WRITE], \
        "exactly two transactions"
    assert packets[0].id == BROADCAST_ID and packets[0].params == h("7E 00 0A 00 01 02 03 04 05 06 07"), \
        "addresses 126..135 (10 bytes) of servos 1..7"
    assert (len(sim.sent()), len(sim.received())) == (21 + 35, 106), "bytes host -> bus, bus -> host"
    assert bus.reply_size == 106, "the fast reply's size: the 8-byte header and seven 14-byte blocks"
    reply = decode_frame(sim.received())
    assert [b.id for b in split_fast_reply(reply, [10] * 7)] == IDS, "one block per servo, in request order"
    assert np.abs(state.q - q_plant).max() <= math.pi / 4096 + 1e-12, "Present Position rounds to a tick"


def test_tick_bytes_and_wire_limited_rate():
    """The figures of hal/README.md, from encoded packets: per tick 21 + 106 + 35 = 162 bytes,
    10 bits each on the wire (start, 8 data, stop), so at most 617 ticks/s at 1 Mbps and 2469 at
    4 Mbps; a plain sync read (seven 21-byte status packets) would allow 493 and 1970."""
    request = inst.fast_sync_read(*PRESENT, IDS).encode()
    reply = encode_fast_reply([FastReadBlock(i, 0, bytes(PRESENT[1])) for i in IDS])
    goals = inst.sync_write(102, 2, {i: bytes(2) for i in IDS}).encode()
    assert (len(request), len(reply), len(goals)) == (21, 106, 35), "fast sync read, its reply, Goal Current write"
    tick = len(request) + len(reply) + len(goals)
    assert tick == 162, "bytes per tick"
    assert (round(1e6 / (10 * tick)), round(4e6 / (10 * tick))) == (617, 2469), \
        "ticks per second the wire allows at 1 and 4 Mbps, 10 bits a byte"
    plain = len(inst.sync_read(*PRESENT, IDS).encode()) + len(IDS) * len(StatusPacket(1, 0, bytes(10)).encode())
    assert plain + len(goals) == 203, "21-byte sync read, seven 21-byte status packets, the 35-byte write"
    assert (round(1e6 / (10 * 203)), round(4e6 / (10 * 203))) == (493, 1970), \
        "ticks per second with a plain sync read at 1 and 4 Mbps"


def test_goal_current_sync_write_never_needs_stuffing():
    """Goal Current is 2 bytes after a 1-byte ID: FF FF FD would need an ID of 0xFD (253), which
    does not exist, so the tick's sync write is 35 bytes whatever the currents (here every
    16-bit value, each followed by every ID the replica uses)."""
    for value in range(-32768, 32768):
        data = value.to_bytes(2, "little", signed=True)
        body = inst.sync_write(102, 2, {i: data for i in IDS}).params
        assert b"\xFF\xFF\xFD" not in bytes([Instruction.SYNC_WRITE]) + body, value
    assert len(inst.sync_write(102, 2, {i: h("FF FF") for i in IDS}).encode()) == 35, \
        "Goal Current FF FF on every servo: nothing stuffed, still 35 bytes"


# --- a silent servo ------------------------------------------------------------------------------

def test_fast_reply_stops_at_the_silent_servo():
    """sim/dynamixel/wire.py: the chain's fast reply holds the blocks of the servos before the
    silent one (each 14 bytes after the 8-byte header), with the LEN of the whole reply; a silent
    first servo leaves nothing; a plain sync read only loses the silent servo's own packet."""
    arm = SimulatedRobot(CONFIG).port()
    request = inst.fast_sync_read(*PRESENT, IDS).encode()
    full = arm.handle(request)
    assert len(full) == 106, "every servo answers: the 8-byte header and seven 14-byte blocks"
    for silent, kept in ((4, 3), (7, 6), (1, 0)):
        arm.clear_faults()
        arm.inject_fault(silent, "silent")
        reply = arm.handle(request)
        assert len(reply) == (8 + 14 * kept if kept else 0), f"servo {silent} silent"
        assert reply == full[:len(reply)], "what came is the real reply's beginning"
        if kept:
            assert reply[5] | reply[6] << 8 == 99, "LEN still counts all seven blocks"
            for k in range(kept):                            # every block that came is whole
                end = 8 + 14 * k + 12
                assert reply[8 + 14 * k + 1] == IDS[k] and crc16(reply[:end]) == int.from_bytes(reply[end:end + 2], "little"), \
                    f"block {k}: servo {IDS[k]}'s ID, and the running CRC of the reply up to its end"
    arm.clear_faults()
    arm.inject_fault(4, "silent")
    plain = arm.handle(inst.sync_read(*PRESENT, IDS).encode())
    assert len(plain) == 6 * 21, "six 21-byte status packets: only silent servo 4's is missing"
    assert [decode_frame(plain[k:k + 21]).id for k in range(0, len(plain), 21)] == [1, 2, 3, 5, 6, 7], \
        "the others answer in turn"


def test_fast_bulk_reply_with_unequal_blocks_stops_at_the_silent_servo():
    """Blocks of 10, 4 and 1 data bytes: the boundaries come from the running CRCs."""
    arm = SimulatedRobot(CONFIG).port()
    request = inst.fast_bulk_read([(1, 126, 10), (2, 132, 4), (3, 64, 1)]).encode()
    assert len(arm.handle(request)) == 8 + 14 + 8 + 5, "header, then error, ID, data and CRC: 4 bytes + data each"
    arm.inject_fault(3, "silent")
    assert len(arm.handle(request)) == 8 + 14 + 8, "servo 3 silent: its 5-byte block is cut"


def test_silent_servo_is_named_after_the_retries(sim):
    """Servo 4 stops answering: every try of the fast sync read (1 + 2 retries) comes back cut after
    servo 3's block; the pings then name servo 4 (silent twice while the others answer, so not a
    stall of the whole bus) and ServoTimeoutError carries its joint."""
    bus = sim.bus
    bus.read_state()
    sim.server.inject_fault(4, "silent")
    sim.wire.clear()
    with pytest.raises(ServoTimeoutError) as caught:
        bus.read_state()
    err = caught.value
    assert (err.servo_id, err.joint) == (4, CONFIG.joints[3].dof), "servo 4 and its joint, the elbow flexion"
    assert "stopped after 3 of 7 blocks" in str(err) and "no answer to 3 pings" in str(err), str(err)
    packets = sim.instructions()
    kinds = [p.instruction for p in packets]
    assert kinds.count(Instruction.FAST_SYNC_READ) == 3 and bus.stats.reads_retried == 3, "one try and two retries"
    pings = {k: sum(p.instruction == Instruction.PING and p.id == k for p in packets) for k in range(1, 8)}
    # servo 4 is silent, so its count is exact; an answering servo whose reply a loaded machine
    # holds back past the 0.25 s timeout is pinged again (its retries: at most 3 in the second round)
    assert pings[4] == 1 + 3 + 3, \
        f"servo 4: one ping for a corrupt line, 3 unanswered, 3 more once the others answered: {pings}"
    assert all(2 <= pings[k] <= 1 + 3 for k in (1, 2, 3, 5, 6, 7)), \
        f"the others: one ping for a corrupt line, then answered within their 3 tries: {pings}"
    sim.server.clear_faults()
    assert bus.read_state().q.shape == (7,), "answers again: the next read succeeds"


@pytest.mark.parametrize("fault", ["garbage", "flipped_byte"])
def test_a_corrupt_line_is_an_operation_error_not_a_silent_servo(sim, fault):
    """Every reply garbled on the wire: after the retries the servos do answer a ping, with
    corrupt bytes; that is a corrupt line (ServoOperationError), not a servo that stopped."""
    bus = sim.bus
    bus.read_state()
    sim.server.inject_fault(1, fault)
    with pytest.raises(ServoOperationError, match="corrupt replies") as caught:
        bus.read_state()
    assert not isinstance(caught.value, ServoTimeoutError), str(caught.value)
    sim.server.clear_faults()
    assert bus.read_state().q.shape == (7,), "a clean line again: the next read succeeds"


def test_a_reply_later_than_its_timeout_is_dropped_not_taken_for_the_retry(sim):
    """Each fast read reply held back past the reply timeout: the late one is drained before the
    retry, so no reply is ever taken for a later request's (it would be a tick old); the read
    fails as a stall of the bus (nothing in time, the reply after its time-out)."""
    bus = sim.bus
    bus.read_state()
    sim.server.inject_fault(1, "delayed_reply")
    with pytest.raises(BusStallError, match="came after the time-out and were dropped"):
        bus.read_state()
    sim.server.clear_faults()
    assert bus.read_state().q.shape == (7,), "prompt replies again: the next read succeeds"


def _lose_fast_reads(sim, count: int) -> None:
    """The next `count` fast sync reads never reach the servos (a packet lost on the wire)."""
    request = inst.fast_sync_read(*PRESENT, IDS).encode()
    handle, left = sim.arm.handle, [count]

    def losing(data: bytes) -> bytes:
        if left[0] and request in data:
            left[0] -= 1
            return handle(data.replace(request, b""))
        return handle(data)
    sim.arm.handle = losing


def test_a_lost_request_within_the_watchdog_is_retried(sim):
    """With torque on, one fast sync read lost: nothing comes back, the try times out (0.25 s),
    the line is drained (0.25 s) and the retry is answered. The bus was silent ~0.5 s, within a
    Bus Watchdog of 2 s (servos and host alike), so it is a hiccup: the read succeeds."""
    bus = sim.bus
    bus.watchdog = 2.0          # the servos' too (armed by enable_torque), as long as a servo allows
    bus.enable_torque(True)
    bus.read_state()
    bus.write(JointCommand.torque(np.zeros(7)))
    _lose_fast_reads(sim, 1)
    state = bus.read_state()
    assert state.q.shape == (7,) and bus.stats.reads_retried == 1, "one try lost, the retry answered"


@pytest.mark.serial
def test_a_silence_longer_than_the_watchdog_is_a_stall(sim):
    """With torque on and the servos' 100 ms Bus Watchdog armed, every fast sync read lost: after
    the first try and its drain (0.25 s each) the bus has been silent longer than the watchdog, so
    the servos have let go (on real ones): BusStallError at once, naming the silence, no retry
    and no pings (three tries and seven servos' pings took seconds before, on a dead bus)."""
    bus = sim.bus
    bus.enable_torque(True)
    bus.read_state()
    bus.write(JointCommand.torque(np.zeros(7)))
    _lose_fast_reads(sim, 3)
    began = time.monotonic()
    with pytest.raises(BusStallError, match=r"silent for \d+ ms, longer than the servos' Bus Watchdog of 100 ms"):
        bus.read_state()
    assert bus.stats.reads_retried == 1, "stopped after the first failed try"
    # one try and one drain of 0.25 s each; 0.5 s more of slack for a loaded machine, far below
    # the ~3 s of three tries, three drains and the pings
    assert time.monotonic() - began < 1.5


# --- byte stuffing -------------------------------------------------------------------------------

def test_values_that_need_stuffing_arrive_intact_through_the_hal(sim):
    """Goal PWM -1 with Goal Current -515 is FF FF FD FD: DynamixelBus sends it stuffed (an FD
    inserted after FF FF FD) and the servo's registers hold exactly those values. Goal Position
    -131073 is FF FF FD FF. A Goal Current of -1 (FF FF) is followed by an ID, never by FD."""
    bus = sim.bus
    sim.wire.clear()
    bus.sync_write(100, {5: h("FF FF FD FD")})
    sim.until(1)
    assert b"\xFF\xFF\xFD\xFD\xFD" in sim.sent(), "stuffed on the wire"
    assert (sim.servo(5).get("goal_pwm"), sim.servo(5).get("goal_current")) == (-1, -515), \
        "little-endian FF FF is -1, FD FD is 0xFDFD = -515"
    bus.sync_write(116, {2: (-131073).to_bytes(4, "little", signed=True), 6: h("00 01 00 00")})
    sim.until(2)
    assert (sim.servo(2).get("goal_position"), sim.servo(6).get("goal_position")) == (-131073, 256), \
        "FF FF FD FF (stuffed) is -131073, 00 01 00 00 is 256"
    bus.enable_torque(True)
    bus.read_state()
    tau = bus.units.from_current_units(np.full(7, -1))      # -1 current unit on every servo
    bus.write(JointCommand.torque(tau))
    bus.read_state()
    assert [sim.servo(i).get("goal_current") for i in IDS] == [-1] * 7, "FF FF on every servo, each ID after it"


def test_the_sdk_alone_sends_it_unstuffed_and_the_servo_sees_another_packet(sim):
    """The same sync write through dynamixel-sdk's own packet handler: no FD inserted, so the
    servo removes the FD that follows FF FF FD as stuffing, finds 3 data bytes where 4 belong and
    drops the write: Goal PWM and Goal Current keep their values."""
    bus = sim.bus
    before = (sim.servo(5).get("goal_pwm"), sim.servo(5).get("goal_current"))
    sim.wire.clear()
    writer = sdk.GroupSyncWrite(bus.port, sdk.PacketHandler(2.0), 100, 4)
    writer.addParam(5, list(h("FF FF FD FD")))
    assert writer.txPacket() == sdk.COMM_SUCCESS, "the SDK reports success: a sync write has no reply"
    sim.until(1)
    assert b"\xFF\xFF\xFD\xFD\xFD" not in sim.sent() and b"\xFF\xFF\xFD\xFD" in sim.sent(), "sent unstuffed"
    seen = sim.instructions()[0]
    assert seen.params == h("64 00 04 00 05 FF FF FD"), "what the servo unstuffed: one byte short"
    assert (sim.servo(5).get("goal_pwm"), sim.servo(5).get("goal_current")) == before, \
        "the short write was dropped: servo 5's registers unchanged"


# --- hardware errors -----------------------------------------------------------------------------

@pytest.mark.parametrize("bits, faults, torque_stays", [
    (HardwareError.OVERLOAD, ("overload",), False),            # in Shutdown (default 52): torque cut
    (HardwareError.INPUT_VOLTAGE, ("input voltage",), True),   # not in Shutdown: alert only
])
def test_hardware_error_mid_run_names_servo_and_bit(sim, bits, faults, torque_stays):
    """A hardware error raised on servo 3 between two ticks: its block carries the alert bit, the
    backend reads Hardware Error Status (70), read_state raises with servo, joint and bits, and
    write refuses too (a sync write has no reply to carry the alert) while the alert stands."""
    bus = sim.bus
    bus.enable_torque(True)
    for _ in range(3):
        bus.read_state()
        bus.write(JointCommand.torque(np.zeros(7)))
    sim.server.inject_fault(3, int(bits))
    with pytest.raises(ServoHardwareError) as caught:
        bus.read_state()
    err = caught.value
    assert (err.servo_id, err.joint, err.status, err.faults) == (3, CONFIG.joints[2].dof, int(bits), faults), \
        "servo 3, its joint, Hardware Error Status and the bits' names"
    with pytest.raises(ServoHardwareError, match=r"\(id 3\)"):
        bus.write(JointCommand.torque(np.zeros(7)))
    assert sim.servo(3).torque_enabled is torque_stays, \
        "Shutdown 0x34 (overheating, electrical shock, overload) cuts torque; an input-voltage error does not"
    assert bus.stop(), "every servo still answers: torque off everywhere"
    assert not any(s.torque_enabled for s in sim.arm.servos), "stop() left a servo's torque on"


def test_an_answer_the_wire_cannot_carry_leaves_the_bus_answering():
    """A fast sync read of 10,000 bytes from each of the seven servos would need a reply of
    70,000 bytes, more than a 16-bit LEN can say: nobody answers, it is counted, and the next
    ping is answered as before (the simulator used to raise in its serving thread and go deaf)."""
    arm = SimulatedRobot(CONFIG).port()
    assert arm.handle(inst.fast_sync_read(0, 10_000, IDS).encode()) == b"", "no reply can be encoded"
    assert arm.bus.unanswerable == 1, "and the refusal is counted"
    assert decode_frame(arm.handle(inst.ping(1).encode())).id == 1, "the next ping is answered"


def test_the_pty_server_survives_an_exception_in_the_arm():
    """Whatever the arm raises while answering, the server reports it in one line and goes on."""
    arm = SimulatedRobot(CONFIG).port()
    seen = []
    server = PtyServer(arm, "lockstep", on_error=seen.append)
    handle = arm.handle
    calls = {"n": 0}

    def flaky(data):
        calls["n"] += 1
        if calls["n"] == 1:
            raise FloatingPointError("the plant diverged")
        return handle(data)
    arm.handle = flaky
    with server:
        fd = os.open(server.path, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, inst.ping(1).encode())
            assert wait_until(lambda: seen, timeout=5), "the first ping raised, and the server said so"
            os.write(fd, inst.ping(1).encode())
            reply = b""
            deadline = time.monotonic() + 5
            while len(reply) < 14 and time.monotonic() < deadline:
                ready, _, _ = select.select([fd], [], [], 0.1)
                if ready:
                    reply += os.read(fd, 64)
        finally:
            os.close(fd)
    assert server.errors == 1 and seen == ["simulated bus: FloatingPointError while answering the host: "
                                           "the plant diverged"], seen
    assert decode_frame(reply[:14]).id == 1, "the second ping was answered"
