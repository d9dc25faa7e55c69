"""`servodyn swing --controller python|native|qemu:BOARD|PORT` (servodyn.loop.link_controllers): the
general firmware application plays any built-in configuration's motion — keyframed or a sampled
trajectory (the excitation) — loaded and streamed over the host link, as a Linux process, under
QEMU and on a serial port, and the log and summary are the Python loop's. Agreement: every command
within 1 servo unit of the host's double-precision controller fed the same measured state
(hil.link_agreement, the oracle of the generated firmware's agreement)."""

from __future__ import annotations

import json
import re
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from servodyn.control.motion import motion_path
from servodyn.control.trajectory import read_trajectory_csv
from servodyn.hil import link_agreement, run_link
from servodyn.loop.link_controllers import ControllerChoice, ControllerError, parse_controller
from servodyn.loop.link_load import KNOT_SPACING, KNOT_TOLERANCE, MIN_KNOT_GAP, plan
from servodyn.hal.config import load_config
from helpers import PTY, run_cli, sim_process

ROOT = Path(__file__).resolve().parent.parent
LINK = ROOT / "build" / "fw" / "native" / "servodyn-fw-link"
EXCITATION_S = 6.0


@pytest.fixture(scope="module")
def built():
    for target in ("build/fw/native/servodyn-fw-link", "build/fw/an386-link/servodyn-fw-link.elf"):
        build = subprocess.run(["make", "--no-print-directory", "-s", target], cwd=ROOT, capture_output=True, text=True)
        assert build.returncode == 0, f"the build failed:\n{build.stdout}\n{build.stderr}"


@pytest.fixture(scope="module")
def excitation(tmp_path_factory):
    """A short excitation of the replica, as `servodyn excite` writes it (a CSV every 5 ms)."""
    path = tmp_path_factory.mktemp("excite") / "excitation.csv"
    result = run_cli("excite", "--config", "replica", "--duration", f"{EXCITATION_S:g}", "--harmonics", "3",
                     "-o", path)
    assert result.returncode == 0, result.stderr
    return path


@pytest.mark.parametrize("text, expected", [
    ("python", ControllerChoice("python")), ("native", ControllerChoice("native")),
    ("qemu:an386", ControllerChoice("qemu", board="an386")), ("qemu:f405", ControllerChoice("qemu", board="f405")),
    ("/dev/ttyACM0", ControllerChoice("port", path="/dev/ttyACM0"))])
def test_the_controller_forms(text, expected):
    assert parse_controller(text) == expected and str(parse_controller(text)) == text


@pytest.mark.parametrize("text, says", [("qemu:an500", "QEMU runs the controller on qemu:an386"),
                                        ("teensy", "python, native, qemu:BOARD")])
def test_a_controller_that_is_none_is_refused_in_one_line(text, says, tmp_path):
    with pytest.raises(ControllerError, match=re.escape(says)):
        parse_controller(text)
    result = run_cli("swing", "--controller", text, "--out", tmp_path)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and says in lines[0], result.stderr


def test_qemu_refuses_the_wall_clock(tmp_path):
    result = run_cli("swing", "--controller", "qemu:an386", "--realtime", "--out", tmp_path)
    assert result.returncode == 2 and "lock-step" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_a_sampled_motion_streams_a_knot_every_few_periods(excitation):
    """The excitation's rows are 5 ms apart: the link plan keeps every other one (10 ms), as the
    quintic through them is the file's curve within KNOT_TOLERANCE, and the plan's swing — what the
    controller plays — is the file's motion within that tolerance at every control period."""
    config = load_config("replica")
    p = plan(config, str(excitation), time_scale=1.0)
    rows = read_trajectory_csv(excitation, config.model.dof_names)
    spacing = np.diff([k.t_us for k in p.knots]) * 1e-6
    assert abs(np.median(spacing) - KNOT_SPACING) < 1e-6, f"knots {np.median(spacing) * 1e3:.2f} ms apart"
    assert len(p.knots) < 0.6 * len(rows.t), f"{len(p.knots)} knots for {len(rows.t)} rows"
    written = motion_path(str(excitation), config.model).at_scale(1.0, config.control_period)
    assert np.abs(p.swing.q - written.q).max() <= KNOT_TOLERANCE


def test_the_excitation_on_the_native_controller_is_the_host_controllers(built, excitation):
    """A sampled trajectory through the Linux process, lock-stepped: every Goal Current within 1
    unit of the host's double controller from the same measured state, over homing and the whole
    motion."""
    run = run_link("native", "replica", str(excitation), 1.0)
    assert run.error is None, run.error
    agreement = link_agreement("replica", run)
    assert agreement["motion_ticks"] == len(run.plan.swing.t), agreement
    assert agreement["max_units"] <= 1, agreement


def test_swing_on_qemu_has_the_python_loops_summary(built, tmp_path):
    """`servodyn swing --controller qemu:an386`: the forehand on the Cortex-M4F image under QEMU,
    lock-stepped to the simulated arm; the log, summary and figure of the Python loop, the
    controller's report (its worst tick, with the link's work) in the summary."""
    result = run_cli("swing", "--controller", "qemu:an386", "--out", tmp_path, timeout=900)
    assert result.returncode == 0, result.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["completed"] and summary["stop_reason"] == "completed" and summary["torque_off"]
    assert summary["controller"] == "qemu:an386" and summary["ticks"] == 7201
    assert summary["tracking_max_rad"] < np.radians(0.5), summary["tracking_max_rad"]
    report = summary["controller_report"]
    assert report["result"] == "done" and report["missed"] == 0 and report["worst_work"] > 0, report
    assert (tmp_path / "swing_tracking.png").stat().st_size > 10_000
    assert "qemu-system-arm: -serial" not in result.stdout + result.stderr, "QEMU's set-up chatter is not said"


@pytest.mark.serial
def test_a_board_on_a_serial_port(built, tmp_path):
    """A controller already running on its own line — the Linux process started with link=pty, as a
    board's USB port appears — driving its own bus (`servodyn sim` in real time): `swing
    --controller PORT` asks before it moves, declined moves nothing; with --yes the forehand plays
    to its end in real time, and the controller stays on for the next run."""
    # the observer's thresholds are the lock-step simulator's clean runs: against a real-time
    # simulator in another process on a busy machine its jitter can cross them, and this test is
    # about the serial port, so its configuration is the replica's with contact detection off
    config = tmp_path / "replica_no_contact.toml"
    config.write_text((ROOT / "hal" / "configs" / "replica.toml").read_text().replace("[safety]\n",
                                                                                    "[safety]\ncontact = false\n"))
    with sim_process("--config", "replica") as (_, banner):
        bus = PTY.findall("".join(banner))[0]
        proc = subprocess.Popen([str(LINK), bus, "link=pty", "realtime", "tolerance_us=200000", "reply_ms=1000",
                                 "baud=4000000"], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        try:
            line = proc.stderr.readline()
            found = PTY.findall(line)
            assert found and "host link is on" in line, line
            declined = run_cli("swing", "--config", config, "--controller", found[0], "--out", tmp_path / "no",
                               input="n\n")
            assert declined.returncode == 1 and "will switch torque on" in declined.stdout + declined.stderr
            t0 = time.monotonic()
            result = run_cli("swing", "--config", config, "--controller", found[0], "--yes", "--out", tmp_path / "yes",
                             timeout=300)
            assert result.returncode == 0, result.stderr
            summary = json.loads((tmp_path / "yes" / "summary.json").read_text())
            assert summary["completed"] and summary["clock"] == "realtime" and summary["ticks"] == 7201
            assert time.monotonic() - t0 > 7.2, "the motion took its own 7.2 s of wall time"
            assert proc.poll() is None, "the board stays on after the run"
        finally:
            proc.kill()
            proc.wait()


CLIP = Path("/usr/share/assimp/models/BVH/01_01.bvh")
needs_clip = pytest.mark.skipif(not CLIP.exists(), reason="assimp-testmodels not installed (make test installs it)")


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """Four seconds of CMU 01_01 retargeted onto the replica, at 1.1 x the time scale validate
    --fit finds for it (the retarget report's)."""
    folder = tmp_path_factory.mktemp("clip")
    result = run_cli("retarget", CLIP, "--config", "replica", "--time", "4:8", "-o", folder / "clip.csv",
                     "--report", folder)
    assert result.returncode in (0, 1), result.stderr
    report = json.loads((folder / "report.json").read_text())
    return folder / "clip.csv", 1.1 * report["validate"]["fit_time_scale"]


@needs_clip
def test_knots_are_a_period_apart_at_least(clip):
    """The clip's rows (every 39 ms played) and the gain schedule's knots: where two would fall
    within MIN_KNOT_GAP, the gain knot goes — a quintic over a millisecond or less is ill-conditioned
    in single precision (it spiked the feed-forward until the contact guard stopped the run)."""
    path, scale = clip
    config = load_config("replica")
    p = plan(config, str(path), time_scale=scale)
    gaps = np.diff([k.t_us for k in p.knots])
    assert gaps.min() >= MIN_KNOT_GAP * 1e6, f"knots {gaps.min()} µs apart"
    assert np.allclose(p.swing_gains.t * 1e6, [k.t_us for k in p.knots], rtol=0, atol=1e-3), \
        "the host's schedule is the knots' gains, linear between them, as the controller's"


@needs_clip
def test_a_retargeted_clip_on_the_native_controller_is_the_host_controllers(built, clip):
    """The clip's 23 s through the Linux process, lock-stepped: it plays to its end and every Goal
    Current is within 1 unit of the host's double controller (the motion's clock past 16 s in
    single precision lost a microsecond; each segment's clock is now whole microseconds)."""
    path, scale = clip
    run = run_link("native", "replica", str(path), scale)
    assert run.error is None, run.error
    agreement = link_agreement("replica", run)
    assert agreement["motion_ticks"] == len(run.plan.swing.t) > 20_000, agreement
    assert agreement["max_units"] <= 1, agreement
