"""The general firmware application (firmware/app/fw_link.c) driving CAN motors as a Linux process:
the CAN bus through an SLCAN adapter on a pseudo-terminal (the simulator's, sim/transport/can.py:
the Lawicel lines python-can and CANable adapters speak), the MIT codec of hal/can/c; the mixed arm's
Dynamixel bus beside it, both in one tick. Lock-stepped (the plant advances one period once every
bus has had its tick's commands), so every command is deterministic: each one the controller sent
(a CAN motor's MIT torque field, a Dynamixel's Goal Current) is checked against the host's
double-precision controller fed the same measured state (the answers the controller read), within
one unit of that servo's or motor's command. Then a silent motor: a fault naming its joint."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from servodyn.control import ControlConfig, Controller
from servodyn.control.schedule import Segment, homing
from servodyn.control.timing import HOME_DURATION
from servodyn.hal.can import frames
from servodyn.hal.can.dialects import DIALECTS, REG_TIMEOUT
from servodyn.hal.config import load_config
from servodyn.hal.dynamixel.units import ServoMap
from servodyn.hal.link import messages as ms
from servodyn.hil import FirmwareLink
from servodyn.loop import tick
from servodyn.loop.link_load import plan
from servodyn.loop.link_log import TORQUE_BITS
from servodyn.loop.link_session import LinkSession
from servodyn.loop.native_link import bus_arguments
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.can import SlcanServer
from servodyn.sim.transport.pty import PtyServer
from runs import run_swing

ROOT = Path(__file__).resolve().parent.parent
EXE = ROOT / "build" / "fw" / "native" / "servodyn-fw-link"


@pytest.fixture(scope="module")
def exe():
    build = subprocess.run(["make", "--no-print-directory", "-s", str(EXE.relative_to(ROOT))], cwd=ROOT,
                           capture_output=True, text=True)
    assert build.returncode == 0, f"the build failed:\n{build.stdout}\n{build.stderr}"
    return EXE


class CanRecord:
    """Every frame the controller put on a simulated CAN bus, with the motors' answers to it."""

    def __init__(self, port):
        self.frames = []
        handle = port.handle

        def recorded(arbitration_id, data):
            answers = handle(arbitration_id, data)
            self.frames.append((arbitration_id, bytes(data), list(answers)))
            return answers
        port.handle = recorded


class Arm:
    """The native link application against a fresh simulated robot, each bus served on its
    pseudo-terminal (a Dynamixel bus recorded by hil.FirmwareLink, a CAN bus as an SLCAN adapter
    recorded by CanRecord), the host link on another."""

    def __init__(self, exe, config: str, *arguments: str):
        self.config = load_config(config)
        self.robot = SimulatedRobot(self.config)
        self.servers, self.dxl, self.can, buses = [], None, None, {}
        for name, bus in self.config.buses.items():
            port = self.robot.port(name)
            if bus.kind == "can":
                self.can = CanRecord(port)
                server = SlcanServer(port, "lockstep")
            else:
                self.dxl = FirmwareLink(port)
                server = PtyServer(port, "lockstep")
            server.start()
            self.servers.append(server)
            buses[name] = {"port": server.path, "reply_timeout": 1.0}
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.proc = subprocess.Popen([str(exe), *bus_arguments(self.config, buses), f"link={os.ttyname(self.slave)}",
                                      *arguments],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.link = LinkSession(self.master)

    def close(self):
        if self.proc.returncode is None:
            self.proc.terminate()
            self.proc.communicate(timeout=10)
        for server in self.servers:
            server.stop()
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


@pytest.fixture
def arm(exe, request):
    a = Arm(exe, request.param)
    yield a
    a.close()


def play(a: Arm, p, done, timeout: float = 300.0):
    """Pump the link and stream the knots until done(telemetry) or the timeout (s of wall time)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        a.link.pump(0.005)
        a.link.stream(p)
        if a.link.last is not None and done(a.link.last):
            return a.link.last
        assert a.proc.poll() is None, f"the controller stopped: {a.proc.communicate()}"
    raise AssertionError(f"not done within {timeout} s: {a.link.last}")


def torque_code(data: bytes) -> int:
    """An MIT command frame's torque field (hal/can/frames.py's layout, bytes 6-7)."""
    return (data[6] & 0xF) << 8 | data[7]


def can_ticks(config, record: CanRecord):
    """Per command round of the CAN bus (one a tick): the state each motor had answered before it
    (what the controller read that tick: q, qd by joint) and the torque codes it sent (by joint)."""
    joints = {j.id: k for k, j in enumerate(config.joints) if config.buses[j.bus].kind == "can"}
    last, states, commands, round_ = {}, [], [], {}
    for arbitration_id, data, answers in record.frames:
        k = joints.get(arbitration_id)
        if k is None:
            continue
        if not frames.special(data):                     # a command frame
            if not round_:
                states.append(dict(last))
            round_[k] = torque_code(data)
            if len(round_) == len(joints):
                commands.append(round_)
                round_ = {}
        j = config.joints[k]
        for _, answer in answers:
            y = DIALECTS[j.options["dialect"]].unpack(j.options["ranges"], answer)
            scale = j.direction * j.gear_ratio               # hal/can/backend.py's CanBus._read
            last[k] = ((y.p - j.zero_offset) / scale, y.v / scale)
    return states, commands


def within_range(config, segment: Segment) -> Segment:
    """The segment as the controller plays it: a desired position outside its joint's range (the
    float32 limits the link carries) clamped to it, at rest (fw_step_clamp_plan's limiting; homing
    from a joint at rest a hair below a range that starts at 0 is clamped there)."""
    lo = np.array([np.float32(j.position_limits[0]) for j in config.joints], dtype=float)
    hi = np.array([np.float32(j.position_limits[1]) for j in config.joints], dtype=float)
    traj = segment.traj
    out = (traj.q < lo) | (traj.q > hi)
    q = np.clip(traj.q, lo, hi)
    return Segment(segment.name, dataclasses.replace(traj, q=q, qd=np.where(out, 0.0, traj.qd),
                                                     qdd=np.where(out, 0.0, traj.qdd)), segment.gains)


def host_commands(config, q, qd, segments) -> np.ndarray:
    """The host's double-precision controller on the measured q, qd of each tick (homing, then the
    motion, each within the joints' ranges), each torque as its joint's bus commands it: a
    Dynamixel's Goal Current units (ServoMap.goal_current_units, clamped at its current limit), a
    CAN motor's MIT torque code (frames.pack_command as hal/can/backend.py's CanBus sends it:
    torque alone)."""
    model = config.model
    controller = Controller(model, ControlConfig(mode="feedforward_pd", small_time_step=config.control_period,
                                                 **config.friction))
    can = [config.buses[j.bus].kind == "can" for j in config.joints]
    dxl = [k for k, c in enumerate(can) if not c]
    units = ServoMap.from_joints([config.joints[k] for k in dxl]) if dxl else None
    limit = [config.joints[k].current_limit for k in dxl]
    out, n = [], 0
    for segment in map(lambda s: within_range(config, s), segments(q[0])):
        controller.reset()
        for k in range(len(segment.traj.t)):
            if n >= len(q):
                break
            tau = tick(controller, segment, k, q[n], qd[n])
            row = np.zeros(len(can), dtype=int)
            if dxl:
                row[dxl] = units.goal_current_units(tau[dxl], limit)[0]
            for i, j in enumerate(config.joints):
                if can[i]:
                    scale = j.direction * j.gear_ratio
                    data, _ = frames.pack_command(j.options["ranges"], j.zero_offset, 0.0, 0.0, 0.0, tau[i] / scale)
                    row[i] = torque_code(data)
            out.append(row)
            n += 1
    return np.array(out)


def measured_and_sent(a: Arm, ticks: int):
    """The state the controller read at each of its first `ticks` ticks (by joint) and the command
    it sent, from both buses' records."""
    config, nj = a.config, len(a.config.joints)
    q, qd, sent = np.zeros((ticks, nj)), np.zeros((ticks, nj)), np.zeros((ticks, nj), dtype=int)
    if a.can is not None:
        states, commands = can_ticks(config, a.can)
        assert len(commands) >= ticks, f"{len(commands)} CAN rounds for {ticks} ticks"
        for n in range(ticks):
            for k, (qk, qdk) in states[n].items():
                q[n, k], qd[n, k] = qk, qdk
            for k, code in commands[n].items():
                sent[n, k] = code
    if a.dxl is not None:
        dxl = [k for k, j in enumerate(config.joints) if config.buses[j.bus].kind != "can"]
        units = ServoMap.from_joints([config.joints[k] for k in dxl])
        reads, goals = a.dxl.record.reads, a.dxl.record.goals
        assert len(goals) >= ticks and len(reads) >= ticks + 1, f"{len(goals)} Goal Current writes for {ticks} ticks"
        for n in range(ticks):          # reads[0] is HOME's, each tick's its own after it
            q[n, dxl] = units.from_ticks(reads[n + 1][:, 2])
            qd[n, dxl] = units.from_velocity_units(reads[n + 1][:, 1])
            sent[n, dxl] = goals[n]
    return q, qd, sent


@pytest.mark.parametrize("arm", ["replica_can", "replica_mixed"], indirect=True)
def test_every_command_is_the_host_controllers_on_the_same_state(arm):
    """The configuration loaded over the link (each CAN joint's dialect, reply id and MIT ranges
    checked on COMMIT), the forehand streamed, home then play in lock-step: the motion done without
    a fault, and every command of homing and the motion -- each CAN motor's 12-bit MIT torque code,
    each Dynamixel's Goal Current -- within 1 unit of the host's double controller on the state the
    controller read (its float arithmetic against double: a unit is 2 t_max / 4095 = 0.0137 N m of
    a DM-J4340, 2.69 mA of an XM430), then torque off on every motor and servo."""
    a = arm
    config = a.config
    p = plan(config, host_timeout_ms=60000)
    hello = a.link.hello()
    assert hello.buses & (1 << ms.BUSES["can"]), "the controller says it has a CAN bus (can=PATH)"
    assert a.link.load(p.messages).code == 0
    a.link.stream(p)
    a.link.command("home", p.home_ms)
    a.link.command("play")
    last = play(a, p, lambda t: t.flags & ms.TM_DONE or ms.STATES[t.state] in ("fault", "torque_off"))
    assert last.fault == 0 and last.flags & ms.TM_DONE, f"the motion played to its end: {last}"
    a.link.command("torque_off")
    a.link.pump(0.2)
    a.close()
    period = config.control_period
    home_ticks = round(HOME_DURATION / period) + 1
    ticks = home_ticks + len(p.swing.t)
    q, qd, sent = measured_and_sent(a, ticks)
    segments = lambda q0: (Segment("home", homing(q0, p.swing.q[0], HOME_DURATION, period), p.hold_gains),
                           Segment("motion", p.swing, p.swing_gains))
    want = host_commands(config, q, qd, segments)
    assert want.shape == sent.shape, f"the host's plan covers homing and the motion ({want.shape} vs {sent.shape})"
    diff = np.abs(sent - want)
    print(f"{config.name}: {ticks} ticks ({home_ticks} homing), commands within {diff.max()} unit(s) of the host's "
          f"({int((diff.max(axis=1) > 0).sum())} ticks with a unit off)")
    assert diff.max() <= 1, f"commands differ by up to {diff.max()} units from the host's controller"
    assert all(not d.torque_enabled for d in a.robot.drives), "torque off on every motor and servo"


@pytest.mark.parametrize("arm", ["replica_can"], indirect=True)
def test_a_silent_motor_is_a_timeout_fault_naming_its_joint(arm):
    """Motor 3 stops answering while homing: fault 10 (timeout) naming its joint (the shoulder
    rotation, joint 2), torque off; the other motors told to exit motor mode."""
    a = arm
    p = plan(a.config, host_timeout_ms=60000)
    a.link.hello()
    a.link.load(p.messages)
    a.link.stream(p)
    a.link.command("home", p.home_ms)
    deadline = time.monotonic() + 60
    while a.link.last is None or ms.STATES[a.link.last.state] != "homing":
        assert time.monotonic() < deadline, a.link.last
        a.link.pump(0.005)
    a.servers[0].inject_fault(3, "silent")
    t = play(a, p, lambda t: ms.STATES[t.state] == "fault", timeout=60)
    joint = [j.id for j in a.config.joints].index(3)
    assert (t.fault, t.fault_joint) == (10, joint), f"timeout, motor 3's joint: {t}"
    assert a.config.model.dof_names[t.fault_joint] == "r_shoulder_rotation"
    deadline = time.monotonic() + 5
    while any(d.torque_enabled for d in a.robot.drives if d.can_id != 3) and time.monotonic() < deadline:
        a.link.pump(0.01)
    assert not any(d.torque_enabled for d in a.robot.drives if d.can_id != 3), "the others out of motor mode"


@pytest.mark.parametrize("arm", ["replica_can"], indirect=True)
def test_a_damiao_motor_set_up_otherwise_is_refused_naming_its_joint(arm):
    """HOME checks each Damiao motor's registers as the host's backend does: motor 5 with TMAX 12
    N m where the configuration says 10 is fault 16 (setup) naming its joint (the forearm
    pronation), before any motor enters motor mode; the motors checked before it have their CAN
    timeout written (2,000 x 50 us = 0.1 s: a controller that stops leaves them limp)."""
    a = arm
    motor = next(iter(a.robot.networks.values())).motor(5)
    assert motor.ranges.t_max == 10.0
    motor.ranges = dataclasses.replace(motor.ranges, t_max=12.0)
    p = plan(a.config, host_timeout_ms=60000)
    a.link.hello()
    a.link.load(p.messages)
    a.link.stream(p)
    a.link.command("home", p.home_ms)
    t = play(a, p, lambda t: ms.STATES[t.state] == "fault", timeout=60)
    assert (t.fault, a.config.model.dof_names[t.fault_joint]) == (16, "r_forearm_pronation"), t
    assert not any(d.torque_enabled for d in a.robot.drives), "no motor entered motor mode"
    timeouts = [d.registers[REG_TIMEOUT] for d in a.robot.drives]
    assert timeouts[:4] == [2000] * 4 and timeouts[4:] == [0] * 3, timeouts


@pytest.mark.slow
@pytest.mark.parametrize("config", ["replica_can", "replica_mixed"])
def test_swing_controller_native_plays_can_and_mixed_arms(exe, tmp_path, config):
    """`servodyn swing --controller native --config replica_can | replica_mixed`: the simulator
    serves the CAN bus as an SLCAN adapter, the process drives it (and the mixed arm's Dynamixel
    bus) over the host link; the forehand completed within 5 degrees, every tick of the motion
    logged, torque off on every motor."""
    summary = run_swing(config, out=tmp_path, controller="native")
    nswing = len(plan(load_config(config)).swing.t)
    assert summary["completed"] and summary["loop"] == "native-link", summary.get("error")
    assert summary["ticks"] == nswing and summary["tracking_max_rad"] <= np.radians(5), summary
    assert all(summary["torque_off"]) and summary["exit_code"] == 0
