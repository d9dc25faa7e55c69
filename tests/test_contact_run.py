"""Contact in a run, end to end on the simulated replica: a push detected, isolated and estimated;
an obstacle met, the contact ended by the reaction; the hold's stop from full speed; the
calibration command. The thresholds are the built-in configuration's, calibrated by `servodyn
contact` on its clean runs."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tomlkit

from servodyn.control.motion import motion_path
from servodyn.hal.config import load_config
from servodyn.hal.contact_spec import Push, Sphere
from servodyn.loop.run import Run, RunOptions
from servodyn.sim.serve import serve

from helpers import run_cli

pytestmark = pytest.mark.slow           # whole swings

REPLICA = load_config("replica")
PEAK_T = 5.1        # s: the replica's forehand at its time scale 4 is fastest at the hand here (1.01 m/s)


def hand_direction(config, t: float) -> np.ndarray:
    """The unit direction the hand's centre of mass moves in at t of the forehand."""
    traj = motion_path("tennis_forehand", config.model).at_scale(config.time_scale_for("tennis_forehand"),
                                                                config.control_period)
    k = int(round(t / config.control_period))
    a, b = (config.model.com_positions(traj.q[i])[-1] for i in (k, k + 5))
    return (b - a) / np.linalg.norm(b - a), a


def played(config, out: Path, **options):
    """A run on an in-process simulator; the run and the plant's true hand position every tick."""
    held, truth = [], []

    def served(cfg, mode, **kw):
        held.append(serve(cfg, mode, process=False, **kw))
        return held[-1]

    def watch(t, q_d, state, tau):
        truth.append((t, config.model.com_positions(held[0].robot.plant.q)[-1]))
    run = Run(config, RunOptions(**options), serve=served, say=lambda *a: None, observer=watch)
    summary = run.play(out)
    return run, summary, np.array([t for t, _ in truth]), np.array([p for _, p in truth])


def test_a_push_at_the_hand_is_detected_isolated_and_estimated(tmp_path):
    direction, _ = hand_direction(REPLICA, PEAK_T)
    force = -10.0 * direction                      # 10 N against the hand's motion at its fastest
    push = f"r_hand:{force[0]:.4f},{force[1]:.4f},{force[2]:.4f}@{PEAK_T}"
    res = run_cli("swing", "--contact", push, "--out", str(tmp_path))
    assert res.returncode == 18, res.stderr[-800:]          # a contact's own exit status
    summary = json.loads((tmp_path / "summary.json").read_text())
    contact = summary["contact"]
    assert summary["stop_reason"] == "contact" and contact["applied_t_s"] == pytest.approx(PEAK_T, abs=1.5e-3)
    delay = contact["detected_t_s"] - contact["applied_t_s"]
    # the goal: P95 <= 12 ms at 1 kHz (`make bench` measures the distribution; one push here)
    assert 0 < delay <= 0.012, delay
    assert contact["link"] in ("r_hand", "r_wrist_link"), "the hand, or its parent across the wrist's axes"
    # the force where the observer settled it: within max(15 %, 1 N) of the 10 N applied
    assert contact["force_estimate_n"] == pytest.approx(10.0, abs=1.5), contact
    assert summary["reaction"] == {"kind": "hold", "gave_way": None}
    assert "the swing stopped: contact: link" in res.stderr


def test_an_obstacle_in_the_path_is_left_within_50_ms(tmp_path):
    """A ball of lower-arm stiffness (5 N/mm) where the hand passes at full speed: detected, held back,
    and the contact over well within 50 ms of its onset, once (no second contact, no clamping)."""
    direction, at = hand_direction(REPLICA, PEAK_T)
    ball = Sphere(tuple(at + 0.05 * direction), 0.05, 5e3)
    run, summary, _, _ = played(REPLICA, tmp_path, obstacles=(ball,))
    assert summary["stop_reason"] == "contact", summary["error"]
    assert summary["contact"]["link"] == "r_hand"
    log = run.contact_log
    t = np.array([row[0] for row in log["rows"]]) - log["swing_start"]
    force = np.linalg.norm(np.array([row[3:6] for row in log["rows"]], dtype=float), axis=1)
    onset = t[0]
    assert t[-1] - onset <= 0.05, f"the last contact force {1e3 * (t[-1] - onset):.0f} ms after the onset"
    assert np.all(np.diff(t) < 0.005), "one contact, not two"
    # ISO/TS 15066 Table A.2: the hand's transient limit, 280 N (measured 43 N at 5 N/mm)
    assert force.max() < 280.0, force.max()


def test_hold_stops_the_hand_from_full_speed(tmp_path):
    """The hold after a stop at the hand's fastest: brought to rest within 15 mm and under 1 cm/s
    within 160 ms (the issue's goal). The stop is a following error: the contact watch off, a push of
    40 N for 30 ms throws the arm off its path."""
    config = replace(REPLICA, safety=replace(REPLICA.guards, contact=False))
    direction, _ = hand_direction(config, PEAK_T)
    push = Push("r_hand", tuple(-40.0 * direction), PEAK_T, 0.03)
    _, summary, t, hand = played(config, tmp_path, contacts=(push,))
    assert summary["stop_reason"] == "following_error", summary["error"]
    stop = summary["following_error"]["t_s"]
    after = t >= stop - 1e-9
    hand, t = hand[after], t[after]
    speed = np.linalg.norm(hand[5:] - hand[:-5], axis=1) / (t[5:] - t[:-5])
    travel = np.linalg.norm(hand - hand[0], axis=1).max()
    assert travel <= 0.015, f"{1e3 * travel:.1f} mm of travel after the stop"
    still = next(i for i in range(len(speed)) if np.all(speed[i:] < 0.01))
    assert t[still] - t[0] <= 0.16, f"under 1 cm/s only {t[still] - t[0]:.3f} s after the stop"


def test_contact_thresholds_calibrates_into_a_copy(tmp_path):
    target = tmp_path / "replica.toml"
    res = run_cli("contact", "--config", "replica", "--runs", "1", "--write", str(target),
                  "--out", str(tmp_path / "runs"), "--yes")
    assert res.returncode == 0, res.stderr[-800:]
    written = tomlkit.parse(target.read_text())
    thresholds = written["safety"]["contact_threshold_nm"]
    assert set(thresholds) == set(REPLICA.model.dof_names)
    # 1.2 x the largest residual of a clean forehand: a tenth to a few tenths of a N m on the replica
    assert all(0.01 < float(v) < 1.0 for v in thresholds.values()), dict(thresholds)
    assert "# " in target.read_text(), "the built-in file's comments kept in the copy"
    assert load_config(target).guards.contact_threshold is not None, "the copy loads with its thresholds"
