"""What a newcomer trips on (issue 21, item 7): the help and the version, a list of what ships,
and every mistake ending in one line `servodyn: error: ...` with exit status 2, never a traceback."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib.metadata import version

import pytest


def run(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "servodyn.tools.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=cwd, env={**os.environ, **(env or {})})


def one_error_line(res, *words):
    """The result failed with exit 2 and one line `servodyn: error: ...` holding every word."""
    assert res.returncode == 2, f"exit {res.returncode}, stderr: {res.stderr}"
    lines = res.stderr.splitlines()
    assert len(lines) == 1, f"one line on stderr, got {len(lines)}:\n{res.stderr}"
    assert lines[0].startswith("servodyn: error: "), f"argparse's prefix, got {lines[0]!r}"
    for word in words:
        assert word in lines[0], f"{word!r} missing from {lines[0]!r}"
    return lines[0]


# ---------------------------------------------------------------------------- help, version, list

def test_every_subcommand_has_a_one_line_description():
    res = run("--help", env={"COLUMNS": "80"})
    assert res.returncode == 0, res.stderr
    listing = res.stdout.split("COMMAND\n", 1)[1].split("\n\n", 1)[0].splitlines()
    from servodyn.tools.cli import VERBS
    commands = list(VERBS)
    assert len(listing) == len(commands), \
        f"{len(commands)} subcommands, {len(listing)} lines: a description wrapped or is missing:\n" + "\n".join(listing)
    for line, name in zip(listing, commands):
        words = line.split()
        assert words[0] == name and len(words) > 2, f"'{name}' and its description on one line, got {line!r}"
        assert len(line) <= 80, f"{line!r} is wider than 80 columns"


def test_version_is_the_packages():
    res = run("--version")
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"servodyn {version('servodyn')}", \
        f"the installed package's metadata version, got {res.stdout!r}"


def test_list_names_every_builtin_model_configuration_and_motion():
    from servodyn.control.motion import builtin_motions
    from servodyn.hal.config import builtin_configs
    from servodyn.model import builtin_models
    res = run("list", "--json")
    assert res.returncode == 0, res.stderr
    found = json.loads(res.stdout)
    assert [m["name"] for m in found["models"]] == list(builtin_models()), "every built-in model, in order"
    assert [c["name"] for c in found["configurations"]] == list(builtin_configs()), "every built-in configuration"
    assert [m["name"] for m in found["motions"]] == list(builtin_motions()), "every built-in motion"
    replica = next(c for c in found["configurations"] if c["name"] == "replica")
    assert replica["buses"] == {"arm": "dynamixel"} and replica["model"] == "replica", \
        "a configuration says its model and its buses' kinds"
    forehand = next(m for m in found["motions"] if m["name"] == "tennis_forehand")
    assert forehand["duration_s"] == pytest.approx(1.8), "the forehand's keyframes span 1.8 s"
    text = run("list")
    assert text.returncode == 0, text.stderr
    for name in ["human15", "replica_can", "tennis_forehand"]:
        assert re.search(rf"^\s+{name}\s", text.stdout, re.M), f"{name} on a line of its own in the text listing"


# ---------------------------------------------------------------------------- options that make no sense

@pytest.mark.parametrize("args, words", [
    (["validate", "replica", "tennis_forehand", "--repeat", "-1"], ["--repeat", "1 or more", "-1"]),
    (["validate", "replica", "tennis_forehand", "--repeat", "two"], ["--repeat", "whole number"]),
    (["torques", "human_arm", "t.csv", "-o", "tau.csv", "--top", "-3"], ["--top", "0 or more"]),
    (["firmware", "--icount-shift", "40"], ["--icount-shift", "from 0 to 10"]),
    (["view", "--http-port", "-80"], ["--http-port", "from 0 to 65535"]),
    (["view", "--port", "99999"], ["--port", "from 0 to 65535"]),      # the earlier name, still taken
    (["bogus"], ["invalid choice"]),
    ([], ["COMMAND"]),
])
def test_a_count_that_makes_no_sense_is_refused_in_one_line(tmp_path, args, words):
    one_error_line(run(*args, cwd=tmp_path), *words)
    assert not any(tmp_path.iterdir()), "nothing written for a refused command"


def test_the_soak_refuses_no_workers():
    res = subprocess.run([sys.executable, "-m", "servodyn.tools.cli", "soak", "--jobs", "0"], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, f"one line, exit 2: {res.stderr}"
    assert "--jobs" in res.stderr and "1 or more" in res.stderr, res.stderr


# ---------------------------------------------------------------------------- codegen

def test_codegen_says_it_takes_keyframes_for_a_csv(tmp_path):
    (tmp_path / "retimed.csv").write_text("t,q_a\n0,0\n0.001,0\n")
    line = one_error_line(run("codegen", "--motion", tmp_path / "retimed.csv", "-o", tmp_path / "gen"),
                          "keyframes", "retimed.csv")
    assert "TOML" not in line, f"not a TOML parser's complaint about a CSV: {line}"
    assert not (tmp_path / "gen").exists(), "nothing generated"


# ---------------------------------------------------------------------------- the swing

@pytest.mark.parametrize("args", [["--port", "/dev/servodyn-no-such-port"],
                                  ["--config", "replica_can", "--port", "servodyn-no-such-adapter"]])
def test_a_port_that_does_not_open_is_one_line_and_no_run(tmp_path, args):
    res = run("swing", *args, "--out", tmp_path / "out")
    one_error_line(res, "cannot open", "No such file or directory")
    assert "torque off" not in res.stdout + res.stderr, "nothing was switched on, so nothing is switched off"
    assert res.stdout == "", f"nothing else said for a run that never started: {res.stdout!r}"
    for never in ("swing_log.csv", "summary.json"):
        assert not (tmp_path / "out" / never).exists(), f"{never} written for a run that never started"


def test_a_refused_swing_is_one_line_and_verbose_lists_every_violation(tmp_path):
    res = run("swing", "--time-scale", "1", "--out", tmp_path / "out")
    line = one_error_line(res, "would leave a servo's limits", "--verbose lists them", "--fit")
    count = int(re.search(r"\((\d+) violations", line).group(1))
    assert count > 1, f"the forehand at human speed breaks several limits on the replica: {line}"
    assert res.stdout == "" and not (tmp_path / "out").exists(), "nothing ran, nothing said or written"
    verbose = run("swing", "--time-scale", "1", "--out", tmp_path / "out", "--verbose")
    assert verbose.returncode == 2 and verbose.stdout == "", f"exit {verbose.returncode}: {verbose.stdout}"
    *listed, last = verbose.stderr.splitlines()
    assert last == line, "the same one error line, last on stderr"
    assert len(listed) == count, f"--verbose lists all {count} violations, one a line (stderr): {verbose.stderr}"
    assert listed[0].strip() in line, "the one line's violation is the first listed"


# ---------------------------------------------------------------------------- huge but finite numbers

def _csv(path, names, t, q, qd, qdd):
    import numpy as np
    header = ["t"] + [f"{k}_{n}" for k in ("q", "qd", "qdd") for n in names]
    rows = np.hstack([t[:, None], q, qd, qdd])
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(x)) for x in row) for row in rows) + "\n")


def test_readable_keeps_ordinary_numbers_and_shortens_huge_ones():
    from servodyn.readable import fixed, percent
    assert fixed(3.14159, 3) == "3.142" and fixed(-12.5, 2) == "-12.50", "ordinary numbers as :.Nf prints them"
    assert fixed(1.8463e295, 2) == "1.85e+295", "a huge number in scientific notation"
    assert percent(1.002) == "100.2%" and percent(3e297) == "3.00e+299%", "percentages likewise"
    assert fixed(float("inf")) == "inf", "inf stays inf"


def test_huge_torques_print_as_numbers_a_person_reads(tmp_path):
    import numpy as np
    import servodyn
    arm = servodyn.load_model("human_arm")
    t = np.arange(10) * 1e-3
    q = np.tile((np.nan_to_num(arm.lower, posinf=0, neginf=0) + np.nan_to_num(arm.upper, posinf=0, neginf=0)) / 2,
                (10, 1))
    _csv(tmp_path / "huge.csv", arm.dof_names, t, q, np.zeros_like(q), np.full_like(q, 1e295))
    res = run("torques", "human_arm", tmp_path / "huge.csv", "-o", tmp_path / "tau.csv")
    assert res.returncode == 0, res.stderr
    peaks = [line for line in res.stdout.splitlines() if "peak |tau|" in line]
    assert len(peaks) == 7, res.stdout
    for line in peaks:
        assert len(line) < 60 and re.search(r"\d\.\d{3}e\+29\d N·m$", line), f"short, in scientific notation: {line!r}"


def test_a_huge_position_in_the_validators_lines_is_readable(tmp_path):
    import numpy as np
    import servodyn
    names = servodyn.load_model("replica").dof_names
    t = np.arange(10) * 1e-3
    q = np.zeros((10, len(names)))
    q[:, 0] = 1e300
    _csv(tmp_path / "far.csv", names, t, q, np.zeros_like(q), np.zeros_like(q))
    res = run("validate", "replica", tmp_path / "far.csv", "--out", tmp_path / "out")
    assert res.returncode == 1, f"a fail, not an error: {res.stderr}"
    lines = [line for line in res.stdout.splitlines() if not line.startswith("wrote ")]   # (long paths)
    assert max(map(len, lines)) < 200, f"no line of hundreds of digits:\n{res.stdout}"
    assert "reaches 1.000e+300 rad" in res.stdout, res.stdout


# ---------------------------------------------------------------------------- supply voltage, strict JSON, numpy

def test_a_tiny_supply_voltage_is_refused_with_the_data_sheets_range(tmp_path):
    line = one_error_line(run("validate", "replica", "tennis_forehand", "--supply-voltage", "5e-324",
                              "--out", tmp_path / "out"), "--supply-voltage", "[5.55, 100] V", "data sheets")
    assert "nan" not in line.lower() and not (tmp_path / "out").exists(), "refused before anything is computed"
    from servodyn.hal.config import CONFIGS_DIR
    config = tmp_path / "tiny.toml"
    config.write_text((CONFIGS_DIR / "replica.toml").read_text() + "\n[supply]\nvoltage = 5e-324\n")
    one_error_line(run("validate", config, "tennis_forehand", "--out", tmp_path / "out"),
                   "tiny.toml: supply: 'voltage'", "11.1 V")
    one_error_line(run("validate", "replica_can", "tennis_forehand", "--supply-voltage", "11", "--out",
                       tmp_path / "out"), "[12, 100] V", "24 V"), "the CAN motors' data sheets rate them at 24 V"
    res = run("validate", "replica", "tennis_forehand", "--supply-voltage", "11.1", "--time-scale", "3",
              "--out", tmp_path / "ok")
    assert res.returncode == 0, f"a supply the data sheet rates passes: {res.stderr}"


def test_report_json_is_strict_and_names_what_is_not_finite(tmp_path):
    from servodyn.report.validation import report_json
    res = run("validate", "replica", "tennis_forehand", "--time-scale", "3", "--out", tmp_path)
    assert res.returncode == 0, res.stderr
    text = (tmp_path / "report.json").read_text()
    json.loads(text, parse_constant=lambda token: pytest.fail(f"{token} in report.json: not JSON"))
    with pytest.raises(ValueError, match=r"joints\.r_elbow_flexion\.peak_current_a = nan is not a finite number"):
        report_json({"passed": False, "joints": {"r_elbow_flexion": {"peak_current_a": float("nan")}}})
    with pytest.raises(ValueError, match=r"violations\.0\.limit = inf"):
        report_json({"violations": [{"limit": float("inf")}]})


def test_no_numpy_warning_reaches_the_user(tmp_path):
    import numpy as np
    import servodyn
    names = servodyn.load_model("replica").dof_names
    t = np.arange(10) * 1e-3
    q = np.zeros((10, len(names)))
    _csv(tmp_path / "wild.csv", names, t, q, np.zeros_like(q), np.full_like(q, 1e295))
    res = run("validate", "replica", tmp_path / "wild.csv", "--out", tmp_path / "out")
    line = one_error_line(res, "double precision", "overflow")
    assert "Warning" not in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert not (tmp_path / "out" / "report.json").exists(), "no report computed from an overflow"


# ---------------------------------------------------------------------------- the configuration

@pytest.mark.parametrize("key, value, words", [
    ("torque_constant", 1e-300, ["'torque_constant' 1e-300 is below 0.01", "N m per A", "slip of units"]),
    ("torque_constant", 1e300, ["'torque_constant' 1e+300 is beyond 100"]),
    ("gear_ratio", 1e-3, ["'gear_ratio' 0.001 is below 0.1", "ten times the servo's speed"]),
    ("gear_ratio", 1e300, ["'gear_ratio' 1e+300 is beyond 100"]),
])
def test_an_absurd_torque_constant_or_gear_is_refused_at_load(tmp_path, key, value, words):
    from servodyn.hal.config import CONFIGS_DIR
    text = (CONFIGS_DIR / "replica.toml").read_text()
    config = tmp_path / "absurd.toml"
    config.write_text(re.sub(rf"^{key} = .*$", f"{key} = {value!r}", text, count=1, flags=re.M))
    line = one_error_line(run("codegen", "--config", config, "-o", tmp_path / "gen"), "absurd.toml: joint 1", *words)
    assert not (tmp_path / "gen").exists(), f"nothing compiled for the firmware: {line}"


# ---------------------------------------------------------------------------- wrongly typed keys

def _builtin(kind):
    from servodyn.control.motion import builtin_motions
    from servodyn.hal.config import CONFIGS_DIR
    from servodyn.model import builtin_models
    return {"config": CONFIGS_DIR / "replica.toml", "model": builtin_models()["human_arm"],
            "motion": builtin_motions()["tennis_forehand"]}[kind]


@pytest.mark.parametrize("kind", ["config", "model", "motion"])
@pytest.mark.parametrize("key, value, words", [("name", "false", ["'name' must be a non-empty string", "False"]),
                                               ("description", "[]", ["'description' must be a string", "[]"])])
def test_a_wrongly_typed_key_is_refused_in_one_line(tmp_path, kind, key, value, words):
    source = _builtin(kind).read_text()
    # the key's first assignment (a multi-line string included) replaced by the wrong type
    changed, n = re.subn(rf'^{key} = ("""[\s\S]*?"""|"[^"\n]*")', f"{key} = {value}", source, count=1, flags=re.M)
    if not n:      # a file without the key gets it
        changed, n = re.subn(r"^name = ", f"{key} = {value}\nname = ", source, count=1, flags=re.M)
    assert n == 1, f"the {kind} file has a top-level 'name'"
    path = tmp_path / f"wrong_{kind}.toml"
    path.write_text(changed)
    args = {"config": ["validate", path, "tennis_forehand"], "model": ["export", path, tmp_path / "out.urdf"],
            "motion": ["validate", "replica", path]}[kind]
    one_error_line(run(*args, "--out", tmp_path / "out") if args[0] == "validate" else run(*args),
                   f"wrong_{kind}", *words)


# ---------------------------------------------------------------------------- a very long name

def test_a_100k_character_name_is_cut_in_every_figure_title(tmp_path, monkeypatch):
    """matplotlib lays out every glyph of a title: a configuration named with 100 000 characters
    took half a minute to draw. Every text of the validator's figures is cut to a line's length."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from servodyn.hal.config import CONFIGS_DIR, load_config
    from servodyn.report.validation import validate
    config = tmp_path / "long.toml"
    config.write_text((CONFIGS_DIR / "replica.toml").read_text().replace('name = "replica"', f'name = "{"x" * 100_000}"'))
    texts = []
    original = Figure.savefig

    def savefig(fig, *args, **kwargs):
        texts.extend(t.get_text() for t in fig.findobj(matplotlib.text.Text))
        return original(fig, *args, **kwargs)
    monkeypatch.setattr(Figure, "savefig", savefig)
    validate(load_config(config), "tennis_forehand", time_scale=3.0, out=tmp_path / "out", say=lambda *a, **k: None)
    assert any("xxx" in t for t in texts), "the configuration's name is in the figures' titles"
    longest = max(texts, key=len)
    assert len(longest) <= 120, f"a figure's text of {len(longest)} characters: {longest[:80]}..."


# ---------------------------------------------------------------------------- the swing's figure

def test_the_swings_figure_reads_at_a_glance(tmp_path, monkeypatch):
    """Per joint a panel of its tracking error with one encoder count shaded, the PD-only run named so
    in the title, and the commanded torques against their limits drawn at ±100 %."""
    import math
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from servodyn.hal.config import load_config
    from runs import run_swing
    figures = []
    original = Figure.savefig

    def savefig(fig, *args, **kwargs):
        figures.append(fig)
        return original(fig, *args, **kwargs)
    monkeypatch.setattr(Figure, "savefig", savefig)
    summary = run_swing("replica", out=tmp_path, feedforward=False, say=lambda *a, **k: None)
    assert summary["completed"], summary.get("error")
    assert (tmp_path / "swing_tracking.png").exists(), "the figure is written"
    fig = figures[-1]
    assert "PD only" in fig._suptitle.get_text(), f"the PD-only run says so: {fig._suptitle.get_text()!r}"
    config = load_config("replica")
    names = config.model.dof_names
    panels = [ax for ax in fig.axes if ax.get_title().split(":")[0] in names]
    assert len(panels) == len(names), f"one error panel per joint, got {[ax.get_title() for ax in fig.axes]}"
    step = math.degrees(2 * math.pi / 4096)        # an XM servo's position count, gear 1
    for ax in panels:
        bands = [p for p in ax.patches if p.get_label() == "±1 encoder count"]
        assert bands, f"{ax.get_title()}: one encoder count shaded"
        low, high = bands[0].get_y(), bands[0].get_y() + bands[0].get_height()     # axhspan: y in data
        assert math.isclose(low, -step) and math.isclose(high, step), f"±{step:.4f}°, got [{low}, {high}]"
    torque = next(ax for ax in fig.axes if "% of limit" in ax.get_ylabel())
    limits = sorted(line.get_ydata()[0] for line in torque.lines if line.get_linestyle() == "--")
    assert limits == [-100, 100], f"the torque limit drawn at ±100 %, got {limits}"
    assert any("torque limit" in t.get_text() for t in torque.get_legend().get_texts()), "and named in the legend"


# ---------------------------------------------------------------------------- the view

def test_the_views_plots_have_legends_and_a_model_without_a_motion_says_why_no_play(tmp_path):
    from servodyn.tools.view import open_view
    quiet = dict(say=lambda *a, **k: None)
    viewer = open_view("replica", port=0, **quiet)
    try:
        assert viewer.plots, "the forehand's plots are shown"
        for title, handle in viewer.plots.items():
            assert handle.legend["show"], f"the {title} plot names its joints in a legend"
    finally:
        viewer.close()
    viewer = open_view("human15", port=0, **quiet)      # a model, no configuration: the forehand does not fit
    try:
        assert viewer.player is None, "nothing to play"
        said = viewer.readout.content
        assert "No Play panel" in said and "tennis_forehand" in said and "--motion" in said, \
            f"the page says why there is no Play panel and how to get one: {said!r}"
    finally:
        viewer.close()
