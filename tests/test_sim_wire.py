"""The simulated Dynamixel bus as a wire behaves: the servos' receivers drop a frame whose bytes
stop for more than 1.5 ms, a stall of the whole bus is reported as one (not blamed on a servo),
and in real time the servos' Bus Watchdog runs on the wall clock, so a host that goes quiet
leaves them limp."""

import time

import pytest

from servodyn.hal import BusStallError, JointCommand, make_bus
from servodyn.hal.config import load_config
from servodyn.hal.dynamixel import PacketReader, StatusPacket
from servodyn.hal.dynamixel.reader import Fault
from servodyn.hal.dynamixel import instructions as inst
from servodyn.hal.dynamixel.control_table import WATCHDOG_UNIT
from servodyn.control.timing import BUS_WATCHDOG
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.pty import PtyServer

from helpers import wait_until

pytest.importorskip("dynamixel_sdk")

CONFIG = load_config("replica")


class WireClock:
    """A hand-set clock for the servos' receivers: the tests say when each chunk arrives."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _statuses(data: bytes) -> list:
    return [(e.id, e.error) for e in PacketReader(None).feed(data) if isinstance(e, StatusPacket)]


def test_the_pty_server_times_the_bytes_on_the_wall_clock():
    arm = SimulatedRobot(CONFIG).port()
    server = PtyServer(arm, "lockstep")
    try:
        assert arm.bus.wire_clock is time.monotonic and arm.bus.reader.byte_timeout == 1.5e-3, \
            "the servos' receivers time the pseudo-terminal's bytes on the wall clock, 1.5 ms apart at most"
    finally:
        server.stop()


def test_a_truncated_frame_then_silence_is_dropped_not_joined_to_the_next():
    """The first 9 bytes of a read of servo 2, 10 ms of silence, then a ping of servo 1: one
    reply, the ping's, without error (the truncated frame used to swallow the ping's bytes and
    get a spurious CRC-error status from servo 2). Within 1 ms the bytes still join up."""
    arm, clock = SimulatedRobot(CONFIG).port(), WireClock()
    arm.wire_clock(clock)
    assert arm.handle(inst.read(2, 132, 4).encode()[:9]) == b""
    clock.now += 0.010
    assert _statuses(arm.handle(inst.ping(1).encode())) == [(1, 0)], "only the ping's reply, no error"
    assert arm.bus.faults[Fault.TRUNCATED] == 1, "the truncated frame is counted"
    whole = inst.ping(5).encode()
    assert arm.handle(whole[:6]) == b""
    clock.now += 0.001
    assert _statuses(arm.handle(whole[6:])) == [(5, 0)], "a 1 ms gap inside a frame is not a timeout"


def test_a_header_announcing_1000_bytes_that_never_come_swallows_nothing():
    """A header with LEN 1000 and then ten pings, each after 5 ms: ten replies, one per ping (the
    frame used to swallow the next 99 pings, then 101 stale replies came at once)."""
    arm, clock = SimulatedRobot(CONFIG).port(), WireClock()
    arm.wire_clock(clock)
    assert arm.handle(bytes.fromhex("FFFFFD0001E803")) == b""
    answered = []
    for _ in range(10):
        clock.now += 0.005
        answered += _statuses(arm.handle(inst.ping(3).encode()))
    assert answered == [(3, 0)] * 10, f"{len(answered)} replies for 10 pings: {answered[:3]}"


def test_a_whole_bus_stall_is_not_blamed_on_one_servo():
    """The simulator paused for 300 ms while the host reads (80 ms per try, 3 tries, then pings):
    BusStallError naming the bus, no ServoTimeoutError naming the first servo pinged."""
    arm = SimulatedRobot(CONFIG).port()
    with PtyServer(arm, "lockstep") as server:
        bus = make_bus(CONFIG, port=server.path, reply_timeout=0.08)
        bus.open()
        try:
            bus.read_state()
            server.pause(0.3)
            with pytest.raises(BusStallError) as caught:
                bus.read_state()
            message = str(caught.value)
            assert message.startswith("bus 'arm' stalled: no servo answered"), message
            assert "did not answer" not in message and "joint" not in message, message
            assert bus.read_state().q.shape == (7,), "after the stall the bus answers again"
        finally:
            bus.stop()


def test_in_real_time_the_servos_clocks_are_the_wall_clock():
    """The plant may fall behind the wall clock on a loaded machine; the servos' own clocks (Bus
    Watchdog, Realtime Tick) do not wait for it."""
    arm = SimulatedRobot(CONFIG).port()
    server = PtyServer(arm, "realtime")          # not started: the plant stands at 0
    try:
        before = arm.bus.clock()
        time.sleep(0.05)
        assert arm.bus.clock() - before >= 0.05 and arm.time == 0.0, "the servos' clock moved, the plant did not"
    finally:
        server.stop()


def test_a_host_gone_quiet_finds_its_servos_limp():
    """A host that arms the Bus Watchdog, commands a current and then goes quiet (as if killed),
    the servos on the wall clock and the plant standing still: within the watchdog's time every
    servo has tripped it and dropped its Goal Current; the host's next read reports the stall."""
    arm = SimulatedRobot(CONFIG).port()
    with PtyServer(arm, "lockstep") as server:
        arm.wall_clock()
        bus = make_bus(CONFIG, port=server.path, reply_timeout=0.25)
        bus.open()
        try:
            bus.enable_torque(True)
            state = bus.read_state()
            units = arm.servos[0].get("bus_watchdog")
            assert units * WATCHDOG_UNIT == pytest.approx(BUS_WATCHDOG), "the HAL armed the watchdog"
            bus.write(JointCommand.torque(0.2 + 0 * state.q))
            sent = time.monotonic()      # the servos may have heard it up to a GIL switch (5 ms) earlier

            def all_tripped():           # the servos' clocks move on their bus's ticks
                arm.bus.tick()
                return all(s.get("bus_watchdog") == -1 for s in arm.servos)
            tripped = wait_until(all_tripped, timeout=5.0, every=0.002)
            took = time.monotonic() - sent
            assert tripped, "every servo's watchdog tripped"
            assert all(s.get("goal_current") == 0 for s in arm.servos), "and dropped its Goal Current"
            assert took >= BUS_WATCHDOG - 0.01, f"not before the watchdog's {BUS_WATCHDOG} s ({took:.3f} s)"
            # the host that comes back finds out: its goals would be refused until the watchdog is cleared
            with pytest.raises(BusStallError, match="over the servos' Bus Watchdog of 100 ms: servos 1, 2, 3, 4, 5, 6, 7"):
                bus.read_state()
        finally:
            bus.stop()
