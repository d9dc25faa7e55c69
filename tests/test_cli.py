"""The `servodyn` command line: torques, models, export, and one clear line for bad input."""

import csv
import os
import subprocess
import sys

import numpy as np
import pytest

import servodyn
from servodyn.tools.demo import reach_motion


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "servodyn.tools.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=120, cwd=cwd)


def read_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], dtype=float)


def write_traj(path, t, names, q, qd=None, qdd=None):
    header = ["t"] + [f"q_{n}" for n in names]
    cols = [t[:, None], q]
    if qd is not None:
        header += [f"qd_{n}" for n in names]
        cols.append(qd)
    if qdd is not None:
        header += [f"qdd_{n}" for n in names]
        cols.append(qdd)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(np.hstack(cols).tolist())


def test_torques_with_full_state_equal_the_api(tmp_path):
    arm = servodyn.load_model("human_arm")
    t, q, qd, qdd = reach_motion(arm)
    write_traj(tmp_path / "traj.csv", t, arm.dof_names, q, qd, qdd)
    res = run("torques", "human_arm", tmp_path / "traj.csv", "-o", tmp_path / "tau.csv")
    assert res.returncode == 0, res.stderr
    assert "2001 samples" in res.stderr, "the 2.0 s reach every 1 ms, both ends included (a message: stderr)"
    header, data = read_csv(tmp_path / "tau.csv")
    assert header == ["t"] + [f"tau_{n}" for n in arm.dof_names], "t, then one tau column per dof in model order"
    assert np.array_equal(data[:, 0], t), "the time column is the trajectory's, unchanged"
    assert np.array_equal(data[:, 1:], arm.inverse_dynamics(q, qd, qdd)), "full precision in the CSV"


def test_torques_derive_velocity_and_acceleration_from_a_spline(tmp_path):
    """Given only q of the smooth reach at 1 ms, the spline's qd and qdd reproduce the
    torques of the exact derivatives within 1e-3 relative (the ends excepted: a not-a-knot
    spline cannot know the motion starts at rest)."""
    arm = servodyn.load_model("human_arm")
    t, q, qd, qdd = reach_motion(arm)
    write_traj(tmp_path / "traj.csv", t, arm.dof_names, q)
    res = run("torques", "human_arm", tmp_path / "traj.csv", "-o", tmp_path / "tau.csv")
    assert res.returncode == 0, res.stderr
    _, data = read_csv(tmp_path / "tau.csv")
    exact = arm.inverse_dynamics(q, qd, qdd)
    inner = slice(50, -50)
    err = np.abs(data[inner, 1:] - exact[inner]).max() / np.abs(exact).max()
    assert err <= 1e-3, f"spline-derived torques differ by {err:.2e}"


def test_models_lists_the_builtins():
    res = run("models")
    assert res.returncode == 0, res.stderr
    assert "human_arm" in res.stdout and "human15" in res.stdout, "both built-in models listed"


def test_export_loads_in_pinocchio(tmp_path):
    import pinocchio as pin
    res = run("export", "human_arm", tmp_path / "arm.urdf")
    assert res.returncode == 0, res.stderr
    model = pin.buildModelFromUrdf(str(tmp_path / "arm.urdf"))
    assert model.nq == 7, "human_arm's 7 hinges: shoulder 3, elbow, forearm, wrist 2"
    assert sum(i.mass for i in model.inertias) == pytest.approx(3.5), "human_arm's 3.50 kg, every body's mass kept"


GOOD_HEADER = "t," + ",".join(f"q_{n}" for n in servodyn.load_model("human_arm").dof_names)


@pytest.mark.parametrize("content,message", [
    ("", "empty file"),
    ("time,q_a\n0,1\n", "first column must be 't'"),
    (GOOD_HEADER + ",q_elbow\n", "unknown column 'q_elbow'"),
    ("t,q_r_shoulder_flexion\n0,0\n", "missing column q_r_shoulder_abduction"),
    (GOOD_HEADER + "\n", "no data rows"),
    (GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n0.001,0,0,0,0,0,0\n", "row 3 has 7 values"),
    (GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n0.001,0,0,x,0,0,0,0\n", "row 3, column 'q_r_shoulder_rotation': 'x' is not a number"),
    (GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n0.001,0,0,nan,0,0,0,0\n", "not finite"),
    (GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n0,0,0,0,0,0,0,0\n", "time must increase"),
    (GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n0.001,0,0,0_5,0,0,0,0\n", "row 3, column 'q_r_shoulder_rotation': '0_5' is not a number"),
    (GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n1,0,0,1e308,0,0,0,0\n2,0,0,-1e308,0,0,0,0\n3,0,0,0,0,0,0,0\n",
     "t = 0 s (sample 1): the spline's velocity or acceleration overflows"),
    (GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n1e-300,0,0,1,0,0,0,0\n2e-300,0,0,0,0,0,0,0\n", "overflows"),
])
def test_bad_trajectories_give_one_line_and_exit_2(tmp_path, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    res = run("torques", "human_arm", path, "-o", tmp_path / "out.csv")
    assert res.returncode == 2, f"bad input exits 2 (a CliError), got {res.returncode}: {res.stderr}"
    assert message in res.stderr, res.stderr
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, "one line, no traceback"
    assert not (tmp_path / "out.csv").exists(), "no torque file for a refused trajectory"


def test_a_byte_order_mark_before_the_header_is_dropped(tmp_path):
    """Spreadsheets save UTF-8 CSV with a byte-order mark; the header's 't' is still 't'."""
    (tmp_path / "bom.csv").write_text(GOOD_HEADER + "\n0,0,0,0,0,0,0,0\n1,0,0,0,0,0,0,0\n", encoding="utf-8-sig")
    res = run("torques", "human_arm", tmp_path / "bom.csv", "-o", tmp_path / "tau.csv")
    assert res.returncode == 0, res.stderr
    assert read_csv(tmp_path / "tau.csv")[1].shape == (2, 8), "both samples, t and 7 torques"


@pytest.mark.parametrize("args,message", [
    (("torques", "no_such_model", "x.csv", "-o", "y.csv"), "not a built-in model"),
    (("torques", "human_arm", "missing.csv", "-o", "y.csv"), "cannot read"),
    (("export", "human_arm", "arm.txt"), "name the file .urdf"),
])
def test_bad_arguments_give_one_line(tmp_path, args, message):
    res = run(*args, cwd=tmp_path)
    assert res.returncode == 2, f"bad input exits 2 (a CliError), got {res.returncode}: {res.stderr}"
    assert message in res.stderr and "Traceback" not in res.stderr, res.stderr


def test_bad_model_file_gives_one_line(tmp_path):
    (tmp_path / "m.toml").write_text("[[body]]\nname='a'\n[body.solid]\ntype='sphere'\nradius=0\nmass=1\n")
    res = run("export", tmp_path / "m.toml", tmp_path / "m.urdf")
    assert res.returncode == 2, f"a bad model exits 2 (a ModelError), got {res.returncode}: {res.stderr}"
    assert "dimensions must be positive" in res.stderr and "Traceback" not in res.stderr, res.stderr


def test_demo_prints_the_torque_profile(tmp_path):
    res = run("demo", "--out", tmp_path / "demo")
    assert res.returncode == 0, res.stderr
    assert "peak" in res.stdout and "inverse dynamics" in res.stdout, "the timing line and the peak row"
    for name in ("torques.csv", "motion.csv", "torques.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 0, f"{name} written and not empty"


def test_torques_refuses_a_trajectory_beyond_the_limits(tmp_path):
    arm = servodyn.load_model("human_arm")
    t, q, qd, qdd = reach_motion(arm)
    q[100:, arm.dof_names.index("r_elbow_flexion")] = 3.0
    write_traj(tmp_path / "traj.csv", t, arm.dof_names, q, qd, qdd)
    res = run("torques", "human_arm", tmp_path / "traj.csv", "-o", tmp_path / "tau.csv")
    assert res.returncode == 2, f"the elbow's limit is 2.618 rad (150 deg); 3 rad is refused: {res.stderr}"
    assert "sample 101), dof 'r_elbow_flexion': position 3 rad beyond the limit" in res.stderr, \
        f"the first sample out of range, q[100], is sample 101: {res.stderr}"
    res = run("torques", "human_arm", tmp_path / "traj.csv", "-o", tmp_path / "tau.csv", "--ignore-limits")
    assert res.returncode == 0, f"--ignore-limits skips the check: {res.stderr}"
    write_traj(tmp_path / "ok.csv", t, arm.dof_names, *reach_motion(arm)[1:])
    res = run("torques", "human_arm", tmp_path / "ok.csv", "-o", tmp_path / "tau.csv", "--max-velocity", "0.5")
    assert res.returncode == 2 and "speed" in res.stderr, \
        f"the reach peaks at 2.86 rad/s (shoulder flexion), beyond --max-velocity 0.5: {res.stderr}"


def test_sim_serves_the_bus_and_stops_cleanly_on_ctrl_c():
    """`servodyn sim` prints the pseudo-terminal's path; dynamixel-sdk opens it and servo 1 (the
    replica's XM540-W270, model number 1120) answers a ping; SIGINT, sent with the client still
    connected, ends it with status 0 within 5 s, the stop line on stdout and nothing on stderr."""
    import re
    import select
    import signal
    import time
    sdk = pytest.importorskip("dynamixel_sdk")
    # SIGINT as a terminal delivers it, even when this test runs from a background job (which
    # starts with SIGINT ignored, and Python then installs no KeyboardInterrupt handler)
    proc = subprocess.Popen([sys.executable, "-m", "servodyn.tools.cli", "sim"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    port = None
    try:
        assert select.select([proc.stdout], [], [], 60)[0], "the path is printed at start-up"
        first = proc.stdout.readline()
        path = re.search(r" on (/dev/\S+)$", first.strip())
        assert path, first
        port = sdk.PortHandler(path.group(1))
        assert port.openPort() and port.setBaudRate(4_000_000), "the replica's bus runs at 4 Mbps"
        assert sdk.PacketHandler(2.0).ping(port, 1) == (1120, sdk.COMM_SUCCESS, 0), \
            "servo 1, an XM540-W270 (model number 1120), answers with no error"
        proc.send_signal(signal.SIGINT)
        began = time.monotonic()
        out, err = proc.communicate(timeout=5)
        took = time.monotonic() - began
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        if port is not None:
            port.closePort()
    assert proc.returncode == 0 and took < 5, f"SIGINT ended it with status {proc.returncode} after {took:.1f} s"
    assert "stopped after" in out, out
    assert err == "", err


def assert_one_line_error(res, *words):
    """Bad input: exit 2 and exactly one stderr line, `servodyn: error: ...`, naming the problem."""
    assert res.returncode == 2, f"bad input exits 2, got {res.returncode}: {res.stderr}"
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("servodyn: error: "), f"one line, no traceback: {res.stderr}"
    for word in words:
        assert word in lines[0], f"'{word}' missing from: {lines[0]}"


@pytest.mark.parametrize("column,value", [("qd", 1e154), ("qdd", 1e308)])
def test_torques_that_overflow_are_refused_not_written_as_zero(tmp_path, column, value):
    """Finite values whose torques overflow double precision: the core zeroes them; the CLI must
    refuse, naming the file and the sample, and write no torque file."""
    arm = servodyn.load_model("human_arm")
    t = np.array([0.0, 0.5, 1.0])
    state = {"qd": np.zeros((3, arm.nq)), "qdd": np.zeros((3, arm.nq))}
    state[column][1] = value
    write_traj(tmp_path / "traj.csv", t, arm.dof_names, np.zeros((3, arm.nq)), state["qd"], state["qdd"])
    res = run("torques", "human_arm", tmp_path / "traj.csv", "-o", tmp_path / "tau.csv", "--ignore-limits")
    assert_one_line_error(res, "traj.csv", "t = 0.500 s (sample 2)", "overflow")
    assert not (tmp_path / "tau.csv").exists(), "no torque file of zeros"


@pytest.mark.parametrize("args,words", [
    (("torques", "human_arm", "ok.csv", "-o", "folder"), ("folder: is a folder",)),
    (("torques", "human_arm", "ok.csv", "-o", "/dev/full"), ("/dev/full", "No space left")),
    (("export", "human_arm", "folder.urdf"), ("folder.urdf: is a folder",)),
    (("experiment", "still", "--out", "ok.csv"), ("ok.csv: is a file where a folder is needed",)),
    (("swing", "--out", "ok.csv"), ("ok.csv: is a file where a folder is needed",)),
    (("validate", "replica", "tennis_forehand", "--out", "ok.csv"), ("ok.csv: is a file where a folder",)),
    (("codegen", "-o", "ok.csv"), ("ok.csv: is a file where a folder is needed",)),
    (("demo", "--out", "ok.csv"), ("ok.csv: is a file where a folder is needed",)),
    (("demo", "--out", "ok.csv/sub"), ("is a file where a folder is needed",)),
])
def test_unwritable_output_gives_one_line(tmp_path, args, words):
    """Every command that writes: an output that is a folder, a full device, or a folder path
    through a file is one line naming the path, not a traceback."""
    arm = servodyn.load_model("human_arm")
    write_traj(tmp_path / "ok.csv", np.array([0.0, 1.0]), arm.dof_names, np.zeros((2, arm.nq)))
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder.urdf").mkdir()
    if not os.path.exists("/dev/full") and "/dev/full" in args:
        pytest.skip("no /dev/full here")
    assert_one_line_error(run(*args, cwd=tmp_path), *words)


@pytest.mark.parametrize("args,words", [
    (("export", "garbage.urdf", "out.urdf"), ("garbage.urdf: cannot read URDF", "not XML")),
    (("codegen", "--config", "binary.toml", "-o", "gen"), ("binary.toml: not a text file",)),
    (("swing", "--config", "folder.toml"), ("folder.toml: is a folder",)),
    (("validate", "replica", "binary.toml"), ("binary.toml: not a text file",)),
])
def test_unreadable_input_files_give_one_line_naming_the_file(tmp_path, args, words):
    """No library logging and no traceback: exactly one line that names the file."""
    (tmp_path / "garbage.urdf").write_text("garbage <robot")
    (tmp_path / "binary.toml").write_bytes(bytes(range(256)) * 4)
    (tmp_path / "folder.toml").mkdir()
    assert_one_line_error(run(*args, cwd=tmp_path), *words)


@pytest.mark.parametrize("scale,words", [
    ("-1", ("--time-scale", "positive")), ("nan", ("--time-scale",)), ("inf", ("--time-scale",)),
    ("0", ("--time-scale", "got 0")), ("1e9", ("1e+09", "at most 600 s")), ("1e-6", ("1e-06", "too fast")),
])
def test_swing_refuses_a_bad_time_scale_in_one_line(tmp_path, scale, words):
    assert_one_line_error(run("swing", "--time-scale", scale, "--out", tmp_path / "out"), *words)


@pytest.mark.parametrize("flag,value", [("--max-velocity", "nan"), ("--max-velocity", "-1"),
                                        ("--max-acceleration", "nan")])
def test_torques_refuses_a_limit_that_is_not_positive(tmp_path, flag, value):
    """--max-velocity nan used to switch the check off and write the torques."""
    arm = servodyn.load_model("human_arm")
    write_traj(tmp_path / "ok.csv", np.array([0.0, 1.0]), arm.dof_names, np.zeros((2, arm.nq)))
    res = run("torques", "human_arm", tmp_path / "ok.csv", "-o", tmp_path / "tau.csv", flag, value)
    assert_one_line_error(res, "limit must be a positive number", f"got {value}")
    assert not (tmp_path / "tau.csv").exists()


def test_a_mixed_robot_needs_a_port_per_bus(tmp_path):
    done = run("swing", "--config", "replica_mixed", "--port", "/dev/ttyUSB0", "--out", tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "2 buses (shoulder, wrist): give each its port as --port BUS=PATH" in done.stderr, done.stderr
