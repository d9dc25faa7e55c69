"""The commands added last (excite, identify, retarget, ik, the BVH reader) under input a careless or
unlucky user gives: each case ends in one line and exit status 2 (a refusal), never a traceback, a
hang, a lost file or an impossible number reported as determined."""

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from servodyn.hal.config import CONFIGS_DIR, load_config
from servodyn.loop.log import columns
from servodyn.mocap.bvh import BvhError, format_bvh, read_bvh
from servodyn.mocap.export import arm_clip
from servodyn.mocap.retarget import ArmTarget
from servodyn.model import load_model
from servodyn.tools.cli import main

BAD_INPUT = 2        # servodyn.errors.ExitCode.BAD_INPUT


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line_refusal(code: int, err: str) -> None:
    assert code == BAD_INPUT, f"bad input: exit status 2, got {code}: {err}"
    assert err.count("\n") == 1 and err.startswith("servodyn: error: "), f"one line, got {err!r}"


TINY_BVH = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT RightArm
\t{
\t\tOFFSET 0 -1 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -3 0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.0083333
0 0 0 0 0 0 0 0 0
0 0 0 0 0 0 0 0 1
"""


# ------------------------------------------------------------------ an output that is an input

def test_excite_refuses_to_write_over_its_configuration(tmp_path, capsys):
    config = tmp_path / "my.toml"
    shutil.copy(CONFIGS_DIR / "replica.toml", config)
    before = digest(config)
    code = main(["excite", "--config", str(config), "--out", str(config)])
    one_line_refusal(code, capsys.readouterr().err)
    assert digest(config) == before, "the configuration is untouched"


@pytest.mark.parametrize("onto", ["clip", "config", "map", "a symlink to the map"])
def test_retarget_refuses_to_write_over_its_inputs(tmp_path, capsys, onto):
    clip, config, names = tmp_path / "c.bvh", tmp_path / "my.toml", tmp_path / "names.toml"
    clip.write_text(TINY_BVH)
    shutil.copy(CONFIGS_DIR / "replica.toml", config)
    names.write_text('[right]\nthorax = "Hips"\nupper_arm = "RightArm"\n')
    link = tmp_path / "link.csv"
    link.symlink_to(names)
    output = {"clip": clip, "config": config, "map": names, "a symlink to the map": link}[onto]
    before = {p: digest(p) for p in (clip, config, names)}
    code = main(["retarget", str(clip), "--config", str(config), "--map", str(names), "-o", str(output)])
    one_line_refusal(code, capsys.readouterr().err)
    assert {p: digest(p) for p in before} == before, "every input untouched"


def test_ik_refuses_to_write_over_its_targets(tmp_path, capsys):
    targets = tmp_path / "targets.csv"
    targets.write_text("t,x,y,z\n0,0.3,-0.1,-0.2\n0.5,0.3,-0.1,-0.25\n")
    before = digest(targets)
    code = main(["ik", "human_arm", "--path", str(targets), "-o", str(targets)])
    one_line_refusal(code, capsys.readouterr().err)
    assert digest(targets) == before, "the targets file is untouched"


# ------------------------------------------------------------------ a hang, a design out of bounds

@pytest.mark.parametrize("args, words", [
    (["--harmonics", "1000"], "to 59"),          # 120 samples a period tell 59 harmonics apart
    (["--duration", "2", "--harmonics", "30"], "to 20"),    # 20 x 0.5 Hz = identify's 10 Hz low-pass
    (["--duration", "700"], "600 s"),            # the longest a swing plays
    (["--duration", "0.1"], "from 0.2 s"),       # two harmonics inside the 10 Hz low-pass
])
def test_excite_refuses_a_design_out_of_bounds_at_once(tmp_path, capsys, args, words):
    out = tmp_path / "x.csv"
    code = main(["excite", "--config", "replica", *args, "--out", str(out)])
    err = capsys.readouterr().err
    one_line_refusal(code, err)
    assert words in err and not out.exists(), err


# ------------------------------------------------------------------ numbers no one checked: mocap

@pytest.fixture(scope="module")
def arm_bvh(tmp_path_factory) -> str:
    """An arm waving for 40 frames at 120 Hz, as export-bvh writes it (the CMU naming)."""
    target = ArmTarget.of(load_model("human_arm"))
    q = np.zeros((40, 7)) + np.linspace(0, 0.6, 40)[:, None] * np.array([1, 0.5, 0, 1, 0, 0.2, 0])
    return format_bvh(arm_clip(target, q, 1 / 120.0), 6)


def line_of(text: str, word: str) -> int:
    return next(k for k, line in enumerate(text.splitlines(), start=1) if word in line)


@pytest.mark.parametrize("args, words", [
    (["--time", "1e308:"], "--time"),          # once an overflow converting seconds to a frame index
    (["--twist", "nan"], "--twist nan"),       # once scipy's "array must not contain infs or NaNs"
    (["--twist", "inf"], "--twist inf"),       # once "a computation left the range of double precision"
])
def test_retarget_options_out_of_range_are_one_line_naming_the_option(tmp_path, capsys, arm_bvh, args, words):
    clip = tmp_path / "arm.bvh"
    clip.write_text(arm_bvh)
    code = main(["retarget", str(clip), "-o", str(tmp_path / "m.csv"), *args])
    err = capsys.readouterr().err
    one_line_refusal(code, err)
    assert words in err, err


@pytest.mark.parametrize("case", ["Frame Time 1e-9", "Frame Time 1e9", "OFFSET 1e308", "position 1e308"])
@pytest.mark.parametrize("command", ["retarget", "mocap info"])
def test_a_clip_with_numbers_no_capture_has_is_one_line_naming_the_line(tmp_path, capsys, arm_bvh, case, command):
    """A frame time of 1e-9 s once made retarget (and view --source) sample 0.25 s at 1e9 Hz, 19 GiB;
    an OFFSET of 1e308 overflowed in a dot product, naming no line."""
    lines = arm_bvh.splitlines()
    if case.startswith("Frame Time"):
        k = line_of(arm_bvh, "Frame Time:")
        lines[k - 1] = f"Frame Time: {case.split()[-1]}"
    elif case == "OFFSET 1e308":
        k = line_of(arm_bvh, "JOINT RightForeArm") + 2
        lines[k - 1] = "OFFSET 1e308 0 0"
    else:
        k = line_of(arm_bvh, "Frame Time:") + 3        # the third frame's root x position
        lines[k - 1] = "1e308 " + lines[k - 1].split(" ", 1)[1]
    clip = tmp_path / "bad.bvh"
    clip.write_text("\n".join(lines) + "\n")
    args = ["retarget", str(clip), "-o", str(tmp_path / "m.csv")] if command == "retarget" else ["mocap", "info", str(clip)]
    code = main(args)
    err = capsys.readouterr().err
    one_line_refusal(code, err)
    assert f"line {k}:" in err, err
    with pytest.raises(BvhError):
        read_bvh(clip)


# ------------------------------------------------------------------ numbers no one checked: ik

@pytest.mark.parametrize("targets, args, words", [
    ("t,x,y,z\n0,0.3,-0.1,-0.2\n1,0.3,-0.1,-0.25\n", ["--dt", "1e-9"], "--dt"),     # 1e9 samples: 7.45 GiB
    ("t,x,y,z\n0,0.3,-0.1,-0.2\n1e9,0.3,-0.1,-0.25\n", [], "spans 1e+09 s"),          # 1e11 samples at 10 ms
    (b"\x8a\x00\xff\xfe binary", [], "not a text file"),                             # once UnicodeDecodeError
])
def test_ik_paths_no_one_can_sample_are_one_line(tmp_path, capsys, targets, args, words):
    path = tmp_path / "targets.csv"
    path.write_bytes(targets if isinstance(targets, bytes) else targets.encode())
    out = tmp_path / "m.csv"
    code = main(["ik", "human_arm", "--path", str(path), "-o", str(out), *args])
    err = capsys.readouterr().err
    one_line_refusal(code, err)
    assert words in err and not out.exists(), err


# ------------------------------------------------------------------ numbers no one checked: identify

def swing_log(path: Path, step: float, rows: int = 400) -> Path:
    """A swing_log.csv (loop.log.columns) every `step` s: each joint swinging, 0.1 A of current."""
    dofs = load_config("replica").model.dof_names
    header = columns(dofs)
    k = np.arange(rows)
    values = {"t": k * step}
    for d in dofs:
        values.update({f"q_{d}": 0.5 * np.sin(k / 50), f"q_d_{d}": 0.5 * np.sin(k / 50), f"current_{d}": 0.1 + 0 * k})
    table = np.column_stack([values.get(h, np.zeros(rows)) for h in header])
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in row) for row in table) + "\n")
    return path


def test_identify_on_a_log_whose_time_step_no_servo_has_is_one_line(tmp_path, capsys):
    """t every 1e-300 s: once a 'Singular matrix' traceback from the filter's design at 1e300 Hz."""
    log = swing_log(tmp_path / "swing_log.csv", 1e-300)
    code = main(["identify", "--config", "replica", str(log), "--out", str(tmp_path / "id")])
    err = capsys.readouterr().err
    one_line_refusal(code, err)
    assert "time step of 1e-300 s" in err, err
