"""The tennis swing through dynamixel-sdk against the simulated Dynamixel bus (host/swing.py,
hal/dynamixel/backend.py, sim/arm.py): feed-forward against PD alone, and a servo that stops
answering mid-swing."""

import numpy as np
import pytest

from servodyn.swing import run_swing


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    quiet = lambda *a, **k: None
    ff = run_swing(out=tmp_path_factory.mktemp("ff"), say=quiet)
    pd = run_swing(out=tmp_path_factory.mktemp("pd"), feedforward=False, say=quiet)
    return ff, pd


def test_swing_completes_on_the_simulated_bus(runs):
    ff, _ = runs
    assert ff["completed"], ff.get("error")
    assert ff["tracking_max_rad"] <= np.radians(5), "feed-forward + PD tracks the replica within 5 deg"
    assert ff["loop_hz"] >= 200, "lock-step ticks run well above 200 Hz on this machine"
    assert all(ff["torque_off"]), "every servo's torque is off after the run"


def test_feedforward_cuts_the_largest_error_threefold(runs):
    ff, pd = runs
    ratio = pd["tracking_max_rad"] / ff["tracking_max_rad"]
    assert ratio >= 3, f"feed-forward cut the largest tracking error only {ratio:.1f}x"


def test_servo_that_stops_answering_stops_the_swing_safely(tmp_path):
    """Servo 5 goes silent 1 s into the swing: the HAL raises naming it, the torque goes off on
    every servo before the plant runs two more ticks, and the log holds every tick until then."""
    summary = run_swing(out=tmp_path, say=lambda *a, **k: None, fault_at=(1.0, 5))
    assert not summary["completed"]
    assert "servo 5" in summary["error"] or "r_forearm_pronation" in summary["error"]
    assert summary["ticks"] == 1000, "ticks 0..999 answered and were logged; tick 1000 failed"
    # the plant advances one period per command: the stop came within two ticks of the last one
    assert summary["sim_time_at_stop_s"] - summary["last_tick_time_s"] <= 2e-3 + 1e-9
    assert all(summary["torque_off"])
    lines = (tmp_path / "swing_log.csv").read_text().splitlines()
    assert len(lines) == 1 + 1000


def test_hardware_error_stops_the_swing_safely(tmp_path):
    """Servo 3 reports an overload 1 s into the swing: its fast-read block carries the alert bit,
    the HAL reads Hardware Error Status and raises naming servo and bit, torque goes off on every
    servo within two ticks of plant time, and the log holds the 1000 ticks before it."""
    summary = run_swing(out=tmp_path, say=lambda *a, **k: None, fault_at=(1.0, 3, "overload"))
    assert not summary["completed"]
    assert "(id 3) hardware error 0x20: overload" in summary["error"]
    assert summary["ticks"] == 1000, "ticks 0..999 were clean; tick 1000's read saw the alert"
    assert summary["sim_time_at_stop_s"] - summary["last_tick_time_s"] <= 2e-3 + 1e-9
    assert all(summary["torque_off"])
    assert len((tmp_path / "swing_log.csv").read_text().splitlines()) == 1 + 1000


def test_summary_reports_rate_jitter_and_cpu_per_tick(runs):
    """Lock-step: the loop runs as fast as the bus answers. CPU per tick is the loop thread's
    (HAL read, control step, HAL write), so it is at most the tick's wall time; the process's
    CPU also counts the simulated bus in its own thread, so it is at least as much."""
    ff, _ = runs
    for key in ("tracking_rms_rad", "tracking_max_rad", "loop_hz", "jitter_p99_ms"):
        assert ff[key] > 0, key
    cpu = ff["cpu_ms_per_tick"]
    assert ff["clock"] == "lockstep"
    assert 0 < cpu["median"] <= cpu["p99"]
    assert cpu["median"] <= ff["tick_median_ms"], "a thread's CPU time cannot exceed its wall time"
    assert ff["process_cpu_ms_per_tick"]["median"] >= cpu["median"]
    assert abs(ff["loop_hz"] * ff["period_median_ms"] / 1e3 - 1) < 0.2, "rate and median period agree"


def test_realtime_swing_is_paced_at_1khz(tmp_path):
    """Real time (the plant on the wall clock, the loop sleeping to the next 1 ms): never faster
    than 1 kHz, and it keeps up, since a tick's work takes well under its period."""
    summary = run_swing(out=tmp_path, say=lambda *a, **k: None, realtime=True, time_scale=3.0)
    assert summary["clock"] == "realtime" and summary["ticks"] >= 1000
    assert 900 <= summary["loop_hz"] <= 1000.5
    assert 0.95 <= summary["period_median_ms"] <= 1.05
    assert summary["cpu_ms_per_tick"]["median"] < 1.0, "the host could hold the 1 ms period"
    assert summary["jitter_p99_ms"] >= 0
