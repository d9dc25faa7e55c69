"""The simulated CAN motors behind an SLCAN adapter on a pseudo-terminal (sim/transport/can.py),
driven from another process by python-can's own slcan interface, as a user's program would: the
open handshake, frames both ways (enable, an MIT command, a register read), the adapter's
version, garbage lines refused with BEL while the adapter keeps working; a host that writes without
reading (the adapter drops what does not fit and goes on); and the CAN backend through the same
adapter."""

import json
import re
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from servodyn.hal.bus import JointCommand, make_bus
from servodyn.hal.can import frames
from servodyn.hal.config import load_config
from servodyn.hal.robot import Robot
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.can import SlcanServer
from servodyn.hal.ports import PTY_REPLY_TIMEOUT

from helpers import sim_process

CLIENT = textwrap.dedent(r'''
    import json, struct, sys, time
    import can, serial
    path = sys.argv[1]
    out = {}
    bus = can.Bus(interface="slcan", channel=path, bitrate=1000000)
    out["version"] = bus.get_version(2.0)

    def ask(arbitration_id, data):
        bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            msg = bus.recv(0.5)
            if msg is not None:
                return [msg.arbitration_id, bytes(msg.data).hex()]
        return None

    out["enable"] = ask(0x001, bytes([0xFF] * 7 + [0xFC]))
    # an MIT command to motor 5: p 0, v 0, kp 0, kd 0, t code 2047 + 100
    out["command"] = ask(0x005, bytes([0x7F, 0xFF, 0x7F, 0xF0, 0x00, 0x00, 0x08, 0x63]))
    out["register"] = ask(0x7FF, bytes([0x06, 0x00, 0x33, 23, 0, 0, 0, 0]))
    bus.shutdown()
    raw = serial.Serial(path, timeout=0.5)
    raw.write(b"garbage\rS9\rt12Z\rt0018FFFFFFFFFFFFFFFC\r")
    time.sleep(0.3)
    out["raw"] = raw.read(raw.in_waiting or 1).decode("ascii", "replace")
    raw.write(b"O\rt0018FFFFFFFFFFFFFFFD\r")
    time.sleep(0.3)
    out["after"] = raw.read(raw.in_waiting or 1).decode("ascii", "replace")
    raw.close()
    print(json.dumps(out))
''')


FLOOD = textwrap.dedent(r'''
    import json, sys, time
    import can
    path, frames = sys.argv[1], int(sys.argv[2])
    bus = can.Bus(interface="slcan", channel=path, bitrate=1000000)
    enable = bytes([0xFF] * 7 + [0xFC])
    for _ in range(frames):              # python-can's send blocks while the adapter does not read
        bus.send(can.Message(arbitration_id=1, data=enable, is_extended_id=False))
    stale, begun = 0, time.monotonic()
    while bus.recv(0.25) is not None and time.monotonic() - begun < 30:
        stale += 1                       # what the adapter kept for us while we did not read
    sent = time.monotonic()
    bus.send(can.Message(arbitration_id=7, data=enable, is_extended_id=False))
    reply = None
    while reply is None and time.monotonic() - sent < 10:
        msg = bus.recv(0.5)
        if msg is not None and msg.arbitration_id == 0x17:
            reply = time.monotonic() - sent
    bus.shutdown()
    print(json.dumps({"stale": stale, "reply_s": reply}))
''')


@pytest.fixture
def adapter():
    arm = SimulatedRobot(load_config("replica_can"))
    server = SlcanServer(arm.port(), mode="realtime", on_error=lambda m: None)
    server.start()
    yield arm, server
    server.stop()


def test_python_can_in_another_process_drives_the_simulated_motors(adapter):
    arm, server = adapter
    done = subprocess.run([sys.executable, "-c", CLIENT, server.path], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"the python-can client failed:\n{done.stderr[-2000:]}"
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["version"] == [10, 13], "V answered as Vhhss"
    arbitration_id, data = out["enable"]
    assert arbitration_id == 0x11 and bytes.fromhex(data)[0] == 0x11, \
        "motor 1 answers on its feedback id 0x11 with status 1 (enabled) and id 1 in byte 0"
    arbitration_id, data = out["command"]
    assert arbitration_id == 0x15 and len(bytes.fromhex(data)) == 8, "motor 5 answers an MIT frame on 0x15"
    arbitration_id, data = out["register"]
    reply = frames.unpack_register(bytes.fromhex(data))
    assert arbitration_id == 0x16 and (reply.can_id, reply.cmd, reply.rid) == (6, 0x33, 23), "register echo"
    assert reply.as_float == 10.0, "TMAX of a DM-J4310"
    # after python-can's shutdown (C) the adapter is closed: garbage and frames get BEL (the
    # acknowledgement of C itself may still be waiting, unread by python-can)
    assert out["raw"].lstrip("\r") == "\a\a\a\a", f"closed adapter refuses garbage, S9, a bad frame, a frame: {out['raw']!r}"
    assert out["after"].startswith("\rz\rt011"), f"open again, the adapter acks and motor 1 answers: {out['after']!r}"
    assert not arm.motor(1).enabled, "motor 1 took the exit frame sent as a raw line"
    assert server.refused >= 4 and server.errors == 0


def test_a_host_that_does_not_read_never_stops_the_adapter(adapter):
    """5,000 frames written without reading (~1,500 filled the pseudo-terminal, and the adapter,
    blocked on its write, stopped reading: the client's send hung for ever). Now what does not fit
    is dropped and counted as a real adapter's overflow, and once the client reads again a new
    frame is answered at once."""
    arm, server = adapter
    frames_sent = 5000
    try:
        done = subprocess.run([sys.executable, "-c", FLOOD, server.path, str(frames_sent)], capture_output=True,
                              text=True, timeout=60)      # the flood takes ~0.1 s here, unloaded
    except subprocess.TimeoutExpired:
        pytest.fail("the client hung: the adapter stopped reading while its answers went unread")
    assert done.returncode == 0, f"the python-can client failed:\n{done.stderr[-2000:]}"
    out = json.loads(done.stdout.strip().splitlines()[-1])
    # 10 s of patience for a reply that takes under 1 ms here: only a deaf adapter misses it
    assert out["reply_s"] is not None, f"no answer to a fresh frame once the client read again: {out}"
    assert server.lines >= frames_sent + 1, f"the adapter read every line: {server.lines}"
    # each answer is ~24 bytes: the pseudo-terminal and OUT_QUEUE hold a few hundred of 5,000
    assert server.dropped > frames_sent // 2, f"most of the unread answers dropped: {server.dropped}"
    assert out["stale"] + server.dropped == frames_sent, \
        f"every motor frame either kept for the client or counted as dropped: {out['stale']} + {server.dropped}"
    assert server.line(b"F") == b"F08\r" and server.line(b"F") == b"F00\r", "a data overrun, reported once"
    assert server.errors == 0


def test_the_can_backend_through_the_slcan_adapter():
    arm = SimulatedRobot(load_config("replica_can"))
    with SlcanServer(arm.port(), mode="lockstep") as server:
        # as patient as the swing with a simulated bus: 0.5 s was once too short on a loaded machine
        bus = make_bus(arm.config, port=server.path, reply_timeout=PTY_REPLY_TIMEOUT["can"])
        try:
            bus.open()
            bus.enable_torque(True)
            for _ in range(30):
                bus.read_state()
                bus.write(JointCommand.position(np.full(7, 0.2), kp=3.0, kd=0.03))
            bus.read_state()
            assert arm.time == pytest.approx(30 * arm.period, abs=1e-9), \
                f"one control period ({arm.period * 1e3:g} ms) per round of 7 command frames: {arm.time} s"
            assert bus.stop() is True, "every motor confirmed the exit"
        finally:
            bus.stop()
    assert not any(m.enabled for m in arm.motors)
    assert server.refused == 0, "python-can's open sequence (C, S8, empty line, O) is all accepted"


def test_servodyn_sim_serves_replica_can_to_another_process():
    with sim_process("--config", "replica_can", "--lockstep") as (_, banner):
        line = banner[0]
        assert "SLCAN adapter" in line and "7->0x17 DM-J4310" in line, f"the served bus described: {line!r}"
        path = line.rsplit(" on ", 1)[-1].strip()
        client = textwrap.dedent('''
            import sys, can
            bus = can.Bus(interface="slcan", channel=sys.argv[1], bitrate=1000000)
            bus.send(can.Message(arbitration_id=7, data=bytes([0xFF] * 7 + [0xFC]), is_extended_id=False))
            msg = bus.recv(5.0)
            bus.shutdown()
            print(hex(msg.arbitration_id), bytes(msg.data).hex())
        ''')
        done = subprocess.run([sys.executable, "-c", client, path], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr[-1500:]
        arbitration_id, data = done.stdout.split()
        assert arbitration_id == "0x17" and data[:2] == "17", f"motor 7 enabled answers on 0x17: {done.stdout}"


def test_servodyn_sim_serves_a_mixed_robot_to_another_process():
    """`servodyn sim --config replica_mixed`: the CAN shoulder behind an SLCAN adapter and the
    Dynamixel wrist on a second pseudo-terminal, one plant; the swing's own Robot drives both from
    this process, and in lock-step the plant moves one control period (2 ms) per tick of both."""
    # SIGINT as at a terminal: a job started in the background inherits it ignored
    ticks = 50
    with sim_process("--config", "replica_mixed", "--lockstep", ports=2,
                     preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)) as (sim, lines):
        lines.append(sim.stdout.readline())         # how to connect: one --port for each bus
        assert "SLCAN adapter" in lines[0] and "4->0x14 DM-J4340" in lines[0], lines
        assert "Dynamixel bus 'wrist'" in lines[1] and "servos 5, 6, 7" in lines[1], lines
        assert "--port shoulder=/dev/" in lines[2] and "--port wrist=/dev/" in lines[2], lines
        ports = dict(re.findall(r"--port (\w+)=(\S+)", lines[2]))
        config = load_config("replica_mixed")
        robot = Robot(config, options={name: {"port": path, "reply_timeout": 2.0} for name, path in ports.items()})
        try:
            robot.open()
            start = robot.read_state().q
            robot.enable_torque(True)
            for _ in range(ticks):
                state = robot.read_state()
                robot.write(JointCommand.position(start, kp=np.full(7, 3.0), kd=np.full(7, 0.03)))
            assert np.all(np.isfinite(state.q)) and np.abs(state.q - start).max() < 0.05, \
                f"all seven joints read and held: {state.q - start}"
        finally:
            assert robot.stop() is True, "both buses confirmed the safe stop"
            robot.close()
        sim.send_signal(signal.SIGINT)
        out, _ = sim.communicate(timeout=30)
    said = out.strip().splitlines()[-1]
    assert said == f"stopped after {ticks * config.control_period:.2f} s of simulated time", \
        f"one 2 ms period per tick of both buses: {said!r} {out[-500:]}"
