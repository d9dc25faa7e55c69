"""Bring-up on a Dynamixel bus, end to end through the CLI against the simulated servos on a
pseudo-terminal: scan, doctor, reboot, clear-errors, torque off, monitor, calibrate (driven through
standard input in a separate process, as a person at the arm would), and the refusals, each one
line with its fix."""

from __future__ import annotations

import io
import json
import math
import os
import select
import subprocess
import sys
import termios
import threading
from pathlib import Path

import pytest
import tomlkit

from servodyn.hal.config import load_config
from servodyn.hal.dynamixel import Instruction, InstructionPacket, PacketReader
from servodyn.hal.dynamixel.control_table import ITEMS
from servodyn.sim.lab import Lab
from servodyn.tools.cli import main
from servodyn.sim.serve import serve

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
    errors = [line for line in err.strip().splitlines() if line.startswith("servodyn: error: ")]
    assert len(errors) == 1 and check in errors[0] and "id 4" in errors[0], err    # (its messages beside it)
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


# ---------------------------------------------------------------------------- hostile input

COMMANDS = [ROOT / "tools" / "bringup" / name for name in ("__init__.py", "monitor.py", "calibrate.py")]


def test_the_commands_know_no_bus_kind():
    """Each backend describes its own bring-up (hal.bringup.BringUp, found by name): the commands
    drive every bus through it, with no branch on a kind and no backend module imported."""
    import re
    for path in COMMANDS:
        text = path.read_text()
        found = re.findall(r"kind\s*[!=]=|[\"'](?:can|dynamixel)[\"']|"
                           r"from\s+[.\w]*hal\.(?:can|dynamixel)\b|hal\s+import\s+.*\b(?:can|dynamixel)\b", text)
        assert found == [], f"{path.name} branches on a bus kind: {found}"
    assert all(len(p.read_text().splitlines()) <= 500 for p in COMMANDS)


def run(capsys, *args) -> tuple[int, str, str]:
    """`servodyn ARGS...` in this process: its exit status, stdout and stderr (the cli fixture's
    way, with capsys, for the tests that read the output as a tuple)."""
    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_line(err: str) -> str:
    """The command's error: one line (its progress, on the same stream, may come before it)."""
    lines = [line for line in err.strip().splitlines() if line.startswith("servodyn:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("argv", [
    ["scan", "--port", "/dev/tty"],
    ["doctor", "--config", "replica", "--port", "/dev/tty"],
    ["monitor", "--config", "replica", "--port", "/dev/tty", "--count", "1"],
    ["torque", "off", "--config", "replica_can", "--port", "/dev/tty"],
    ["scan", "--port", "/dev/null"],
])
def test_a_terminal_or_another_device_is_refused_before_anything_is_sent(capsys, argv):
    """`--port /dev/tty` (a typo for /dev/ttyUSB0) would put pings on the user's terminal and leave
    it raw at 4 Mbaud: refused before the port is opened, in one line naming it and `servodyn ports`."""
    code, out, err = run(capsys, *argv)
    line = one_line(err)
    assert code == 2, (argv, out, err)
    assert argv[argv.index("--port") + 1] in line and "servodyn ports" in line and "nothing sent" in line, line
    assert "torque off" not in out, "no bus was opened"


def test_a_shells_pseudo_terminal_is_not_a_simulated_bus(capsys):
    """A terminal emulator's (or ssh's) pseudo-terminal is the controlling terminal of the shell on
    it; `servodyn sim`'s is no one's. The shell's is refused, and nothing reaches it."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    shell = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, termios, time\n"
                              "fcntl.ioctl(0, termios.TIOCSCTTY, 0); print('ready', flush=True); time.sleep(60)"],
                             stdin=slave, stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert shell.stdout.readline().strip() == "ready"
        before = termios.tcgetattr(slave)
        code, out, err = run(capsys, "scan", "--port", path)
        line = one_line(err)
        assert code == 2 and path in line and f"pid {shell.pid}" in line and "servodyn ports" in line, line
        assert select.select([master], [], [], 0.2)[0] == [], "not a byte was written to the terminal"
        assert termios.tcgetattr(slave) == before, "its settings untouched"
    finally:
        shell.kill()
        shell.wait()
        os.close(master)
        os.close(slave)


def test_a_ports_termios_settings_are_restored_on_close(bench, capsys):
    """Bring-up leaves a port as it found it: raw at the bus's rate while it runs, the user's
    settings (here 9600 baud, echo on) back when it closes."""
    served, port = bench
    fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        attrs = termios.tcgetattr(fd)
        attrs[3] |= termios.ECHO
        attrs[4] = attrs[5] = termios.B9600
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        before = termios.tcgetattr(fd)
        code, out, err = run(capsys, "torque", "off", "--config", "replica", "--port", port)
        assert code == 0, out + err
        assert out.count("torque off") == 8, out      # the bus line and its seven servos: it ran at 4 Mbaud
        assert termios.tcgetattr(fd) == before
    finally:
        os.close(fd)


@pytest.mark.parametrize("rate", ["0", "-1", "nan", "1e-300", "inf", "1000"])
def test_monitor_checks_its_rate_before_anything_is_sent(bench, capsys, rate):
    """`monitor --rate 0` switched torque off on every servo, then failed as a traceback: the rate
    (0.1 to 100 refreshes a second) is checked first; a servo with torque on keeps it."""
    served, port = bench
    with served.robot.lock:
        for s in served.robot.servos:
            s.write(ITEMS["torque_enable"].address, b"\x01")
    code, out, err = run(capsys, "monitor", "--config", "replica", "--port", port, "--count", "1", "--rate", rate)
    assert code == 2 and "--rate" in one_line(err), (out, err)
    assert out == "" and all(s.torque_enabled for s in served.robot.servos), "nothing was sent"


def dies_at(served, instruction: int, nth: int) -> None:
    """The simulated bus's port is lost (as an adapter unplugged) when the host's `nth` packet of
    `instruction` arrives, before that packet is answered or acted on."""
    server = served.servers["arm"]
    handle, seen = server.arm.handle, []

    def handle_until(data: bytes) -> bytes:
        seen.extend(p for p in PacketReader(None).feed(data)
                    if isinstance(p, InstructionPacket) and p.instruction == instruction)
        if len(seen) >= nth:
            server._stop.set()
            with open(os.devnull, "rb") as null:
                os.dup2(null.fileno(), server.master)      # the pseudo-terminal's far end closes: a hang-up
            return b""
        return handle(data)
    server.arm.handle = handle_until


@pytest.mark.parametrize("argv, instruction, nth", [
    (["scan", "--baud", "4000000,57600"], Instruction.PING, 2),
    (["monitor", "--config", "replica", "--count", "3"], Instruction.READ, 10),
])
def test_a_port_lost_under_a_command_is_one_line_naming_it(bench, capsys, argv, instruction, nth):
    served, port = bench
    dies_at(served, instruction, nth)
    code, out, err = run(capsys, *argv, "--port", port)
    line = one_line(err)
    assert code == 12 and f"{port}: the port was lost (Input/output error)" in line, (code, line)


def test_calibrate_on_a_lost_port_writes_nothing(bench, capsys, tmp_path, monkeypatch):
    served, port = bench
    dies_at(served, Instruction.READ, 8)          # some reads into the first joint
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n" * 40))
    target = tmp_path / "replica.toml"
    code, out, err = run(capsys, "calibrate", "--config", "replica", "--port", port, "--write", str(target), "--yes")
    assert code == 12 and port in one_line(err) and "lost" in one_line(err), (out, err)
    assert not target.exists(), "no configuration written from a calibration that did not end"


def test_setup_on_a_lost_port_says_which_steps_were_written(capsys):
    """A factory-fresh servo alone on the bench; the port is lost while setup writes its EEPROM:
    the one line names the port and the steps the servo took before (and those it did not)."""
    dof = "r_elbow_flexion"
    served = serve(CONFIG, "lockstep", process=False, lab=Lab(factory=True, connected=(dof,)))
    try:
        port = served.buses["arm"]["port"]
        dies_at(served, Instruction.WRITE, 3)       # torque off, the first EEPROM step, then lost
        code, out, err = run(capsys, "setup", "--config", "replica", "--joint", dof, "--port", port, "--yes")
        line = one_line(err)
        plan = [step.split(":")[0].strip() for step in (out + err).split("to make it joint")[1].splitlines()[1:]
                if "->" in step]
        assert code == 12 and f"{port}: the port was lost" in line, (out, err)
        assert plan[0] == "return delay time" and "id" in plan, plan
        assert f"written before it stopped: {plan[0]}; not written: {', '.join(plan[1:])}" in line, line
        fresh = [s for s in served.robot.servos if s.get("return_delay_time") == 0]
        assert len(fresh) == 1 and fresh[0].get("id") == 1, "only the first step reached the servo"
    finally:
        served.stop()


def test_a_can_adapter_lost_under_monitor_is_one_line_naming_it(capsys):
    """The SLCAN adapter's far end closes mid-monitor (the simulator stopped, as an adapter
    unplugged): one line naming the port, not python-can's traceback."""
    served = serve(load_config("replica_can"), "lockstep", process=False, can="slcan")
    try:
        port = served.buses["arm"]["port"]
        server = served.servers["arm"]
        handle, frames_seen = server.arm.handle, []

        def handle_until(arbitration_id, data):
            frames_seen.append(arbitration_id)
            if len(frames_seen) == 40:             # torque off and a few refreshes: then the adapter goes
                threading.Thread(target=server.stop).start()
            return handle(arbitration_id, data)
        server.arm.handle = handle_until
        code, out, err = run(capsys, "monitor", "--config", "replica_can", "--port", port, "--count", "1000",
                             "--rate", "100")
        line = one_line(err)
        assert code == 12 and f"{port}: the port was lost" in line, (code, line)
    finally:
        served.stop()


def test_can_setup_shows_the_motor_and_every_change_before_it_asks(capsys, monkeypatch):
    """CAN setup asked to save to flash before it had shown anything: now the motor found and every
    register it changes come first, then one question; a no leaves the motor as it was."""
    dof = "r_elbow_flexion"
    config = load_config("replica_can")
    served = serve(config, "lockstep", process=False, can="slcan", lab=Lab(factory=True, connected=(dof,)))
    try:
        port = served.buses["arm"]["port"]
        motor = served.robot.motors[[j.dof for j in config.joints].index(dof)]
        assert (motor.can_id, motor.feedback_id) == (1, 0), "factory-fresh"
        for answer, code_wanted in (("n\n", 1), ("y\n", 0)):
            monkeypatch.setattr(sys, "stdin", io.StringIO(answer))
            code, out, err = run(capsys, "setup", "--config", "replica_can", "--joint", dof, "--port", port)
            assert code == code_wanted, out + err
            out = out + err          # the steps and the question go to stderr, with the messages
            shown, _, after = out.partition("write these? [y/N]")
            assert "found DM-J4340 at CAN ID 1, Master ID 0x0" in shown, out
            assert "CAN ID (ESC_ID): 1 -> 4" in shown and "Master ID: 0x0 -> 0x14" in shown, out
            assert "flash" in shown and out.count("[y/N]") == 1, out
            if answer == "n\n":
                assert "nothing written" in after and (motor.can_id, motor.feedback_id, motor.saves) == (1, 0, 0)
        assert "saved to flash" in after and (motor.can_id, motor.feedback_id, motor.saves) == (4, 0x14, 1), after
    finally:
        served.stop()
