"""The native loop: the firmware's application built for Linux (firmware/posix) against the
simulated Dynamixel bus on a pseudo-terminal, lock-stepped as the QEMU run is (the plant advances
one period per Goal Current write), so everything asserted is deterministic: the goals equal the
host's double-precision controller's on the same measurements within one unit, its log is what
crossed the bus, its safe stops and their codes are the firmware's. No rate is asserted."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from servodyn.control.timing import HOME_DURATION, SMALL_TIME_STEP
from servodyn.hal.config import load_config
from servodyn.hal.contact_spec import Push
from servodyn.hal.dynamixel.units import ServoMap
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.pty import PtyServer
from servodyn.hil import FirmwareLink, replay
from servodyn.loop.native import NATIVE, contact_detail, run_native
from runs import run_swing

from helpers import quiet

ROOT = Path(__file__).resolve().parent.parent
HOME_TICKS = round(HOME_DURATION / SMALL_TIME_STEP) + 1
SWING_TICKS = 7201
FAULT_TICK = 100
PUSH = Push("r_hand", (0.0, 0.0, -10.0), 0.3, 0.3)    # 10 N down at the hand, 0.3 s into the swing


@pytest.fixture(scope="module")
def native():
    build = subprocess.run(["make", "--no-print-directory", "-s", str(NATIVE.relative_to(ROOT))], cwd=ROOT,
                           capture_output=True, text=True)
    assert build.returncode == 0, f"the native build failed:\n{build.stdout}\n{build.stderr}"
    return NATIVE


def _run(args="", on_tick=None, realtime=False, reply_timeout=1.0):
    """The native loop against a fresh simulated arm whose every exchange is recorded (patient
    with the simulator: a pseudo-terminal on a loaded machine can hold bytes back over 100 ms)."""
    config = load_config("replica")
    arm = SimulatedRobot(config, small_time_step=SMALL_TIME_STEP).port()
    link = FirmwareLink(arm, on_tick)
    server = PtyServer(arm, "lockstep")
    server.start()
    try:
        report, log = run_native(server.path, config.model.dof_names, realtime, args, reply_timeout=reply_timeout,
                                 say=quiet)
        server._drain()                  # the last torque-off write, still in flight
    finally:
        server.stop()
    return report, log, link.record, arm


@pytest.fixture(scope="module")
def swing(native):
    return _run()


def test_native_goals_are_the_host_controllers(swing):
    """Every Goal Current the native loop wrote equals the host's double controller's on the same
    measured state within one servo unit (float against double, as under QEMU)."""
    report, log, record, arm = swing
    assert report["result"] == "done" and report["exit_code"] == 0, report
    assert report["ticks"] == HOME_TICKS + SWING_TICKS and len(record.goals) == HOME_TICKS + SWING_TICKS, \
        "one write per tick of homing and swing"
    twin = replay("replica", record)
    n = len(twin["goals"])
    assert n >= HOME_TICKS + SWING_TICKS - 1, f"the replay covers the run ({n} ticks)"
    diff = np.abs(np.array(record.goals[:n]) - twin["goals"])
    assert diff.max() <= 1, f"goals differ by up to {diff.max()} units from the host's controller"
    assert record.torque_off and all(not s.torque_enabled for s in arm.servos), "torque off on every servo at the end"
    assert report["missed"] == 0 and report["lost"] == 0, "lock-step has no deadline to miss"


def test_native_log_is_what_crossed_the_bus(swing):
    """The log's swing ticks hold the measured state the bus carried (to float precision) and the
    plan's desired positions (the host's own plan, to 1e-5 rad)."""
    report, log, record, arm = swing
    assert len(log.t) == SWING_TICKS and log.t[0] == 0.0, "the swing's ticks, on the swing's clock"
    assert log.t[-1] == pytest.approx((SWING_TICKS - 1) * SMALL_TIME_STEP, abs=1e-9)
    units = ServoMap.from_joints(load_config("replica").joints)
    measured = np.array([units.from_ticks(r[:, 2]) for r in record.reads[1 + HOME_TICKS:1 + HOME_TICKS + SWING_TICKS]])
    assert np.abs(np.array(log.q) - measured).max() < 1e-5, "q logged is q read"
    twin = replay("replica", record)
    assert np.abs(np.array(log.q_d) - twin["q_d"][HOME_TICKS:HOME_TICKS + SWING_TICKS]).max() < 1e-5, \
        "q_d logged is the host's plan"
    assert np.isfinite(np.array(log.tau)).all() and np.isfinite(log.cpu_seconds).all()


def test_native_silent_servo_stops_safely(native):
    """Servo 5 stops answering after tick 100's write: the next read names it (fault 10, timeout),
    and the torque-off write goes out."""
    def silence(k, arm):
        if k == FAULT_TICK:
            arm.inject_fault(5, "silent")
    report, log, record, arm = _run(on_tick=silence)
    assert (report["fault"], report["code"], report["exit_code"]) == ("timeout", 10, 10), report
    assert report["servo"] == 5 and report["fault_tick"] == FAULT_TICK + 1, "servo 5, at the read after"
    assert record.torque_off and len(record.goals) == FAULT_TICK + 1, "no command after the fault, torque off sent"


def test_native_nonfinite_stops_safely(native):
    report, log, record, arm = _run(args="nan_at=120")
    assert (report["fault"], report["code"]) == ("nonfinite", 13) and report["fault_tick"] == 120, report
    assert record.torque_off and len(record.goals) == 120, "the NaN at tick 120: no command from it"


def test_native_overrun_stops_safely(native):
    """Real time with a 1 us period and no tolerance: the first tick (a round trip through the
    pseudo-terminal) cannot end inside its period, so it is fault 14 at tick 0."""
    report, log, record, arm = _run(args="period_us=1 tolerance_us=0", realtime=True)
    assert (report["fault"], report["code"]) == ("overrun", 14) and report["fault_tick"] == 0, report
    assert report["missed"] >= 1 and record.torque_off, "the missed deadline is counted, torque off sent"


@pytest.mark.serial
def test_native_caught_up_ticks_are_timed_each(native):
    """Real time with a 20 us period, which no round trip through the pseudo-terminal keeps: every
    tick after the first runs at once, catching up on the plan (a wide tolerance lets it). Each is
    still timed from its own start in the log: the starts rise by at least the tick before's work
    (a caught-up tick used to log the start of the first late one, and its wall time from there)."""
    report, log, record, arm = _run(args=f"period_us=20 tolerance_us=10000000 ticks={HOME_TICKS + 100}",
                                    realtime=True)
    assert report["fault"] == "none" and report["missed"] >= HOME_TICKS, report
    start, wall = np.array(log.tick_start), np.array(log.tick_seconds)
    assert len(start) == 100, "the swing's first 100 ticks are logged"
    assert (np.diff(start) > 0).all(), "every tick has a start of its own"
    assert (start[1:] >= start[:-1] + wall[:-1] - 1e-9).all(), "a tick starts after the one before ended"
    assert (wall < 0.5).all(), "each wall time is one tick's, not the run's since the first late tick"


@pytest.mark.slow
def test_swing_native_has_the_python_loops_summary(native, tmp_path):
    """`servodyn swing --native`: the simulator in its process, the native loop on its
    pseudo-terminal, the summary with the Python loop's keys (and the same tracking bound)."""
    from servodyn.loop import RunLog, summarize
    summary = run_swing(out=tmp_path, native=True, say=quiet)
    assert summary["completed"] and summary["loop"] == "native", summary.get("error")
    assert summary["ticks"] == SWING_TICKS and summary["tracking_max_rad"] <= np.radians(5)
    one = RunLog(("a",))
    one.add(0.0, [0.0], type("S", (), {"q": np.zeros(1), "qd": np.zeros(1), "current": np.zeros(1)})(),
            [0.0], 1e-4, 0.0, 1e-4, 1e-4)
    keys = set(summarize(one, 1, SMALL_TIME_STEP, False)) | {"motion", "mode", "time_scale", "validated", "bus",
                                                              "loop", "sim_time_at_stop_s", "torque_off"}
    assert keys <= set(summary), f"missing: {keys - set(summary)}"
    assert all(summary["torque_off"]), "torque off on every servo"
    assert summary["exit_code"] == 0, "the exit status `servodyn swing` takes from the summary, as the Python loop's"
    assert (tmp_path / "swing_log.csv").read_text().count("\n") == 1 + SWING_TICKS, "the log, as the Python loop's"


@pytest.fixture(scope="module")
def pushed(native):
    """The native loop with PUSH on the simulated arm: (report, log, record, arm)."""
    def on_tick(k, arm):
        if k == 0:
            arm.schedule_push(PUSH, origin=HOME_TICKS * SMALL_TIME_STEP)
    return _run(args=f"ticks={HOME_TICKS + 500}", on_tick=on_tick)


def test_native_detects_a_push(pushed):
    """The native loop's observer on a 10 N push down at the hand, 0.3 s into the swing (the
    firmware's test under QEMU holds the same push against the Python loop's detection): fault 18
    within 20 ms of the push, and summary.json's `contact` entry from `contact_detail`: the joint the
    firmware names, the link (the child body of the last joint over its threshold), the residual
    over that joint's threshold, and the host's force estimate at the tick before the detection.
    The residual has then risen only part of the way (two 100 rad/s poles: 6 % of a step after
    4 ms) and the link is the first joint's, not yet the hand (the Python loop refines both while
    its reaction runs; the firmware has switched torque off): measured 4.8 N, asserted 2-12 N."""
    report, log, record, arm = pushed
    assert (report["fault"], report["code"], report["exit_code"]) == ("contact", 18, 18), report
    assert record.torque_off, "torque off sent after the contact"
    config = load_config("replica")
    detail = contact_detail(config, report)
    assert PUSH.start <= detail["detected_t_s"] <= PUSH.start + 0.02, detail
    assert detail["joint"] in config.model.dof_names and detail["link"] in config.model.body_names, detail
    assert detail["residual_nm"] > config.guards.contact_threshold[config.model.dof_names.index(detail["joint"])]
    assert detail["force_estimate_n"] is not None and 2.0 <= detail["force_estimate_n"] <= 12.0, detail


def test_swing_native_summary_names_the_contact(pushed, tmp_path, monkeypatch):
    """`swing --native`'s summary of that run (native_swing, its run_native given the run above):
    stop_reason "contact", the `contact` entry contact_detail gives, the firmware's exit status 18."""
    import json
    from types import SimpleNamespace
    from servodyn.loop import native as native_module
    report, log, _, _ = pushed
    monkeypatch.setattr(native_module, "run_native", lambda *a, **k: (dict(report), log))
    config = load_config("replica")
    run = SimpleNamespace(config=config, realtime=False, say=quiet, options=SimpleNamespace(
        overrun_tolerance=None, mode="feedforward_pd"), swing=SimpleNamespace(t=np.zeros(SWING_TICKS)),
        verdict=SimpleNamespace(path=Path("forehand.toml"), passed=True), scale=1.0, cpu=None)
    summary = native_module.native_swing(None, "/dev/null", run, tmp_path)
    assert summary["stop_reason"] == "contact" and summary["exit_code"] == 18, summary.get("error")
    assert summary["contact"] == contact_detail(config, report), summary["contact"]
    written = json.loads((tmp_path / "summary.json").read_text())
    assert set(written["contact"]) == {"detected_t_s", "joint", "link", "residual_nm", "force_estimate_n"}
