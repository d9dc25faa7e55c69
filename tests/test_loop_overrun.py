"""Overruns are seen: in real time a tick that ends after its period's end missed its deadline
(counted in the log and the summary), and a loop that falls further behind its schedule than the
tolerance stops (servodyn.loop.Overrun), as the firmware's fault 14. The delays here are forced
(a sleep before a tick), so what is asserted follows from them on any machine: lower bounds on
missed deadlines, never a rate or a period."""

import time

import pytest

import servodyn.loop as loop
from servodyn.control import ControlConfig, Controller
from servodyn.control.schedule import homing, plan_gains, Segment
from servodyn.control.timing import HOME_DURATION, SMALL_TIME_STEP
from servodyn.hal.bus import make_bus
from servodyn.hal.config import load_config
from servodyn.loop import Overrun, RunLog, follow, summarize
from runs import run_swing

from helpers import quiet

pytestmark = pytest.mark.serial      # real-time loops, a simulated bus answering within its timeouts



def _hold(ticks):
    """A loopback bus and a segment holding the arm still for `ticks` periods."""
    config = load_config("replica")
    model = config.model
    bus = make_bus(config, kind="loopback")
    bus.open()
    bus.enable_torque(True)
    q = bus.read_state().q
    traj = homing(q, q, (ticks - 1) * SMALL_TIME_STEP, SMALL_TIME_STEP)
    gains, _ = plan_gains(model, traj)
    controller = Controller(model, ControlConfig(mode="feedforward_pd"), q_start=q)
    return bus, controller, Segment("hold", traj, gains), model


def test_late_ticks_are_counted_as_missed_deadlines():
    """A 3 ms sleep before tick 3: ticks 3, 4 and 5 (deadlines 4, 5 and 6 ms after the start) all
    end after the sleep's end (6 ms at the earliest), so at least three deadlines are missed; the
    loop catches up within the 10 ms tolerance and plays every tick."""
    bus, controller, segment, model = _hold(20)
    log = RunLog(model.dof_names)
    stall = lambda k: time.sleep(3e-3) if k == 3 else None
    missed = follow(bus, controller, segment, log, realtime=True, on_tick=stall, tolerance=1.0)
    bus.stop()
    assert len(log.t) == 20, "every tick ran: a late tick is caught up, not skipped"
    assert missed >= 3 and log.missed == missed, f"{missed} missed, the log says {log.missed}"
    summary = summarize(log, 20, SMALL_TIME_STEP, realtime=True)
    assert summary["missed_deadlines"] == missed, "the summary reports the missed deadlines"
    assert summarize(log, 20, SMALL_TIME_STEP, realtime=False)["missed_deadlines"] is None, \
        "lock-step has no deadline: none is reported, not 0"


def test_a_loop_behind_its_tolerance_stops_before_the_tick():
    """A 50 ms stall before tick 5 against a 20 ms tolerance: tick 5 begins at least 50 ms behind
    its schedule, so Overrun is raised before it reads, in one line naming the tick."""
    bus, controller, segment, model = _hold(50)
    log = RunLog(model.dof_names)
    stall = lambda k: time.sleep(50e-3) if k == 5 else None
    with pytest.raises(Overrun, match=r"^overrun: tick 5 began \d+\.\d ms behind its 1 ms schedule "
                                      r"\(tolerance 20 ms") as stopped:
        follow(bus, controller, segment, log, realtime=True, on_tick=stall, tolerance=20e-3)
    bus.stop()
    assert "\n" not in str(stopped.value), "one line"
    assert len(log.t) == 5, "ticks 0..4 ran and were logged, tick 5 never read"


def test_swing_stops_safely_on_an_overrun(tmp_path, monkeypatch):
    """With a tolerance no loop can hold (negative), the real-time swing stops at its first tick:
    torque off on every simulated servo, the error is the overrun line, the summary written."""
    monkeypatch.setattr(loop, "OVERRUN_TOLERANCE", -1.0)
    summary = run_swing(out=tmp_path, realtime=True, say=quiet)
    assert not summary["completed"] and summary["error"].startswith("overrun: tick 0 began"), summary["error"]
    assert all(summary["torque_off"]), "torque off on every servo after the overrun"
    assert (tmp_path / "summary.json").exists(), "the summary is written on a safe stop"


def test_homings_missed_deadlines_are_the_runs(tmp_path, monkeypatch):
    """missed_deadlines counts homing's late ticks with the swing's (the native loop's count has
    both): a homing that missed 7 and a swing that missed 2 make 9, over homing's 2,001 ticks and
    the swing's. The loop itself is stood in for, so the counts are exact."""
    from servodyn.loop import run as swing

    def follow(bus, controller, segment, log=None, realtime=False, **kw):
        if log is None:
            return 7                  # homing: not logged, its misses returned
        log.missed += 2
        return 2
    monkeypatch.setattr(swing, "follow", follow)
    summary = run_swing(out=tmp_path, realtime=True, say=quiet)
    assert summary["missed_deadlines"] == 9, summary["missed_deadlines"]
    assert summary["home_ticks"] == round(HOME_DURATION / SMALL_TIME_STEP) + 1, summary["home_ticks"]
