"""The commands added last (excite, identify, retarget, ik, the BVH reader) under input a careless or
unlucky user gives: each case ends in one line and exit status 2 (a refusal), never a traceback, a
hang, a lost file or an impossible number reported as determined."""

import hashlib
import shutil
from pathlib import Path

import pytest

from servodyn.hal.config import CONFIGS_DIR
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
