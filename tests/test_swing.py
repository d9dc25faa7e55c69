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
