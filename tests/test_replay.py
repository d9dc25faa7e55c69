"""`servodyn replay` and `servodyn identify --actuator` on the recorded XL330 logs: the CSV contract
(DESIGN.md: t,q_measured,q_predicted,duty_measured,duty_predicted, one row per log entry), the
actuator.json contract, and one line with exit status 2 for a malformed log."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from helpers import run_cli
from test_servo_model import servo_logs

KEYS = ("torque_constant_nm_a", "resistance_ohm", "armature_kg_m2", "friction_coulomb_nm", "friction_viscous_nm_s")


@pytest.fixture(scope="module")
def xl330():
    return sorted((servo_logs() / "xl330-pendulum").glob("*.json"))


@pytest.fixture(scope="module")
def actuator(xl330, tmp_path_factory):
    out = tmp_path_factory.mktemp("identify")
    done = run_cli("identify", "--actuator", "XL330-M288", *xl330, "--out", out, timeout=300)
    assert done.returncode == 0, done.stderr
    return out / "actuator.json", done


def test_identify_actuator_writes_the_contract(actuator):
    file, done = actuator
    data = json.loads(file.read_text())
    for key in KEYS:
        assert isinstance(data[key], float) and data[key] >= 0, key
    assert 0.9 * 0.0021 <= data["armature_kg_m2"] <= 1.1 * 0.0022       # the free swing's armature
    assert data["replay_error_rad"]["mean"] <= 0.030                      # issue 32's goal
    # not fitted: the Stribeck keys are absent and say why; every key has its standard error or a reason
    for key in ("friction_stribeck_nm", "stribeck_velocity_rad_s"):
        assert (key in data) != (key in data["not_determined"]) or key in data["standard_errors"]
    assert "servodyn replay" in done.stderr and "--actuator" in done.stderr


def test_replay_one_log_csv(xl330, actuator, tmp_path):
    log = xl330[4]
    entries = json.loads(log.read_text())["entries"]
    out_csv = tmp_path / "one.csv"
    done = run_cli("replay", log, "--servo", "XL330-M288", "--actuator", actuator[0], "-o", out_csv,
                   "--out", tmp_path / "fig")
    assert done.returncode == 0, done.stderr
    with open(out_csv, newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["t", "q_measured", "q_predicted", "duty_measured", "duty_predicted"]
    assert len(rows) == len(entries)                        # one row per log entry, at its timestamp
    t = np.array([float(r["t"]) for r in rows])
    assert np.allclose(t, [e["timestamp"] for e in entries], atol=1e-6)
    q, p = (np.array([float(r[k]) for r in rows]) for k in ("q_measured", "q_predicted"))
    assert p[0] == pytest.approx(q[0], abs=1e-6)           # starts where the log starts
    assert np.mean(np.abs(p - q)) < 0.05                     # the kp 400 sin_sin: 0.021 rad measured
    summary = json.loads((tmp_path / "fig/replay.json").read_text())
    assert summary["mean_error_rad"] == pytest.approx(np.mean(np.abs(p - q)), abs=1e-6)
    assert (tmp_path / "fig/replay.png").stat().st_size > 10_000


def test_replay_all_logs(xl330, actuator, tmp_path):
    done = run_cli("replay", *xl330, "--servo", "XL330-M288", "--actuator", actuator[0], "--out", tmp_path)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "replay.json").read_text())
    assert len(summary["logs"]) == 8 and summary["mean_error_rad"] <= 0.030
    assert summary["mean_duty_error"] <= 0.04
    assert len(list(tmp_path.glob("*.csv"))) == 8


@pytest.mark.parametrize("text, words", [
    ("{", "not JSON"),
    ('{"mass": 0.49}', "no `length`"),
    ('{"mass": 0.49, "length": 0.1, "kp": 400, "vin": 7.4, "entries": [{"position": 0}, {"position": 0}]}',
     "entry 0 has no `speed`"),
    ('{"mass": -1, "length": 0.1, "kp": 400, "vin": 7.4, "entries": []}', "at least 2 samples"),
])
def test_malformed_log_is_one_line(tmp_path, text, words):
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    done = run_cli("replay", bad, "--servo", "XL330-M288", "--out", tmp_path)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and words in done.stderr and "Traceback" not in done.stderr


def test_bad_command_lines(xl330, tmp_path):
    two = run_cli("replay", xl330[0], xl330[1], "--servo", "XL330-M288", "-o", tmp_path / "x.csv")
    assert two.returncode == 2 and "--out DIR" in two.stderr
    unknown = run_cli("replay", xl330[0], "--servo", "XL999", "--out", tmp_path)
    assert unknown.returncode == 2 and "unknown servo" in unknown.stderr
    both = run_cli("identify", "--actuator", "XL330-M288", "--config", "replica", xl330[0])
    assert both.returncode == 2 and "no --config" in both.stderr
    neither = run_cli("identify", xl330[0])
    assert neither.returncode == 2 and "--config" in neither.stderr
