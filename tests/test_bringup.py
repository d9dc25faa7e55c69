"""Bring-up on a Dynamixel bus, end to end through the CLI against the simulated servos on a
pseudo-terminal: scan, doctor, reboot, clear-errors, torque off, monitor, calibrate (driven through
standard input in a separate process, as a person at the arm would), and the refusals, each one
line with its fix."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import pytest
import tomlkit

from servodyn.hal.config import load_config
from servodyn.hal.dynamixel.control_table import ITEMS
from servodyn.tools.simulator import serve

from helpers import answer_prompts, start_cli

ROOT = Path(__file__).resolve().parent.parent
CONFIG = load_config("replica")


@pytest.fixture
def bench():
    """The replica's simulated bus, lock-step (the plant moves only when a host commands it: a
    joint stays where a hand puts it)."""
    served = serve(CONFIG, "lockstep", process=False)
    try:
        yield served, served.buses["arm"]["port"]
    finally:
        served.stop()


def said(result):
    """A run's exit status, stdout and stderr."""
    return result.returncode, result.stdout, result.stderr


def servo(served, servo_id):
    return next(s for s in served.robot.servos if s.id == servo_id)


def by_hand(served, dof: str, angle: float) -> None:
    """A person moves a joint, torque off: the plant's joint at `angle` (rad), the horns told."""
    robot = served.robot
    with robot.lock:
        robot.plant.q[robot.model.dof_names.index(dof)] = angle
        robot.plant.publish()


def test_doctor_on_a_healthy_replica_is_clean(bench, cli):
    served, port = bench
    code, out, err = said(cli("doctor", "--config", "replica", "--port", port, "--json"))
    findings = json.loads(out)["findings"]
    # a servo that has not been opened by a run keeps its factory Return Delay Time (500 us): a
    # warning only, every open writes 0
    assert code == 0, out + err
    assert {f["check"] for f in findings} <= {"return delay time"}, findings
    assert all(set(f) >= {"joint", "id", "check", "found", "expected", "fix"} for f in findings)


@pytest.mark.parametrize("setting, check, fix", [
    (("firmware_version", 44), "firmware", "Firmware Update"),
    (("drive_mode", 1), "drive mode", "servodyn setup"),
    (("homing_offset", 300), "homing offset", "servodyn setup"),
    (("status_return_level", 1), "status return level", "servodyn reboot"),
    (("current_limit", 500), "current limit", "servodyn setup"),
])
def test_doctor_and_every_open_refuse_a_table_a_run_cannot_use(bench, cli, tmp_path, setting, check, fix):
    """Each of these was set in Wizard or left by another program and shifts, flips or weakens a
    joint silently (or, old firmware, stalls the fast sync read): doctor names it with its fix,
    and a swing refuses to open on it, in one line, before anything moves."""
    served, port = bench
    name, value = setting
    with served.robot.lock:
        servo(served, 4)._set(name, value)
    code, out, err = said(cli("doctor", "--config", "replica", "--port", port, "--json"))
    found = [f for f in json.loads(out)["findings"] if f["check"] == check]
    assert code == 1, out
    assert [f["id"] for f in found] == [4], found
    assert fix in found[0]["fix"]
    code, out, err = said(cli("swing", "--config", "replica", "--port", port, "--out", str(tmp_path), "--yes"))
    assert code == 2, out + err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and check in lines[0] and "id 4" in lines[0], err
    assert not (tmp_path / "swing_log.csv").exists()      # refused at open: nothing ran


def test_a_latched_overload_is_found_and_cleared_by_reboot(bench, cli):
    served, port = bench
    served.inject_fault(5, "overload")
    code, out, _ = said(cli("doctor", "--config", "replica", "--port", port, "--json"))
    found = [f for f in json.loads(out)["findings"] if f["check"] == "hardware error"]
    assert code == 1 and [f["id"] for f in found] == [5] and "servodyn reboot" in found[0]["fix"], out
    result = cli("clear-errors", "--config", "replica", "--port", port)
    assert result.returncode == 1, result.stdout + result.stderr     # clear-errors cannot clear it
    assert servo(served, 5).get("hardware_error_status") != 0, "the overload still latched"
    result = cli("reboot", "--config", "replica", "--port", port, "--yes")
    assert result.returncode == 0, result.stdout + result.stderr
    assert all(s.get("hardware_error_status") == 0 for s in served.robot.servos), "the reboot cleared it"
    code, out, _ = said(cli("doctor", "--config", "replica", "--port", port))
    assert code == 0, out


def test_clear_errors_clears_a_tripped_watchdog(bench, cli):
    served, port = bench
    with served.robot.lock:
        servo(served, 2)._set("bus_watchdog", -1)
    code, out, _ = said(cli("doctor", "--config", "replica", "--port", port, "--json"))
    assert [f["id"] for f in json.loads(out)["findings"] if f["check"] == "bus watchdog"] == [2]
    code, out, _ = said(cli("clear-errors", "--config", "replica", "--port", port))
    assert code == 0, out
    assert servo(served, 2).get("bus_watchdog") == 0


def test_torque_off_reaches_every_servo(bench, cli):
    served, port = bench
    with served.robot.lock:
        for s in served.robot.servos:
            s.write(ITEMS["torque_enable"].address, b"\x01")
    assert all(s.torque_enabled for s in served.robot.servos)
    code, out, _ = said(cli("torque", "off", "--config", "replica", "--port", port))
    assert code == 0, out
    assert not any(s.torque_enabled for s in served.robot.servos)


def test_monitor_shows_every_joint_in_si_and_raw_units(bench, cli):
    served, port = bench
    by_hand(served, "r_elbow_flexion", math.radians(40.0))
    code, out, _ = said(cli("monitor", "--config", "replica", "--port", port, "--count", "2"))
    assert code == 0
    assert out.count("r_elbow_flexion") == 2, out            # two refreshes, one row each
    row = next(line for line in out.splitlines() if "r_elbow_flexion" in line)
    # 40.00 degrees through the configuration's zero offset and direction, read back from ticks
    # (0.088 degrees each)
    assert "40.0" in row or "39.9" in row, row


def test_calibrate_through_standard_input_finds_the_configuration(bench, tmp_path):
    """A person at the arm, answering the prompts of `servodyn calibrate` in another process: the
    direction, the zero (two approaches) and the stops come back as the configuration has them
    (the simulated horns are mounted as it says), written into a copy that keeps its comments."""
    served, port = bench
    dof = "r_elbow_flexion"
    k = CONFIG.model.dof_names.index(dof)
    lower, upper = CONFIG.model.lower[k], CONFIG.model.upper[k]
    target = tmp_path / "replica.toml"
    # what the hand does at each prompt, in order: a small + move, the zero from each side, the stops
    moves = iter([0.3, -0.004, 0.004, lower - 0.02, upper + 0.02])
    by_hand(served, dof, 0.1)
    # the prompts read from stdout and stderr together: whichever stream carries them
    proc = start_cli("calibrate", "--config", "replica", "--port", port, "--joint", dof, "--write", target,
                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    try:
        text = answer_prompts(proc, lambda: by_hand(served, dof, next(moves)))
        code = proc.wait(timeout=60)
    finally:
        proc.kill()
    assert code == 0, text
    joint = next(j for j in tomlkit.parse(target.read_text())["joint"] if j["dof"] == dof)
    configured = next(j for j in CONFIG.joints if j.dof == dof)
    assert joint["direction"] == configured.direction
    # the mean of two approaches 0.008 rad apart sits on the configured zero within a tick (0.0015 rad)
    assert joint["zero_offset"] == pytest.approx(configured.zero_offset, abs=2 * 2 * math.pi / 4096)
    margin = math.radians(3.0)
    limits = list(joint["position_limits"])
    # the stops lie past the model's limits here: the limits stay the model's (said in the transcript)
    assert limits[0] == pytest.approx(max(lower - 0.02 + margin, lower), abs=0.01)
    assert limits[1] == pytest.approx(min(upper + 0.02 - margin, upper), abs=0.01)
    assert "# replica: the servo configuration" in target.read_text()     # comments kept
    assert load_config(target).name == "replica"


def test_refusals_are_one_line_with_their_fix(cli, tmp_path):
    cases = [
        (["scan"], "--port"),
        (["doctor", "--config", "replica"], "servodyn ports"),
        (["scan", "--port", str(tmp_path / "ttyUSB9")], "cannot open (No such file"),
        (["setup", "--config", "replica", "--joint", "r_knee", "--port", "/dev/null"], "no joint 'r_knee'"),
        (["scan", "--port", "/dev/null", "--baud", "12345"], "not a Dynamixel X rate"),
    ]
    for argv, needle in cases:
        code, out, err = said(cli(*argv))
        assert code == 2, (argv, out, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0], (argv, err)


@pytest.mark.serial
def test_can_bus_scan_doctor_and_torque_off_through_the_cli(cli):
    """The same commands on the replica's CAN bus, behind the simulated SLCAN adapter: every
    motor found at its CAN ID with its Master ID, doctor clean, torque off confirmed by each."""
    config = load_config("replica_can")
    served = serve(config, "lockstep", process=False, can="slcan")
    try:
        port = served.buses["arm"]["port"]
        code, out, _ = said(cli("scan", "--config", "replica_can", "--port", port, "--json"))
        found = json.loads(out)
        assert code == 0
        assert [(f["id"], f["master_id"]) for f in found] == [(k, 0x10 + k) for k in range(1, 8)]
        code, out, _ = said(cli("doctor", "--config", "replica_can", "--port", port, "--json"))
        assert code == 0 and json.loads(out)["findings"] == [], out
        with served.robot.lock:
            for motor in served.robot.motors:
                motor.enabled = True
        code, out, _ = said(cli("torque", "off", "--config", "replica_can", "--port", port))
        assert code == 0, out
        assert not any(m.enabled for m in served.robot.motors)
    finally:
        served.stop()
