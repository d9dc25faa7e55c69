"""The commands added last (excite, identify, retarget, ik, the BVH reader) under input a careless or
unlucky user gives: each case ends in one line and exit status 2 (a refusal), never a traceback, a
hang, a lost file or an impossible number reported as determined."""

import hashlib
import math
import re
import shutil
import signal
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from servodyn.hal.config import CONFIGS_DIR, load_config
from servodyn.loop.log import columns
from servodyn.mocap.bvh import BvhError, format_bvh, read_bvh
from servodyn.mocap.export import arm_clip
from servodyn.mocap.retarget import ArmTarget
from servodyn.model import load_model
from servodyn.errors import ServodynError
from servodyn.tools import excite, identify
from servodyn.tools import ik as ik_command
from servodyn.tools.cli import main
from servodyn.tools.mocap import run_retarget

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
def arm_bvh(tmp_path_factory) -> Path:
    """An arm waving for 40 frames at 120 Hz, as export-bvh writes it (the CMU naming)."""
    target = ArmTarget.of(load_model("human_arm"))
    q = np.zeros((40, 7)) + np.linspace(0, 0.6, 40)[:, None] * np.array([1, 0.5, 0, 1, 0, 0.2, 0])
    path = tmp_path_factory.mktemp("clip") / "arm.bvh"
    path.write_text(format_bvh(arm_clip(target, q, 1 / 120.0), 6))
    return path


def line_of(text: str, word: str) -> int:
    return next(k for k, line in enumerate(text.splitlines(), start=1) if word in line)


@pytest.mark.parametrize("args, words", [
    (["--time", "1e308:"], "--time"),          # once an overflow converting seconds to a frame index
    (["--twist", "nan"], "--twist nan"),       # once scipy's "array must not contain infs or NaNs"
    (["--twist", "inf"], "--twist inf"),       # once "a computation left the range of double precision"
])
def test_retarget_options_out_of_range_are_one_line_naming_the_option(tmp_path, capsys, arm_bvh, args, words):
    code = main(["retarget", str(arm_bvh), "-o", str(tmp_path / "m.csv"), *args])
    err = capsys.readouterr().err
    one_line_refusal(code, err)
    assert words in err, err


@pytest.mark.parametrize("case", ["Frame Time 1e-9", "Frame Time 1e9", "OFFSET 1e308", "position 1e308"])
@pytest.mark.parametrize("command", ["retarget", "mocap info"])
def test_a_clip_with_numbers_no_capture_has_is_one_line_naming_the_line(tmp_path, capsys, arm_bvh, case, command):
    """A frame time of 1e-9 s once made retarget (and view --source) sample 0.25 s at 1e9 Hz, 19 GiB;
    an OFFSET of 1e308 overflowed in a dot product, naming no line."""
    text = arm_bvh.read_text()
    lines = text.splitlines()
    if case.startswith("Frame Time"):
        k = line_of(text, "Frame Time:")
        lines[k - 1] = f"Frame Time: {case.split()[-1]}"
    elif case == "OFFSET 1e308":
        k = line_of(text, "JOINT RightForeArm") + 2
        lines[k - 1] = "OFFSET 1e308 0 0"
    else:
        k = line_of(text, "Frame Time:") + 3        # the third frame's root x position
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
    with np.errstate(all="ignore"):                         # 0 x inf: a NaN in t, as a hostile log has
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


# ------------------------------------------------------------------ every entry, random hostile numbers

HOSTILE = [math.nan, math.inf, -math.inf, 0.0, -1.0, 1e-300, -1e-300, 1e-9, 1e308, -1e308, 1e9]
PER_EXAMPLE_S = 60          # a refusal takes a fraction of a second; past this it is a hang


@contextmanager
def no_hang(seconds: int = PER_EXAMPLE_S):
    def stop(signum, frame):
        raise AssertionError(f"still running after {seconds} s: a hang")
    before = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, before)


def refused(call) -> ServodynError:
    """`call()` raises a ServodynError (never another exception, a result, or a hang) and writes nothing."""
    with no_hang(), warnings.catch_warnings():
        warnings.filterwarnings("error", category=RuntimeWarning)       # an overflow is a wrong number too
        with pytest.raises(ServodynError) as caught:
            call()
    return caught.value


ENTRIES = ["excite", "identify", "retarget", "bvh", "ik"]


@settings(deadline=None, max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(entry=st.sampled_from(ENTRIES), x=st.sampled_from(HOSTILE), y=st.sampled_from(HOSTILE),
       n=st.sampled_from([-5, 0, 1, 1000, 10**9]))
def test_every_entry_refuses_hostile_numbers_with_a_servodyn_error(tmp_path, arm_bvh, entry, x, y, n):
    """The commands' entry functions (tools.excite.run, tools.identify.run, tools.mocap.run_retarget,
    mocap.read_bvh, tools.ik.read_targets and solve_targets) given non-finite, huge or tiny numbers
    where a duration, a count, a margin, a payload, a cut-off, a time step, a span, a twist, a frame
    time, an OFFSET or a sampling period goes. x is always out of range (no value of HOSTILE is a
    duration, a log's time step or a frame time a command takes; a start inside the clip is moved past
    its end), y and n are anything: whichever is checked first, the answer is a ServodynError."""
    quiet = lambda *a, **k: None                                  # noqa: E731
    out = Path(tempfile.mkdtemp(dir=tmp_path)) / f"{entry}.out"      # tmp_path is shared by the examples
    if entry == "excite":
        refused(lambda: excite.run("replica", x, None, out, harmonics=n, margin=y, say=quiet))
    elif entry == "identify":
        log = swing_log(tmp_path / "swing_log.csv", x)
        refused(lambda: identify.run("replica", [str(log)], None, y, False, out, cutoff=y, say=quiet, warn=quiet))
    elif entry == "retarget":
        model = load_model("human_arm")
        start = x if not 0 <= x <= 1 else x + 1e9                 # from 0 to 1 s is inside the 0.325 s clip
        twist = y if not math.isfinite(y) else None
        refused(lambda: run_retarget(str(arm_bvh), model=model, time=f"{start!r}:", twist_deg=twist, output=out,
                                     say=quiet))
    elif entry == "bvh":
        text = re.sub(r"Frame Time: .*", f"Frame Time: {x!r}", arm_bvh.read_text())
        clip = tmp_path / "hostile.bvh"
        clip.write_text(re.sub(r"OFFSET .*", f"OFFSET {y!r} 0 0", text, count=2))
        refused(lambda: read_bvh(clip))
    else:
        path = tmp_path / "targets.csv"
        span = x if math.isfinite(x) and abs(x) > 1 else 1.0       # a span of 1 s, with dt out of range
        path.write_text(f"t,x,y,z\n0,0.3,-0.1,-0.2\n{span!r},0.3,-0.1,-0.25\n")
        model = load_model("human_arm")
        dt = y if not y >= 1e-4 else 1e-9
        refused(lambda: ik_command.solve_targets(model, ik_command.read_targets(path), dt))
    assert not out.exists(), "nothing written"
