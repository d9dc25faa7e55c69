"""The per-tick fast paths give what the general code gives: the simulator's fast read reply
filled in place, the reader's repeated packet, the units of a reading, the torque command, and
the real-time helpers leave the process as they found it. Nothing here is timed."""

import gc
import os

import numpy as np
import pytest

from servodyn.hal import realtime
from servodyn.hal import JointCommand, load_config
from servodyn.hal.dynamixel import (ALERT_BIT, ErrorNumber, FastReadBlock, PacketReader,
                                    encode_fast_reply)
from servodyn.hal.dynamixel import instructions as inst
from servodyn.hal.dynamixel.control_table import ADDR_PRESENT, PRESENT_LENGTH, TABLE_SIZE
from servodyn.hal.dynamixel.instructions import fast_reply_frame, seal_fast_reply
from servodyn.hal.dynamixel.units import ServoMap
from servodyn.sim.dynamixel import HardwareError, Servo, DynamixelWire

CONFIG = load_config("replica")


def _bus():
    servos = [Servo(servo_id=i, position=0.1 * i) for i in (1, 2, 3)]
    for k, servo in enumerate(servos):
        servo.set_present(0.3 * k - 0.2, 0.5 - k, 0.1 * k)
    return DynamixelWire(servos), servos


def _expected(servos, address, length, error=None):
    """The reply the general encoder makes of what each servo reads."""
    blocks = []
    for servo in servos:
        alert = ALERT_BIT if servo.alert else 0
        if error is not None and address + length > TABLE_SIZE:
            blocks.append(FastReadBlock(servo.id, error | alert, bytes(length)))
        else:
            blocks.append(FastReadBlock(servo.id, alert, servo.read(address, length)))
    return encode_fast_reply(blocks)


def test_a_fast_read_filled_in_place_is_the_encoded_reply():
    bus, servos = _bus()
    request = inst.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, [1, 2, 3]).encode()
    for step in range(3):                                  # the same frame reused, refilled
        for k, servo in enumerate(servos):
            servo.set_present(0.01 * step + k, -0.2 * step, 0.05 * k)
        assert bus.handle(request, 0.0) == _expected(servos, ADDR_PRESENT, PRESENT_LENGTH), \
            f"step {step}: the reply equals encode_fast_reply of each servo's registers"
    servos[1].set_hardware_error(HardwareError.OVERLOAD)
    reply = bus.handle(request, 0.0)
    assert reply == _expected(servos, ADDR_PRESENT, PRESENT_LENGTH) and reply[8 + 14] & ALERT_BIT, \
        "the alert bit in servo 2's error byte"
    beyond = inst.fast_sync_read(TABLE_SIZE - 2, 4, [1, 2, 3]).encode()
    assert bus.handle(beyond, 0.0) == _expected(servos, TABLE_SIZE - 2, 4, ErrorNumber.ACCESS), \
        "a read past the table: zeros and the access error, as the general path"


def test_a_silent_servo_cuts_the_filled_reply_where_its_block_begins():
    bus, servos = _bus()
    request = inst.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, [1, 2, 3]).encode()
    whole = bus.handle(request, 0.0)
    servos[1].silent = True
    cut = bus.handle(request, 0.0)
    assert cut == whole[:8 + PRESENT_LENGTH + 4], "servo 1's block only, the LEN still counting all three"
    servos[0].silent = True
    assert bus.handle(request, 0.0) == b"", "the first servo silent: nothing at all"


def test_seal_refuses_blocks_that_do_not_fit():
    frame = fast_reply_frame([1, 2], [4, 4])
    with pytest.raises(ValueError):
        seal_fast_reply(frame, [4, 40])
    for blocks in (2, 3, 7):       # short by one byte: each earlier block's CRC counts (the codec's
        short = fast_reply_frame(list(range(1, blocks + 1)), [4] * blocks)[:-1]     # fit check once
        with pytest.raises(ValueError):                                             # left them out and
            seal_fast_reply(short, [4] * blocks)                                    # wrote past the end)
    with pytest.raises(ValueError):
        seal_fast_reply(bytearray(5), [])                      # not even a header
    seal_fast_reply(frame, [4, 4])
    assert bytes(frame) == encode_fast_reply([FastReadBlock(1, 0, bytes(4)), FastReadBlock(2, 0, bytes(4))]), \
        "sealed in place = encoded"


def test_the_reader_gives_a_repeated_packet_again_and_parses_anything_else():
    reader = PacketReader(None)
    frame = inst.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, [1, 2]).encode()
    first, again = reader.feed(frame), reader.feed(frame)
    assert first == again and len(first) == 1, "the same chunk: the same one packet"
    write = inst.sync_write(102, 2, {1: b"\x01\x00", 2: b"\x02\x00"}).encode()
    assert [reader.feed(write), reader.feed(frame)] == [reader.feed(write), first], \
        "a request and a command in turn, each as itself"
    assert reader.feed(frame[:5]) == [] and reader.feed(frame[5:]) == first, "a split frame is parsed"
    other = inst.ping(3).encode()
    assert reader.feed(frame[:3] + other) != first, "bytes that only begin like it are parsed"


def test_a_reading_in_si_is_the_four_conversions():
    units = ServoMap.from_joints(CONFIG.joints)
    rng = np.random.default_rng(7)
    for _ in range(200):
        position = rng.integers(-2 ** 31, 2 ** 31, 7).astype("<i4")
        velocity = rng.integers(-2 ** 20, 2 ** 20, 7).astype("<i4")
        current = rng.integers(-2 ** 15, 2 ** 15, 7).astype("<i2")
        fused = units.state_from_units(position, velocity, current)
        apart = (units.from_ticks(position), units.from_velocity_units(velocity),
                 units.current_from_units(current), units.from_current_units(current))
        assert all(np.array_equal(a, b) for a, b in zip(fused, apart)), "bit for bit"
        tau = rng.normal(0.0, 8.0, 7)
        limit = np.array([j.current_limit for j in CONFIG.joints])
        wanted = units.current(tau)
        clipped = np.clip(wanted, -limit, limit)
        expected = np.rint(units.direction * clipped / units.current_unit).astype(np.int64), clipped != wanted
        got = units.goal_current_units(tau, limit)
        assert all(np.array_equal(a, b) for a, b in zip(got, expected)), "goal units and limiting as np.clip's"


def test_a_torque_command_is_the_general_one():
    tau = np.linspace(-3.0, 4.0, 7)
    fast, general = JointCommand.torque(tau), JointCommand(q=0.0, qd=0.0, tau_ff=tau, kp=0.0, kd=0.0)
    for name in ("q", "qd", "tau_ff", "kp", "kd"):
        assert np.array_equal(getattr(fast, name), getattr(general, name)), name
    tau[0] = 99.0
    assert fast.tau_ff[0] == -3.0, "the command holds a copy"
    with pytest.raises(ValueError, match="'tau_ff' is not finite"):
        JointCommand.torque(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="one length"):
        JointCommand.torque(np.ones((2, 7)))


def test_realtime_priority_is_given_back(monkeypatch, capsys):
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no POSIX scheduling here")
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    with realtime.realtime_priority(10) as granted:
        if granted:
            assert os.sched_getscheduler(0) == os.SCHED_FIFO, "SCHED_FIFO inside"
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before, "the policy given back"

    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(realtime.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime, "_refused", set())
    for _ in range(2):
        with realtime.realtime_priority(10, "the test loop") as granted:
            assert granted is False
    assert capsys.readouterr().err.count("SCHED_FIFO not allowed") == 1, "one line, once"


def test_the_collector_is_paused_and_given_back():
    enabled = gc.isenabled()
    try:
        gc.enable()
        with realtime.collector_paused():
            assert not gc.isenabled(), "no collection inside"
        assert gc.isenabled(), "enabled again"
        gc.disable()
        with realtime.collector_paused():
            pass
        assert not gc.isenabled(), "left off if it was off"
    finally:
        (gc.enable if enabled else gc.disable)()


class _Signal(Exception):
    """Stands for the exception a signal handler raises between two steps."""


@pytest.mark.parametrize("where", ["format", "write", "flush"])
def test_a_signal_anywhere_in_the_log_leaves_each_row_once(tmp_path, where):
    """A row being formatted, a write done but not yet recorded, a flush cut short: close()
    still puts every logged row in the file exactly once."""
    from types import SimpleNamespace

    from servodyn import loop
    log = loop.RunLog(("a", "b"))
    path = tmp_path / "log.csv"
    log.stream(path, flush_every=0.0)            # a flush after every row
    state = SimpleNamespace(q=np.zeros(2), qd=np.ones(2), current=np.zeros(2))
    for k in range(5):
        log.add(k * 1e-3, np.zeros(2), state, np.zeros(2), 0.0, 0.0, 0.0, 0.0)
    calls = {"n": 0}

    def once(real):
        def cut(*args):
            calls["n"] += 1
            if calls["n"] == 1:
                if where == "format":
                    raise _Signal()
                real(*args)
                raise _Signal()       # after the call did its work
            return real(*args)
        return cut
    if where == "format":
        log._line = once(log._line)
    elif where == "write":
        log._file.write = once(log._file.write)
    else:
        log._file.flush = once(log._file.flush)
    with pytest.raises(_Signal):
        log.add(5e-3, np.zeros(2), state, np.zeros(2), 0.0, 0.0, 0.0, 0.0)
    log.close()
    lines = path.read_text().splitlines()
    assert lines[0].startswith("t,") and [line.split(",")[0] for line in lines[1:]] == \
        [f"{k * 1e-3:.9g}" for k in range(6)], f"every row once, in order ({where})"


@pytest.mark.parametrize("cut_after", ["q_d", "current", "process_cpu_seconds"])
def test_a_signal_inside_add_drops_that_row_whole(tmp_path, cut_after):
    """A signal's exception between two of add()'s appends (SIGTERM during a swing's tick, seen
    in a full suite run: close() then raised IndexError on the ragged row, a traceback instead of
    exit 143): the row is not counted, the file and every column hold the whole rows only."""
    from types import SimpleNamespace

    from servodyn import loop
    log = loop.RunLog(("a", "b"))
    path = tmp_path / "log.csv"
    log.stream(path, flush_every=0.0)
    state = SimpleNamespace(q=np.zeros(2), qd=np.ones(2), current=np.zeros(2))
    for k in range(3):
        log.add(k * 1e-3, np.zeros(2), state, np.zeros(2), 0.0, 0.0, 0.0, 0.0)
    # add()'s appends up to `cut_after`, then the signal: in the order add() makes them
    order = ["q_d", "q", "qd", "tau", "current", "tick_seconds", "tick_start", "cpu_seconds", "process_cpu_seconds"]
    for name in order[:order.index(cut_after) + 1]:
        getattr(log, name).append(np.zeros(2) if name in ("q_d", "q", "qd", "tau", "current") else 0.0)
    log.close()
    lines = path.read_text().splitlines()
    assert [line.split(",")[0] for line in lines[1:]] == [f"{k * 1e-3:.9g}" for k in range(3)], \
        f"the three whole rows, not the cut one ({cut_after})"
    assert {len(getattr(log, name)) for name in order + ["t"]} == {3}, "every column as long as t"
