"""LeRobot datasets validated end to end through the CLI (servodyn validate CONFIG --lerobot DIR), malformed
ones refused in one line, and LeRobot calibrations imported (servodyn calibrate --from-lerobot)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from servodyn.hal.config import load_config
from servodyn.control.motion import load_motion
from servodyn.validation.lerobot_write import SO101_NAMES, write_dataset
from helpers import run_cli


def lerobot_values(q: np.ndarray, limits, units: str) -> np.ndarray:
    """Joint angles (rad, the so101 configuration's joints: direction +1, gear 1, zero at the range's
    middle) as LeRobot records them: body joints in degrees ((raw − mid)·360/4095 with raw − mid =
    q·4096/2π) or ±100 over the range; the gripper 0..100 over its range."""
    out = np.empty_like(q)
    for j, (lower, upper) in enumerate(limits):
        middle, half = (lower + upper) / 2, (upper - lower) / 2
        if j == len(limits) - 1:                                  # the gripper: RANGE_0_100
            out[:, j] = ((q[:, j] - lower) / (upper - lower)) * 100
        elif units == "degrees":
            out[:, j] = (q[:, j] * 4096 / (2 * math.pi)) * 360 / 4095
        else:
            out[:, j] = ((q[:, j] - middle) / half) * 100
    return out



FPS = 30.0
CHECK_TIE = 0.01        # two checks within 1 % of each other are a tie (a PWM joint's envelope and duty)


@pytest.fixture(scope="module")
def so101():
    return load_config("so101")


@pytest.fixture(scope="module")
def pick(so101):
    """so101_pick sampled as a recording: 30 fps, its joint angles (rad) and the configuration's limits."""
    motion = load_motion("so101_pick", so101.model)
    t = np.arange(int(round(motion.duration * FPS)) + 1) / FPS
    return motion, [j.position_limits for j in so101.joints], t


def recorded(pick, slower: float, units: str) -> np.ndarray:
    motion, limits, _ = pick
    t = np.arange(int(round(motion.duration * slower * FPS)) + 1) / FPS
    return lerobot_values(motion.at(np.minimum(t / slower, motion.duration))[0], limits, units)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """`servodyn validate so101 so101_pick --fit`: the motion itself, checked every control period, its
    verdict, the joint and checks nearest or past their limits, its fit time scale."""
    out = tmp_path_factory.mktemp("pick")
    done = run_cli("validate", "so101", "so101_pick", "--fit", "--out", out)
    assert done.returncode == 1, done.stderr          # the shoulder overloads at recorded speed
    report = json.loads((out / "report.json").read_text())
    allowed = lambda check: 1.0 if check == "position" else report["margin"]
    joint = max(report["joints"], key=lambda d: report["joints"][d]["worst_ratio"] / allowed(report["joints"][d]["worst_check"]))
    row = report["joints"][joint]
    ties = {c for c, r in row["checks"].items() if r >= row["worst_ratio"] * (1 - CHECK_TIE)}
    return {"passed": report["passed"], "joint": joint, "ratio": row["worst_ratio"], "checks": ties,
            "fit": report["fit_time_scale"]}


LAYOUTS = [("v3.0", "degrees", None, []),                               # units from the codebase version
           ("v2.1", "range_m100_100", None, []),                        # ... the older ±100
           ("v2.1", "degrees", "degrees", []),                          # stated in meta/info.json
           ("v3.0", "range_m100_100", None, ["--units", "range_m100_100"])]   # stated on the command line


@pytest.mark.slow
@pytest.mark.parametrize("version, units, declared, flags", LAYOUTS)
def test_pick_recorded_is_judged_as_the_motion_itself(tmp_path, so101, pick, reference, version, units, declared,
                                                      flags):
    """so101_pick written as a LeRobot dataset (episode 0 at its own speed, episode 1 twice slower), read
    back through `servodyn validate so101 --lerobot`: episode 0 gets the motion's own verdict (validate
    so101 so101_pick, run independently) with the same worst joint and check (a tie of two checks within
    1 % may go either way), its worst ratio within 2 % and its fit time scale from the motion's to 2 %
    above it (the 30 Hz frames and the 5 Hz low-pass move the peaks by under 1 %; the episode's fit is
    found to 1 %, upwards). Episode 1 is the same path twice slower: it passes, and since a time scale
    multiplies the played clock, its fit is half the motion's (to 2 %). Exit 1: one episode fails."""
    root = write_dataset(tmp_path / "data", [(0, recorded(pick, 1.0, units)), (1, recorded(pick, 2.0, units))], FPS,
                         version, declared)
    done = run_cli("validate", "so101", "--lerobot", root, "--jobs", "2", "--out", tmp_path / "out", *flags)
    assert done.returncode == 1, done.stdout + done.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["units"] == units
    first, slow = report["episodes"]
    for row in (first, slow):
        assert list(row) == ["episode_index", "passed", "worst_check", "worst_joint", "worst_ratio", "fit_time_scale"]
    assert first["episode_index"] == 0 and first["passed"] is reference["passed"] is False
    assert first["worst_joint"] == reference["joint"] == "shoulder_lift"
    assert first["worst_check"] in reference["checks"]
    assert first["worst_ratio"] == pytest.approx(reference["ratio"], rel=0.02)
    assert reference["fit"] * 0.995 <= first["fit_time_scale"] <= reference["fit"] * 1.02
    assert slow["episode_index"] == 1 and slow["passed"] is True
    assert slow["fit_time_scale"] == pytest.approx(reference["fit"] / 2, rel=0.02)
    lines = done.stdout.splitlines()
    assert any(line.startswith("FAIL episode 0 (6.00 s): shoulder_lift") for line in lines), done.stdout
    assert any(line.startswith("PASS episode 1 (12.00 s)") for line in lines), done.stdout
    if (version, units, flags) == ("v3.0", "degrees", []):      # docs/lerobot.md quotes this run's lines
        quoted = (Path(__file__).resolve().parents[1] / "docs" / "lerobot.md").read_text(encoding="utf-8")
        assert [line for line in lines if " episode " in line and line not in quoted] == []


@pytest.mark.slow
def test_a_gentle_episode_passes_and_exits_0(tmp_path, pick):
    """Only the slow episode (--episode 1) of a two-episode dataset: every episode asked passes, exit 0,
    and the report lists that one alone."""
    root = write_dataset(tmp_path / "data", [(0, recorded(pick, 1.0, "degrees")), (1, recorded(pick, 3.0, "degrees"))],
                         FPS)
    done = run_cli("validate", "so101", "--lerobot", root, "--episode", "1", "--out", tmp_path / "out")
    assert done.returncode == 0, done.stdout + done.stderr
    episodes = json.loads((tmp_path / "out" / "report.json").read_text())["episodes"]
    assert [e["episode_index"] for e in episodes] == [1] and episodes[0]["passed"] is True
    assert episodes[0]["fit_time_scale"] < 1                  # three times slower than a motion that needs 1.26


# ---------------------------------------------------------------------------- malformed datasets

def _good(root: Path, pick) -> Path:
    return write_dataset(root, [(0, recorded(pick, 1.0, "degrees"))], FPS)


def _rewrite_data(root: Path, change) -> None:
    path = root / "data" / "chunk-000" / "file-000.parquet"
    pq.write_table(change(pq.read_table(path)), path)


def _replace(table, name, array):
    return table.set_column(table.schema.get_field_index(name), name, array)


def _missing_column(root, pick):
    _rewrite_data(_good(root, pick), lambda t: t.drop_columns(["action"]))


def _ragged(root, pick):
    def change(t):
        rows = t.column("action").to_pylist()
        rows[7] = rows[7][:5]
        return _replace(t, "action", pa.array(rows, type=pa.list_(pa.float32())))
    _rewrite_data(_good(root, pick), change)


def _nan(root, pick):
    def change(t):
        rows = t.column("action").to_pylist()
        rows[40][2] = float("nan")
        return _replace(t, "action", pa.array(rows, type=t.column("action").type))
    _rewrite_data(_good(root, pick), change)


def _unknown_name(root, pick):
    write_dataset(root, [(0, recorded(pick, 1.0, "degrees"))], FPS, names=SO101_NAMES[:2] + ["elbow_roll.pos"] + SO101_NAMES[3:])


def _empty_episode(root, pick):
    write_dataset(root, [(0, recorded(pick, 1.0, "degrees")), (1, np.zeros((0, 6)))], FPS)


def _not_parquet(root, pick):
    (_good(root, pick) / "data" / "chunk-000" / "file-000.parquet").write_bytes(b"PAR1 not really\n" * 20)


def _no_info(root, pick):
    (_good(root, pick) / "meta" / "info.json").unlink()


MALFORMED = {
    "missing column": (_missing_column, "missing column 'action'"),
    "ragged vectors": (_ragged, "ragged: row 7 has 5 values, its names 6"),
    "NaN": (_nan, "row 40, value 2 is nan"),
    "a name not in the configuration": (_unknown_name, "'elbow_roll.pos' names no joint of 'so101'"),
    "an empty episode": (_empty_episode, "episode 1 is empty"),
    "a parquet that is not one": (_not_parquet, "not a readable parquet file"),
    "no meta/info.json": (_no_info, "no meta/info.json"),
}


@pytest.mark.parametrize("fault", MALFORMED)
def test_a_malformed_dataset_is_refused_in_one_line(tmp_path, pick, fault):
    """Each fault: exit 2, one line on stderr naming it (and the file), no verdict on stdout, no report."""
    make, says = MALFORMED[fault]
    make(tmp_path / "data", pick)
    done = run_cli("validate", "so101", "--lerobot", tmp_path / "data", "--out", tmp_path / "out")
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], done.stderr
    assert "episode 0 (" not in done.stdout and not (tmp_path / "out" / "report.json").exists()


# ---------------------------------------------------------------------------- smoothing and reading

def test_the_low_pass_does_not_lag():
    """A 1 Hz sway recorded at 30 fps, smoothed as an episode is: its peaks stay where they were (within
    2 ms; a one-way 4th-order Butterworth at the same cutoff delays them by tens of ms, which this test
    would see) and keep their height within 0.5 %."""
    from scipy.signal import butter, sosfilt
    from servodyn.validation.lerobot_motion import CUTOFF_HZ, smooth
    t = np.arange(0, 10, 1 / FPS)
    q = np.sin(2 * np.pi * 1.0 * t)[:, None]
    grid, smoothed = smooth(t, q, FPS, CUTOFF_HZ)
    fine = np.linspace(2.0, 2.6, 6001)                          # one peak, 2.25 s
    from scipy.interpolate import CubicSpline
    between = CubicSpline(grid, smoothed[:, 0])(fine)
    peak = fine[np.argmax(between)]
    assert peak == pytest.approx(2.25, abs=0.002)               # sin peaks at 1/4 s past each whole second
    assert between.max() == pytest.approx(1.0, rel=0.005)
    one_way = sosfilt(butter(4, CUTOFF_HZ / (FPS / 2), output="sos"), q[:, 0])
    late = fine[np.argmax(CubicSpline(t, one_way)(fine))]
    assert late - 2.25 > 0.02                                   # the lag a causal filter would add


def test_without_pyarrow_one_line_says_how_to_install_it(monkeypatch):
    import sys
    from servodyn.validation.lerobot import DatasetError, pyarrow_parquet
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    with pytest.raises(DatasetError, match=r"pip install 'servodyn\[lerobot\]'") as err:
        pyarrow_parquet()
    assert "\n" not in str(err.value)


def test_observation_state_is_read_on_request(tmp_path, so101, pick):
    """--feature observation.state reads that column, not action: a dataset whose state column has a NaN
    and whose action is clean is refused only when the state is asked for."""
    from servodyn.validation.lerobot import DatasetError, read_dataset
    root = _good(tmp_path / "data", pick)

    def change(t):
        rows = t.column("observation.state").to_pylist()
        rows[3][1] = float("nan")
        return _replace(t, "observation.state", pa.array(rows, type=t.column("observation.state").type))
    _rewrite_data(root, change)
    assert len(read_dataset(root, "action").episodes[0].t) == 181
    with pytest.raises(DatasetError, match="column 'observation.state': row 3, value 1 is nan"):
        read_dataset(root, "observation.state")


# ---------------------------------------------------------------------------- calibration

def lerobot_calibration(so101, drive_modes=None) -> tuple[dict, dict]:
    """A LeRobot calibration of the SO-101 (as lerobot-calibrate writes it: Present Position steps about the
    half-turn homing) and, per joint, the middle and half-range it records (steps)."""
    from servodyn.hal.feetech.table import STEP
    middles = [1898, 2248, 1973, 2348, 2047.5, 2168]
    calibration, recorded = {}, {}
    for k, joint in enumerate(so101.joints):
        lower, upper = so101.model.lower[k], so101.model.upper[k]
        half = 2047.5 if joint.dof == "wrist_roll" else math.floor(0.85 * (upper - lower) / 2 / STEP)
        middle = middles[k]
        calibration[joint.dof] = {"id": joint.id, "drive_mode": (drive_modes or {}).get(joint.dof, 0),
                                  "homing_offset": 100 * k - 250, "range_min": int(middle - half),
                                  "range_max": int(middle + half)}
        recorded[joint.dof] = (middle, half)
    return calibration, recorded


def test_calibration_import_round_trip(tmp_path, so101):
    """`servodyn calibrate --config so101 --from-lerobot CAL --write FILE --yes`: each joint's zero is the
    recorded range's middle in Present Position steps (hal.feetech.table.STEP a step; the gripper's range
    laid on the model's, its middle at the model's middle), its limits the recorded stops (wrist_roll's
    full turn clipped to the model's). Round trip: the written file gives back LeRobot's integers. And a
    Present Position read through the HAL's formula (q = (steps·STEP − zero_offset)/(direction·gear))
    is the angle the dataset reader makes of LeRobot's degrees for the same reading, (raw − mid)·360/4095,
    within 1e-5 rad (the file's six significant digits)."""
    from servodyn.hal.feetech.table import STEP
    from servodyn.validation.lerobot_motion import to_radians
    calibration, recorded = lerobot_calibration(so101)
    (tmp_path / "cal.json").write_text(json.dumps(calibration))
    done = run_cli("calibrate", "--config", "so101", "--from-lerobot", tmp_path / "cal.json", "--write",
                   tmp_path / "mine.toml", "--yes")
    assert done.returncode == 0, done.stderr
    mine = load_config(tmp_path / "mine.toml")
    for k, joint in enumerate(mine.joints):
        middle, half = recorded[joint.dof]
        lower, upper = so101.model.lower[k], so101.model.upper[k]
        centre = (lower + upper) / 2 if joint.dof == "gripper" else 0.0
        assert joint.direction == 1
        assert (joint.zero_offset + centre) / STEP == pytest.approx(middle, abs=0.01), joint.dof
        stops = (max(centre - half * STEP, lower), min(centre + half * STEP, upper))
        assert joint.position_limits == pytest.approx(stops, abs=1e-5), joint.dof
        if joint.dof != "wrist_roll":                       # the range comes back as LeRobot's integers
            assert round((joint.zero_offset + centre) / STEP + joint.position_limits[0] / STEP - centre / STEP) \
                == calibration[joint.dof]["range_min"]
    raw = np.array([[m + d for m, _ in recorded.values()] for d in (-300, 0, 250)])
    middles = np.array([m for m, _ in recorded.values()])
    hal = (raw * STEP - np.array([j.zero_offset for j in mine.joints]))
    degrees = (raw - middles) * 360 / 4095
    reader = to_radians(degrees, "degrees", mine, list(range(6)))
    assert reader[:, :5] == pytest.approx(hal[:, :5], abs=1e-5)     # the gripper is 0..100, not degrees


def test_a_flipped_calibration_is_refused(tmp_path, so101):
    """shoulder_lift with drive_mode 1 (LeRobot negates its reading: lerobot#1130's flipped drive mode)
    against the model's direction +1: exit 2, one line naming the joint, nothing written. (DESIGN.md's
    form, `servodyn calibrate --from-lerobot FILE`: the SO-101's configuration unless --config names one.)"""
    calibration, _ = lerobot_calibration(so101, {"shoulder_lift": 1})
    (tmp_path / "cal.json").write_text(json.dumps(calibration))
    done = run_cli("calibrate", "--from-lerobot", tmp_path / "cal.json", "--write",      # so101 by default
                   tmp_path / "mine.toml", "--yes")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert "'shoulder_lift' has drive_mode 1" in lines[-1] and "flipped" in lines[-1], done.stderr
    assert not (tmp_path / "mine.toml").exists()


def test_a_joint_on_a_dynamixel_bus_is_not_imported(tmp_path):
    """The replica's joints are on Dynamixel buses, where LeRobot writes the drive mode into the servo
    (which servodyn's setup clears): its calibration is not read, in one line, exit 2."""
    replica = load_config("replica")
    joint = replica.joints[0]
    (tmp_path / "cal.json").write_text(json.dumps({joint.dof: {"id": joint.id, "drive_mode": 0, "homing_offset": 0,
                                                               "range_min": 1000, "range_max": 3000}}))
    done = run_cli("calibrate", "--config", "replica", "--from-lerobot", tmp_path / "cal.json", "--joint", joint.dof,
                   "--write", tmp_path / "mine.toml", "--yes")
    assert done.returncode == 2
    assert "dynamixel bus" in done.stderr.strip().splitlines()[-1] and not (tmp_path / "mine.toml").exists()


def test_names_as_a_table_of_one_list_are_read(tmp_path, pick):
    """LeRobot v2.0's info.json gives a feature's names as {"motors": [...]}: the same six joints."""
    from servodyn.validation.lerobot import read_dataset
    root = write_dataset(tmp_path / "data", [(0, recorded(pick, 1.0, "degrees"))], FPS, "v2.1")
    info = json.loads((root / "meta" / "info.json").read_text())
    info["features"]["action"]["names"] = {"motors": SO101_NAMES}
    (root / "meta" / "info.json").write_text(json.dumps(info))
    dataset = read_dataset(root)
    assert dataset.names == SO101_NAMES and dataset.version == "v2.1" and dataset.episodes[0].values.shape == (181, 6)
