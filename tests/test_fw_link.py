"""The general firmware application (firmware/app/fw_link.c) as a Linux process: it boots with no
robot; the host loads the replica over the host link (a pseudo-terminal), streams the forehand's
knots within the controller's credits and commands the run, against the simulated Dynamixel bus on
another pseudo-terminal, lock-stepped (the plant advances one period per Goal Current write), so
every command is deterministic: each equals the host's double-precision controller's from the same
measured state within one servo unit (hil.replay, the agreement oracle of the generated firmware).
Then the silent-host watchdog, a robot the core's checks refuse, and a frame of another version."""

from __future__ import annotations

import os
import subprocess
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from servodyn.control.schedule import Segment, homing
from servodyn.control.timing import HOME_DURATION, SMALL_TIME_STEP
from servodyn.hal.config import load_config
from servodyn.hal.link import frame as fr
from servodyn.hal.link import messages as ms
from servodyn.hil import SYSTICK_HZ, FirmwareLink, replay, run_qemu_link
from servodyn.hal.dynamixel.units import ServoMap
from servodyn.loop import RunLog, summarize
from servodyn.loop.link_load import plan
from servodyn.loop.link_log import telemetry_log
from servodyn.loop.link_session import ControllerRefused, LinkSession
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.pty import PtyServer
from helpers import run_cli
from runs import run_swing

ROOT = Path(__file__).resolve().parent.parent
EXE = ROOT / "build" / "fw" / "native" / "servodyn-fw-link"
HOME_TICKS = round(HOME_DURATION / SMALL_TIME_STEP) + 1


@pytest.fixture(scope="module")
def exe():
    build = subprocess.run(["make", "--no-print-directory", "-s", str(EXE.relative_to(ROOT))], cwd=ROOT,
                           capture_output=True, text=True)
    assert build.returncode == 0, f"the build failed:\n{build.stdout}\n{build.stderr}"
    return EXE


class Controller:
    """The native link application against a fresh simulated replica whose every bus exchange is
    recorded; the host link on a pseudo-terminal."""

    def __init__(self, exe, config="replica"):
        self.config = load_config(config)
        self.arm = SimulatedRobot(self.config, small_time_step=SMALL_TIME_STEP).port()
        self.bus = FirmwareLink(self.arm)
        self.server = PtyServer(self.arm, "lockstep")
        self.server.start()
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        baud = next(iter(self.config.buses.values())).baud     # the bus's rate is the board's, not the link's
        self.proc = subprocess.Popen([str(exe), self.server.path, f"link={os.ttyname(self.slave)}", "reply_ms=5000",
                                      f"baud={baud}"],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.link = LinkSession(self.master)

    def close(self):
        if self.proc.returncode is not None:
            return "", ""
        self.proc.terminate()
        out, err = self.proc.communicate(timeout=10)
        self.server._drain()
        self.server.stop()
        os.close(self.master)
        os.close(self.slave)
        return out, err


@pytest.fixture
def controller(exe):
    c = Controller(exe)
    yield c
    c.close()


def assert_goals_agree(record, p, config: str = "replica") -> int:
    """Every Goal Current the controller wrote within 1 unit of the host's double controller fed the
    same measured states (hil.replay, the generated firmware's oracle) over homing then the motion,
    homing with the joints' gains, the motion with the knots' (the host's schedule); the largest
    difference, in servo units."""
    segments = lambda q0: (Segment("home", homing(q0, p.swing.q[0], HOME_DURATION, SMALL_TIME_STEP), p.hold_gains),
                           Segment("motion", p.swing, p.swing_gains))
    twin = replay(config, record, segments)
    n = len(twin["goals"])
    assert n == HOME_TICKS + len(p.swing.t), f"the replay covers homing and the motion ({n} ticks)"
    assert len(record.goals) >= n
    diff = np.abs(np.array(record.goals[:n]) - twin["goals"])
    assert diff.max() <= 1, f"goals differ by up to {diff.max()} units from the host's controller"
    return int(diff.max())


def play_until(c: Controller, p, done, timeout: float = 300.0):
    """Pump the link and stream the knots until done(telemetry) or the timeout (s of wall time)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        c.link.pump(0.005)
        c.link.stream(p)
        if c.link.last is not None and done(c.link.last):
            return c.link.last
        assert c.proc.poll() is None, f"the controller stopped: {c.proc.communicate()}"
    raise AssertionError(f"not done within {timeout} s: {c.link.last}")


def test_hello_answers_with_the_compiled_sizes(controller):
    reply = controller.link.hello(0x1234)
    assert (reply.nonce, reply.link_version, reply.real_bytes) == (0x1234, fr.VERSION, 4), "float build, version 1"
    assert (reply.max_body, reply.max_dof, reply.knot_slots) == (16, 16, 64), "FW_LINK_SIZES of firmware/posix/rules.mk"
    assert reply.board.rstrip("\0") == "posix" and reply.buses == 1 << ms.BUSES["dynamixel"], "no can=PATH: no CAN bus"
    assert ms.STATES[reply.state] == "idle", "it boots with no robot"


def test_the_forehand_streamed_over_the_link_is_the_host_controllers(controller):
    """The replica loaded, the forehand's 75 knots streamed through the 64-slot ring, home then
    play: every Goal Current within 1 unit of the host's double controller on the same measured
    state (homing with the joints' gains, then the motion with the knots' gains, which are the
    host's schedule), no tick starved, the motion done, then torque off."""
    c = controller
    p = plan(c.config, host_timeout_ms=60000)      # lock-step runs faster than the wall clock
    assert len(p.knots) > 64, "longer than the controller's ring: it streams"
    c.link.hello()
    assert c.link.load(p.messages).code == 0
    c.link.stream(p)
    c.link.command("home", p.home_ms)
    c.link.command("play")
    starved = []

    def done(t):
        starved.append(t.flags & ms.TM_STARVED)
        return t.flags & ms.TM_DONE or ms.STATES[t.state] in ("fault", "torque_off")
    last = play_until(c, p, done)
    assert last.fault == 0 and last.flags & ms.TM_DONE, f"the motion played to its end: {last}"
    assert not any(starved), "the ring never ran dry"
    c.link.command("torque_off")
    c.close()
    record = c.bus.record
    nswing = len(p.swing.t)
    assert_goals_agree(record, p)
    assert record.torque_off and all(not s.torque_enabled for s in c.arm.servos), "torque off on every servo"
    # the run's log from the telemetry, summarized as the Python loop's
    log = telemetry_log(c.config, c.link.telemetry)
    assert len(log.t) == nswing and log.t[-1] == pytest.approx((nswing - 1) * SMALL_TIME_STEP), "the motion's ticks"
    units = ServoMap.from_joints(c.config.joints)
    measured = np.array([units.from_ticks(r[:, 2]) for r in record.reads[1 + HOME_TICKS:1 + HOME_TICKS + nswing]])
    assert np.abs(np.array(log.q) - measured).max() <= 2.0 ** -13 + 1e-6, \
        "q logged is q read, to half telemetry's 2^-12 rad (and the controller's float)"
    assert np.abs(np.array(log.q_d) - p.swing.q).max() <= 2.0 ** -13 + 1e-5, \
        "q_d logged is the host's plan (to half 2^-12 rad, and the float knots)"
    summary = summarize(log, nswing, SMALL_TIME_STEP, False)
    assert summary["completed"] and summary["tracking_max_rad"] <= np.radians(5), summary


def test_a_silent_host_holds_at_once_and_switches_torque_off(controller):
    """The host keeps the controller alive through homing, then falls silent once the motion
    plays: the controller holds from the tick its 100 ms timeout ends (HOST_SILENT, state holding,
    the desired pose frozen) and switches torque off reaction_time (1 s) later, on every servo."""
    c = controller
    p = plan(c.config, host_timeout_ms=100)
    c.link.hello()
    c.link.load(p.messages)
    c.link.stream(p)
    c.link.command("home", p.home_ms)
    c.link.command("play")                     # telemetry every tick: HELLO's default
    deadline, alive = time.monotonic() + 120, None
    while c.link.last is None or ms.STATES[c.link.last.state] != "playing":
        assert time.monotonic() < deadline and c.link.last.fault == 0, c.link.last
        if alive is None or alive.answer is not None:
            alive = c.link.sender.send(ms.Command(command=ms.COMMANDS["keepalive"], arg=0))
        c.link.pump(0.002)
    c.link.wait(alive)
    sent_at = c.link.last.tick                 # the host's last frame reached the controller at or after it
    sendings = c.link.sender.sendings
    while ms.STATES[c.link.last.state] not in ("torque_off", "fault"):
        assert time.monotonic() < deadline, c.link.last
        c.link.pump(0.005)                     # reads; nothing in flight, so nothing is sent
    assert c.link.sender.sendings == sendings, "the host was silent"
    assert c.link.last.fault == 0, c.link.last
    tm = {t.tick: t for t in c.link.telemetry}
    silent = sorted(k for k, t in tm.items() if t.flags & ms.TM_HOST_SILENT)
    assert silent, "the controller noticed the silence"
    first = silent[0]
    assert 100 <= first - sent_at <= 400, f"held {first - sent_at} ticks after the host's last frame (timeout 100)"
    assert tm[first].state == ms.STATES.index("holding") and tm[first - 1].state == ms.STATES.index("playing"), \
        "playing until the timeout's tick, holding from it"
    held = [tm[k] for k in silent if tm[k].state == ms.STATES.index("holding")]
    assert len({tuple(j.q_d for j in t.joints) for t in held}) == 1, "the desired pose frozen while holding"
    off = min(k for k, t in tm.items() if t.state == ms.STATES.index("torque_off"))
    reaction = round(c.config.guards.reaction_time / SMALL_TIME_STEP)
    assert abs((off - first) - reaction) <= 1, f"torque off {off - first} ticks after holding (reaction {reaction})"
    c.close()
    assert c.bus.record.torque_off and all(not s.torque_enabled for s in c.arm.servos), "torque off on every servo"


def test_a_robot_the_core_refuses_is_refused_with_the_reason(controller):
    """A body without mass: COMMIT refused by sd_model_setup on the controller (stage model, code
    -6 SD_ERR_MASS, body 2), in one line; the controller stays idle and takes the good robot after."""
    c = controller
    p = plan(c.config)
    bodies = [m for m in p.messages if isinstance(m, ms.Body)]
    heavy = [m if m is not bodies[2] else ms.Body(**{**m.__dict__, "mass": 0.0}) for m in p.messages]
    c.link.hello()
    with pytest.raises(ControllerRefused) as refused:
        c.link.load(heavy)
    assert str(refused.value) == "the controller refused the robot: model check code -6, body 2"
    home = c.link.command("home", 100, check=False)
    assert (home.stage, home.code) == (0, -3), "no robot: HOME refused, not now"
    assert c.link.load(p.messages).code == 0, "the good robot loads after"


def test_a_frame_of_another_version_is_answered_with_its_code(controller):
    """A COMMAND framed as version 2: the controller answers RESULT code -11 for its SEQ and TYPE,
    in its own version 1 (which the host's decoder reads)."""
    c = controller
    c.link.hello()
    os.write(c.master, fr.encode(9, 0, ms.COMMAND, ms.pack(ms.Command(command=0, arg=0))[1], version=2))
    decoder, deadline, answer = fr.Decoder(), time.monotonic() + 5, None
    while answer is None and time.monotonic() < deadline:
        try:
            data = os.read(c.master, 4096)
        except BlockingIOError:
            time.sleep(0.005)
            continue
        for f in decoder.feed(data):
            if f.verdict == fr.FRAME and f.type == ms.RESULT:
                result = ms.unpack(ms.RESULT, f.payload)
                if result.seq == 9:
                    answer = result
    assert answer is not None, "answered"
    assert (answer.type, answer.stage, answer.code) == (ms.COMMAND, 0, -11), answer


def wait_state(c: Controller, *states: str, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while c.link.last is None or ms.STATES[c.link.last.state] not in states:
        assert time.monotonic() < deadline, f"not {states} within {timeout} s: {c.link.last}"
        c.link.pump(0.005)
    return c.link.last


def torque_off_seen(c: Controller, but=(), timeout: float = 5.0) -> bool:
    """Every servo (but those in `but`) has torque off, once the bus's bytes in flight are served."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(not s.torque_enabled for s in c.arm.servos if s.id not in but):
            return True
        c.link.pump(0.01)
    return False


def test_commands_and_a_fault_cleared(controller):
    """PLAY before HOME is refused (not now); TORQUE_OFF while homing switches every servo off; a
    servo that stops answering while homing is fault 10 (timeout) naming its joint, torque off;
    CLEAR_FAULT returns to loaded, and HOME sets the bus up again and homes; STOP holds for the
    safety table's reaction_time (1 s), then switches torque off."""
    c = controller
    p = plan(c.config, host_timeout_ms=60000)
    c.link.hello()
    c.link.load(p.messages)
    c.link.stream(p)
    c.link.pump(0.05)
    play = c.link.command("play", check=False)
    assert (play.stage, play.code) == (0, -3), "PLAY before HOME: not now"
    c.link.command("home", p.home_ms)
    wait_state(c, "homing")
    c.link.command("torque_off")
    wait_state(c, "torque_off")
    assert torque_off_seen(c), "torque off on every servo"
    c.link.command("home", p.home_ms)
    wait_state(c, "homing")
    c.server.inject_fault(5, "silent")
    t = wait_state(c, "fault")
    joint = [j.id for j in c.config.joints].index(5)
    assert (t.fault, t.fault_joint) == (10, joint), f"timeout, servo 5's joint: {t}"
    assert torque_off_seen(c, but=(5,)), "torque off on every servo that answers"
    c.server.clear_faults()
    c.link.command("clear_fault")
    assert ms.STATES[wait_state(c, "loaded").state] == "loaded" and c.link.last.fault == 0
    c.link.command("home", p.home_ms)
    assert ms.STATES[wait_state(c, "homing").state] == "homing", "homing again after the fault"
    c.link.command("stop")                     # the replica's reaction: hold, then torque off
    held = wait_state(c, "holding", "torque_off")
    off = wait_state(c, "torque_off")
    reaction = round(c.config.guards.reaction_time / SMALL_TIME_STEP)
    assert ms.STATES[held.state] == "holding" and abs(off.tick - held.tick - reaction) <= 2, \
        f"STOP held {off.tick - held.tick} ticks before torque off (reaction {reaction})"
    assert torque_off_seen(c), "torque off on every servo after STOP"


def test_the_m4f_link_image_fits_the_boards_budget():
    """The Cortex-M4F image of the general application (8 bodies, 8 dofs, 32 knots) within the
    STM32F405 goals of issue 34: flash (text + data) <= 64 KB, RAM (data + bss, its 4 KB stack
    included) <= 32 KB; no heap, no stdio, no double arithmetic."""
    elf = ROOT / "build" / "fw" / "an386-link" / "servodyn-fw-link.elf"
    build = subprocess.run(["make", "--no-print-directory", "-s", str(elf.relative_to(ROOT))], cwd=ROOT,
                           capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    size = subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True)
    text, data, bss = (int(v) for v in size.stdout.splitlines()[1].split()[:3])
    assert text + data <= 64 * 1024, f"flash {text + data} B over 64 KB"
    assert data + bss <= 32 * 1024, f"RAM {data + bss} B over 32 KB"
    nm = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True).stdout
    names = {line.split()[-1] for line in nm.splitlines() if line.strip()}
    assert not names & {"malloc", "_sbrk", "printf", "puts", "__aeabi_dadd", "__aeabi_dmul", "__aeabi_f2d"}, \
        "no heap, no stdio, no double arithmetic"


@pytest.mark.slow
def test_the_link_application_under_qemu():
    """The same run on the Cortex-M4F image (build/fw/an386-link, sized 8 bodies, 8 dofs, 32 knots)
    under QEMU mps2-an386, the host link on UART2: every Goal Current within 1 unit of the host's
    double controller; the worst tick's instructions reported as the budget bench measures them
    (-icount shift 7, a 3 ms emulated period: 0.3125 instructions a SysTick count at 25 MHz), the
    link's work included, and the stack under the image's 4 KB."""
    build = subprocess.run(["make", "--no-print-directory", "-s", "build/fw/an386-link/servodyn-fw-link.elf"],
                           cwd=ROOT, capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    report, record, session, p = run_qemu_link(icount_shift=7, args="period_us=3000", timeout=900)
    assert (report["result"], report["exit_code"]) == ("done", 0), report
    assert_goals_agree(record, p)
    per_count = 1e9 / SYSTICK_HZ["an386"] / 2 ** 7
    worst = {k: round(report[k] * per_count) for k in ("worst_work", "worst_link", "worst_control", "mean_control")}
    print(f"worst tick instructions: {worst}, stack {report['stack']} bytes")
    assert 0 < report["stack"] < 4096 and worst["worst_work"] > 0


@pytest.mark.slow
def test_swing_controller_native_has_the_python_loops_summary(exe, tmp_path):
    """`servodyn swing --controller native`: the simulator in its process, the general application
    on its pseudo-terminal, loaded and streamed over the host link; the summary from its telemetry
    with the Python loop's keys, the forehand completed within the Python loop's tracking bound,
    torque off on every servo, the log of every tick of the motion."""
    summary = run_swing(out=tmp_path, controller="native")
    nswing = len(plan(load_config("replica")).swing.t)
    assert summary["completed"] and summary["loop"] == "native-link", summary.get("error")
    assert summary["ticks"] == nswing and summary["tracking_max_rad"] <= np.radians(5), summary
    one = RunLog(("a",))
    one.add(0.0, [0.0], type("S", (), {"q": np.zeros(1), "qd": np.zeros(1), "current": np.zeros(1)})(),
            [0.0], 1e-4, 0.0, 1e-4, 1e-4)
    keys = set(summarize(one, 1, SMALL_TIME_STEP, False)) | {"motion", "mode", "time_scale", "validated", "bus",
                                                              "loop", "torque_off", "link"}
    assert keys <= set(summary), f"missing: {keys - set(summary)}"
    assert all(summary["torque_off"]) and summary["exit_code"] == 0
    assert summary["link"]["lost_from_controller"] == 0, "lock-step: every telemetry frame arrives"
    assert (tmp_path / "swing_log.csv").read_text().count("\n") == 1 + nswing


def test_swing_controller_native_refuses_what_it_cannot_drive(tmp_path):
    """A Feetech arm (the SO-101, at a time scale its validation passes): one line, exit 2, before
    anything moves."""
    result = run_cli("swing", "--config", "so101", "--controller", "native", "--time-scale", "1.5", "--out",
                     tmp_path / "out")
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "--controller native: the controller's application drives a Dynamixel bus, a CAN " \
        "bus or one of each" in lines[0], result.stderr
