"""The paper's experiments (tools/experiments.py) and their goals, as `servodyn experiment` runs them."""

import json

import numpy as np
import pytest

from servodyn.tools.experiments import experiment_pendulum, experiment_still, experiment_swing

from helpers import run_cli

pytestmark = pytest.mark.slow      # the paper's experiments, end to end


def test_pendulum_goals(tmp_path):
    """human15 floating on its support, every limb dof free, RK4 at the chosen 0.125 ms for 10 s:
    energy drift <= 1e-4 of the largest kinetic energy, the centre of mass still within 1e-6 m
    (the support cancels the weight)."""
    summary = experiment_pendulum(tmp_path, table=False)
    assert summary["small_time_step_s"] == 1.25e-4, "the chosen 0.125 ms step"
    assert summary["energy_drift_rel"] <= 1e-4, \
        f"energy drift {summary['energy_drift_rel']:.1e} of the largest kinetic energy"
    assert summary["com_displacement_max_m"] <= 1e-6, \
        f"centre of mass moved {summary['com_displacement_max_m']:.1e} m; the support cancels the weight"
    assert (tmp_path / "pendulum_snapshots.png").stat().st_size > 10_000, "the snapshots drawn, not an empty figure"
    assert json.loads((tmp_path / "summary.json").read_text())["energy_drift_rel"] == summary["energy_drift_rel"], \
        "summary.json holds the returned figures"


def test_still_goals(tmp_path):
    """The upper body held at the thorax for 5 s: the default mode (feed-forward + PD) keeps every
    joint within 1e-6 rad; feed-forward alone lets the inverted-pendulum head fall (more than
    1e-3 rad), starting from rounding."""
    summary = experiment_still(tmp_path)
    assert summary["max_drift_rad"] <= 1e-6, f"feed-forward + PD let a joint drift {summary['max_drift_rad']:.1e} rad"
    assert summary["max_drift_ff_only_rad"] > 1e-3, \
        f"feed-forward alone drifted only {summary['max_drift_ff_only_rad']:.1e} rad; the head should fall"
    torques = summary["torques_nm"]
    assert set(torques) >= {"neck_flexion", "r_shoulder_flexion", "l_elbow_flexion"}, \
        "holding torques of upper-body dofs"
    assert abs(torques["r_shoulder_flexion"]) > 1.0, "a raised arm needs a shoulder torque"


def test_swing_keys_and_tracking(tmp_path):
    summary = experiment_swing(tmp_path)
    assert summary["completed"], "the plant stayed finite to the end of the swing"
    assert summary["tracking_max_rad"] <= np.radians(5), \
        f"largest tracking error {np.degrees(summary['tracking_max_rad']):.2f} deg"
    assert 0 < summary["tracking_rms_rad"] <= summary["tracking_max_rad"], \
        "an rms error is positive and cannot exceed the largest"
    peak = summary["peak_torque_nm"]
    assert 5.0 <= peak["r_shoulder_flexion"] <= 30.0, "a bare 3.5 kg arm: some 10 N m at the shoulder"
    for name in ("swing_postures.png", "swing_shoulder_torques.png", "swing_tau.csv"):
        assert (tmp_path / name).stat().st_size > 1000, f"{name} written with content"


def test_experiment_command_line(tmp_path):
    res = run_cli("experiment", "still", "--out", tmp_path / "still")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "still" / "summary.json").exists(), "--out is where the summary goes"
    res = run_cli("experiment", "juggle")
    assert res.returncode == 2 and "juggle" in res.stderr, f"an unknown experiment is refused, named: {res.stderr}"
