"""The firmware under QEMU against the simulated Dynamixel bus (hardware in the loop).

`make fw` builds the images (codegen of the replica, the core in single precision, the C codec);
each test runs one in QEMU with its UART on a TCP socket served by the simulated bus in lock-step.
"""

from __future__ import annotations

import math
import re
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from servodyn.hal.dynamixel.control_table import ITEMS, OperatingMode
from servodyn.model.layout import model_fields
from servodyn.tools.codegen import generate
from servodyn.hal.config import load_config
from servodyn.hal.contact_spec import Push
from servodyn.hil import default_elf, run_qemu, summarize
from servodyn.control.timing import HOME_DURATION, SMALL_TIME_STEP
from runs import run_swing

from helpers import quiet, run_cli

ROOT = Path(__file__).resolve().parent.parent
WHOLE_SWING_TIMEOUT = 900.0   # s of wall clock for the 7,201-tick swing under QEMU
FAULT_TICK = 100          # injections act after this tick's command: the next read sees them
# A starved simulated bus (a loaded machine): the server sleeps before some replies. The long pauses
# are several times the wall time the board's reply timeout (board_uart_wait's polls) lasts under
# QEMU on an idle machine (about 0.35 s): a firmware whose clock ran while it waited took them for
# a silent servo (a timeout fault at the first, with the images before the sync line).
STARVED_PAUSE = 1.2       # s before the replies numbered in STARVED_AT
STARVED_AT = (3, 120)     # a ping of the set-up, a fast sync read of the homing
STARVED_EVERY = 10        # and 20 ms before every 10th reply
HOME_TICKS = int(round(HOME_DURATION / SMALL_TIME_STEP)) + 1
# 10 N down at the hand from 0.3 s into the swing, for 0.3 s: the 10 N case; the prototype
# detected it in 7-11 ms
PUSH = Push("r_hand", (0.0, 0.0, -10.0), 0.3, 0.3)


@pytest.fixture(scope="session")
def images():
    build = subprocess.run(["make", "--no-print-directory", "-s", "fw"], cwd=ROOT, capture_output=True,
                           text=True)
    assert build.returncode == 0, f"make fw failed:\n{build.stdout}\n{build.stderr}"
    return {board: default_elf(board) for board in ("an386", "an500")}


@pytest.fixture(scope="module")
def swing_run(images):
    # the whole swing is CPU-bound in QEMU (about a minute on an idle 2-core machine): on a machine whose cores
    # are shared several times over it takes many times that, so it gets its own, longer bound
    report, record, arm = run_qemu("an386", images["an386"], icount_shift=3, timeout=WHOLE_SWING_TIMEOUT)
    return report, record, arm, summarize(report, record, "replica", 3, "an386")


@pytest.fixture(scope="module")
def host_swing(tmp_path_factory):
    return run_swing("replica", out=tmp_path_factory.mktemp("host_swing"), say=quiet)


def test_codegen_model_is_the_hosts(tmp_path):
    """The generated model is the host's set-up sd_model (derived fields included), so the firmware
    computes nothing at start-up."""
    config = load_config("replica")
    fields = model_fields(config.model)
    assert fields["nbody"] == 7 and fields["ndof"] == 7 and fields["nq"] == 7, "the replica: 7 bodies, one hinge each"
    # the derived first moment is mass x com, as sd_model_setup computes it
    assert np.allclose(fields["body_mcom"], fields["body_mass"][:, None] * fields["body_com"], rtol=1e-12), \
        "body_mcom is mass x com"
    files = generate(config)
    assert "#define SD_MAX_BODY 7" in files["servodyn_gen.h"], "the core's arrays sized to the replica's 7 bodies"
    assert "#define SD_MAX_KNOT 11" in files["servodyn_gen.h"], "sized to the forehand's 11 keyframes"
    for key in ("const sd_model fw_model", "const sd_trajectory fw_swing", "const fw_servo fw_servos",
                "const fw_gains fw_swing_gains", ".swing_ticks = 7201"):
        assert key in files["servodyn_gen.c"], key


def test_codegen_writes_the_python_observers_constants():
    """The firmware's contact rule has the Python loop's constants (servodyn.loop.contact's
    contact_observer): K_O, the low-pass and each joint's threshold to the 9 digits codegen writes,
    the debounce, and the arm time in ticks (40 ms at 1 ms: 2/K_O + 2/low-pass at 100/100); with
    `[safety] contact = false` the firmware does not watch."""
    from dataclasses import replace
    from servodyn.loop.contact import contact_observer
    config = load_config("replica")
    observer = contact_observer(config)
    source = generate(config)["servodyn_gen.c"]
    for key, expected in (("observer_gain", observer.gain), ("observer_lowpass", observer.lowpass),
                          ("contact_threshold", observer.thresholds)):
        written = [float(v) for v in re.findall(rf"\.{key} = SD_R\(([^)]*)\)", source)]
        assert np.allclose(written, expected, rtol=1e-8, atol=0), (key, written, expected)
    assert f".contact_debounce = {observer.debounce}," in source and ".contact_arm_ticks = 40," in source
    assert ".contact = 1," in source, "the replica's [safety] watches for contact"
    off = generate(replace(config, safety=replace(config.guards, contact=False)))["servodyn_gen.c"]
    assert ".contact = 0," in off, "contact = false: the observer runs, its rule stops nothing"


def test_register_addresses_come_from_the_control_table():
    """Every Dynamixel register the firmware names is generated from hal/dynamixel/control_table.py:
    the header defines each at the table's address, and fw_main.c writes no number of its own."""
    header = generate(load_config("replica"))["fw_dynamixel.h"]
    for name, item in (("RETURN_DELAY", "return_delay_time"), ("OPERATING_MODE", "operating_mode"),
                       ("TORQUE_ENABLE", "torque_enable"), ("BUS_WATCHDOG", "bus_watchdog")):
        assert f"#define FW_ADDR_{name} {ITEMS[item].address}\n" in header, f"{name} at the table's address"
    assert f"#define FW_MODE_CURRENT {int(OperatingMode.CURRENT)}\n" in header, "current mode's value"
    source = (ROOT / "firmware/app/fw_main.c").read_text()
    defined = re.findall(r"^#define\s+(\w*(?:ADDR|MODE|ALERT)\w*)", source, flags=re.M)
    assert defined == [], f"fw_main.c defines {defined}: generated from the control table instead"


def test_codegen_cli_refuses_bad_config(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nmodel = "replica"\n[bus.arm]\nkind = "dynamixel"\nbaud = 12\n')
    run = run_cli("codegen", "--config", bad, "-o", tmp_path / "gen")
    assert run.returncode == 2, f"a bad configuration exits 2 (a ConfigError): {run.stderr}"
    assert run.stderr.startswith("servodyn: error:") and "baud" in run.stderr, f"baud 12 is named: {run.stderr}"
    assert "Traceback" not in run.stderr, run.stderr


@pytest.mark.timeout(WHOLE_SWING_TIMEOUT + 300)
@pytest.mark.slow
def test_firmware_swings_the_replica(swing_run, host_swing):
    """The whole swing under QEMU: every goal within one servo unit of the host's double controller
    fed the same measurements, tracking within 10 % of the host loop's on the same bus."""
    report, record, arm, summary = swing_run
    expected_ticks = int(round(HOME_DURATION / SMALL_TIME_STEP)) + 1 + 7201
    assert report["result"] == "done" and report["exit_code"] == 0, report
    assert report["ticks"] == expected_ticks, "2 s of homing at 1 ms, then the 7201 ticks of the swing"
    assert len(record.goals) == expected_ticks, "one Goal Current sync write per tick"
    # float firmware vs double host, same measured state: rounding can flip the last unit only
    assert summary["goal_max_diff_units"] <= 1, summary["goal_diff_counts"]
    host_max = host_swing["tracking_max_rad"]
    assert abs(summary["tracking_max_rad"] - host_max) <= 0.10 * host_max, (summary["tracking_max_rad"], host_max)
    assert math.degrees(summary["tracking_max_rad"]) < 3.0, \
        f"largest tracking error {math.degrees(summary['tracking_max_rad']):.2f} deg"
    # the end of the run switches every servo off
    assert record.torque_off and not any(s.torque_enabled for s in arm.servos), "a servo left with torque on"
    assert report["limited"] == 0, f"{report['limited']} ticks clamped: the swing's time scale fits the servos"
    assert report["stack"] <= 2048, f"{report['stack']} B of stack used; the budget is 2 KB"



@pytest.mark.slow
def test_readme_quotes_this_swing(swing_run, host_swing):
    """README.md's firmware section quotes this run's tracking and the host loop's on the same bus,
    to the 0.001° it prints: the documents' check (tests/test_docs.py) leaves this figure to this
    test, which has the minute-long run under QEMU already."""
    import re
    summary = swing_run[3]
    quoted = re.search(r"tracking max ([0-9.]+)° vs ([0-9.]+)° for the host loop",
                       (ROOT / "README.md").read_text(encoding="utf-8"))
    assert quoted, "README.md no longer quotes the firmware's tracking: update this test with it"
    actual = (f"{math.degrees(summary['tracking_max_rad']):.3f}", f"{math.degrees(host_swing['tracking_max_rad']):.3f}")
    assert quoted.groups() == actual, f"README.md quotes {quoted.groups()}, the runs give {actual}: update README.md"

@pytest.mark.slow
def test_budget_flash_ram_stack(images):
    """The M4F image's footprint against its goals: flash <= 64 KB, RAM (data + bss with a 4 KB
    stack) <= 16 KB; the stack used is checked by the swing test (<= 2 KB)."""
    size = subprocess.run(["arm-none-eabi-size", str(images["an386"])], capture_output=True, text=True)
    text, data, bss = (int(v) for v in size.stdout.splitlines()[1].split()[:3])
    assert text + data <= 64 * 1024, f"flash {text + data} B over the 64 KB goal"
    assert data + bss <= 16 * 1024, f"RAM {data + bss} B (4 KB stack included) over the 16 KB goal"
    nm = subprocess.run(["arm-none-eabi-nm", str(images["an386"])], capture_output=True, text=True).stdout
    names = {line.split()[-1] for line in nm.splitlines() if line.strip()}
    assert not names & {"malloc", "_sbrk", "printf", "puts", "__aeabi_dadd", "__aeabi_f2d", "sin", "cos"}, \
        "no heap, no stdio, no double arithmetic or double libm"


def _fault_run(images, board="an386", **kwargs):
    kwargs.setdefault("args", "ticks=300")
    report, record, arm = run_qemu(board, images[board], icount_shift=3, **kwargs)
    return report, record, arm


def _assert_safe_stop(report, record, arm, fault, code):
    assert report["result"] == "fault" and report["fault"] == fault, report
    assert report["exit_code"] == code, f"a {fault} fault exits {code} (firmware/app's fault codes)"
    assert record.torque_off, "no torque-off sync write after the fault"
    assert not any(s.torque_enabled for s in arm.servos), "a servo left with torque on"


@pytest.mark.slow
def test_silent_servo_stops_with_torque_off(images):
    def silence(k, arm):
        if k == FAULT_TICK:
            arm.inject_fault(3, "silent")
    report, record, arm = _fault_run(images, on_tick=silence)
    _assert_safe_stop(report, record, arm, "timeout", 10)
    assert report["servo"] == 3 and report["fault_tick"] == FAULT_TICK + 1, "servo 3, at the read after the injection"
    assert len(record.goals) == FAULT_TICK + 1          # no command after the silent read


def _starve():
    """A tamper hook that passes every reply on unchanged, some late: STARVED_PAUSE before those
    numbered in STARVED_AT, 20 ms before every STARVED_EVERY-th."""
    count = [0]

    def late(reply):
        count[0] += 1
        if count[0] in STARVED_AT:
            time.sleep(STARVED_PAUSE)
        elif count[0] % STARVED_EVERY == 0:
            time.sleep(0.02)
        return reply
    return late


@pytest.mark.slow
def test_a_starved_bus_changes_nothing(images):
    """The simulated bus slow to answer (as on a machine whose cores are busy): the firmware sleeps
    until the bus has answered, its emulated clock standing still (board_io.c's sync line), so the
    run is the one an unstarved bus gives -- no timeout, every tick, the same commands."""
    report, record, _ = _fault_run(images)
    starved, starved_record, arm = _fault_run(images, tamper=_starve())
    assert starved["result"] == "done" and starved["exit_code"] == 0, \
        f"a reply late in wall time is not a silent servo (the guest's clock must not run meanwhile): {starved}"
    assert starved["ticks"] == report["ticks"] == 300, \
        f"every tick asked for (ticks=300), starved or not (tolerance 0: lock-step): {starved['ticks']}"
    assert starved["missed"] == 0 and starved["lost"] == 0, \
        f"no tick past its period: the waiting is outside the guest's clock: {starved}"
    assert len(starved_record.reads) == len(record.reads) and all(
        np.array_equal(a, b) for a, b in zip(starved_record.reads, record.reads)), \
        "the same measured states (tolerance 0: the plant is lock-stepped to the commands, not to the wall clock)"
    diff = np.abs(np.array(starved_record.goals) - np.array(record.goals)).max()
    assert diff == 0, f"the same Goal Currents (tolerance 0 units: same states, same code), {diff} units apart"
    assert starved_record.torque_off and not any(s.torque_enabled for s in arm.servos), \
        "a servo left with torque on"


@pytest.mark.slow
def test_a_silent_servo_on_a_starved_bus_still_times_out(images):
    """Slow is not silent, and silent is still silent: with the bus starved as above, servo 3 stops
    answering after tick 100 and the firmware's own reply timeout trips at the next read."""
    def silence(k, arm):
        if k == FAULT_TICK:
            arm.inject_fault(3, "silent")
    report, record, arm = _fault_run(images, on_tick=silence, tamper=_starve())
    _assert_safe_stop(report, record, arm, "timeout", 10)
    assert report["servo"] == 3 and report["fault_tick"] == FAULT_TICK + 1, \
        f"servo 3, at the read after the injection (tolerance 0 ticks: a late reply moves no tick): {report}"


@pytest.mark.slow
def test_hardware_error_stops_with_torque_off(images):
    def overload(k, arm):
        if k == FAULT_TICK:
            arm.servos[4].set_hardware_error(0x20)     # overload
    report, record, arm = _fault_run(images, on_tick=overload)
    _assert_safe_stop(report, record, arm, "status", 11)
    assert report["servo"] == 5 and report["fault_tick"] == FAULT_TICK + 1, \
        "servo 5 (servos[4]), at the read after the injection"


@pytest.mark.slow
def test_corrupt_reply_stops_with_torque_off(images):
    replies = []

    def flip(reply):
        replies.append(reply)
        if len(replies) == 7 * 3 + 1 + FAULT_TICK:       # set-up: ping + 2 writes... then reads
            return reply[:20] + bytes([reply[20] ^ 0x10]) + reply[21:]
        return reply
    report, record, arm = _fault_run(images, tamper=flip)
    _assert_safe_stop(report, record, arm, "corrupt", 12)


@pytest.mark.slow
def test_nan_stops_with_torque_off(images):
    report, record, arm = _fault_run(images, args="ticks=300 nan_at=120")
    _assert_safe_stop(report, record, arm, "nonfinite", 13)
    assert report["fault_tick"] == 120 and len(record.goals) == 120, "the NaN at tick 120: no command from it"


@pytest.mark.slow
def test_overflow_stops_with_torque_off(images):
    """Finite measurements whose torque overflows (q = qd = -3e38 in float): the core's step
    flags SD_STATUS_OVERFLOW instead of clamping an inf to the current limit; the firmware stops."""
    report, record, arm = _fault_run(images, args="ticks=300 huge_at=120")
    _assert_safe_stop(report, record, arm, "overflow", 17)
    assert report["fault_tick"] == 120 and len(record.goals) == 120, "the overflow at tick 120: no command from it"


@pytest.mark.slow
def test_overrun_stops_with_torque_off(images):
    """A period shorter than a tick's work (an inverse-dynamics tick takes ~100 us at 125 MIPS)."""
    report, record, arm = _fault_run(images, args="ticks=300 period_us=40")
    _assert_safe_stop(report, record, arm, "overrun", 14)
    assert report["fault_tick"] == 0, "a 40 us period is overrun by the first tick"


@pytest.mark.slow
def test_joint_out_of_range_stops_with_torque_off(images):
    def fling(k, arm):
        if k == FAULT_TICK:
            servo = arm.servos[1]
            servo.set_present(arm.plant.horn(arm.q, arm.qd)[0][1] + 3.0, 0.0, 0.0)
    report, record, arm = _fault_run(images, on_tick=fling)
    _assert_safe_stop(report, record, arm, "range", 15)
    assert report["servo"] == 2, "servo 2 (servos[1]) was flung 3 rad off"


@pytest.mark.slow
def test_following_error_stops_with_torque_off(images):
    """Shoulder abduction reading 0.5 rad off its command: past its 0.15 rad following-error limit
    ([safety]'s default, compiled in by codegen) at the tick it is read, which is the last."""
    def offset(k, arm):
        if k == FAULT_TICK:
            position, velocity = arm.plant.horn(arm.q, arm.qd)
            arm.servos[1].set_present(position[1] - 0.5, velocity[1], 0.0)
    report, record, arm = _fault_run(images, on_tick=offset)
    _assert_safe_stop(report, record, arm, "following_error", 19)
    assert report["servo"] == 2 and report["fault_tick"] == FAULT_TICK + 1, "servo 2, at the read after the offset"
    # the error is the offset plus the tracking error of the moment (well under a degree), in float
    assert abs(report["value_micro"] * 1e-6 - 0.5) < 0.02, report["value_micro"]


@pytest.mark.slow
def test_current_limit_is_limiting_not_a_fault(images):
    """Shoulder abduction reading 20 rad/s too fast: the PD's damping asks for more than the 10.6 N m
    of the current limit; the command is clamped, counted and sent, no fault at that tick. (A
    position 0.5 rad off, as this test once used, is now a following error.) The velocity that
    jumps 20 rad/s is, to the momentum observer, a momentum no modelled torque explains: the run
    then stops on contact at the next tick (the debounce's second), not on the clamp."""
    def offset(k, arm):
        if FAULT_TICK <= k < FAULT_TICK + 10:
            position, velocity = arm.plant.horn(arm.q, arm.qd)
            arm.servos[1].set_present(position[1], velocity[1] + 20.0, 0.0)
    report, record, arm = _fault_run(images, on_tick=offset)
    assert report["limited"] >= 1, "the clamp is counted as limiting"
    limit_units = round(4.4 / 2.69e-3)
    assert abs(int(record.goals[FAULT_TICK + 1][1])) == limit_units, \
        "servo 2's goal at the tick that read the glitch: clamped at the XM540's 4.4 A, 1636 units of 2.69 mA"
    _assert_safe_stop(report, record, arm, "contact", 18)
    assert report["fault_tick"] == FAULT_TICK + 2 and report["servo"] == 2, \
        f"the observer's stop, one tick after the clamp (debounce 2), on servo 2: {report}"


@pytest.mark.slow
def test_cortex_m7_image_runs_the_same_loop(images):
    report, record, arm = _fault_run(images, board="an500")
    assert report["result"] == "done" and report["ticks"] == 300, report
    summary = summarize(report, record, "replica", 3, "an500")
    assert summary["goal_max_diff_units"] <= 1, "float firmware vs double host: rounding flips the last unit only"


@pytest.mark.parametrize("content,words", [
    (b"garbage", ("not an ELF file",)),
    (None, ("not a 32-bit little-endian ARM image",)),      # the Python interpreter: x86-64
])
def test_firmware_refuses_an_image_that_is_not_an_arm_elf(tmp_path, content, words):
    """Checked before QEMU starts: no eight-line register dump, one line naming the file."""
    import sys
    elf = tmp_path / "fw.elf"
    elf.write_bytes(content if content is not None else Path(sys.executable).resolve().read_bytes()[:64])
    res = run_cli("firmware", "--elf", elf, "--out", tmp_path / "out")
    lines = res.stderr.splitlines()
    assert res.returncode == 2 and len(lines) == 1 and lines[0].startswith("servodyn: error: "), res.stderr
    assert str(elf) in lines[0] and all(word in lines[0] for word in words), lines[0]


@pytest.fixture(scope="module")
def python_push(tmp_path_factory):
    """The Python loop on the same push: its detection is the reference the firmware's is held to."""
    return run_swing("replica", out=tmp_path_factory.mktemp("python_push"), contacts=(PUSH,), figure=False,
                     say=quiet)


def push_on_swing(k, arm):
    """on_tick: PUSH on the plant's clock, from the swing's start (homing's ticks, one period each in
    lock-step, as the Python loop counts it)."""
    if k == 0:
        arm.schedule_push(PUSH, origin=HOME_TICKS * SMALL_TIME_STEP)


@pytest.mark.slow
def test_firmware_detects_a_push_as_the_python_loop_does(images, python_push):
    """A 10 N push at the hand 0.3 s into the swing: the firmware's observer (the core's, float, on
    the tables codegen takes from the Python loop's observer) stops with fault 18 within 3 ticks of
    the Python loop's detection on the same push (the rule and constants are the same; float against
    double and the Python loop's dynamic threshold term may move the crossing by a tick or two),
    naming the Python loop's joint, with its residual over that joint's threshold."""
    report, record, arm = _fault_run(images, on_tick=push_on_swing, args=f"ticks={HOME_TICKS + 500}")
    _assert_safe_stop(report, record, arm, "contact", 18)
    assert python_push["stop_reason"] == "contact", python_push.get("error")
    python = python_push["contact"]
    firmware_t = (report["fault_tick"] - HOME_TICKS) * SMALL_TIME_STEP
    assert PUSH.start <= firmware_t <= PUSH.start + 0.02, \
        f"detected {1e3 * (firmware_t - PUSH.start):.0f} ms after the push (the issue's 10 N goal: 7-11 ms)"
    assert abs(firmware_t - python["detected_t_s"]) <= 3 * SMALL_TIME_STEP + 1e-9, \
        (firmware_t, python["detected_t_s"])
    config = load_config("replica")
    joint = next(j for j in config.joints if j.id == report["servo"])
    assert joint.dof == python["joint"], f"servo {report['servo']} ({joint.dof}), the Python loop's {python['joint']}"
    threshold = config.guards.contact_threshold[config.model.dof_names.index(joint.dof)]
    assert report["value_micro"] * 1e-6 > threshold, (report["value_micro"], threshold)
    assert report["link_servo"] in [j.id for j in config.joints], report
