"""servodyn size (tools/size.py over validation/sizing.py) and validate over many motions: the
hand-inward greedy against a brute force over the catalogue, the written files against the
validator, the replica against its own servos, and validate --jobs against one process."""

import itertools
import json
from dataclasses import replace

import numpy as np
import pytest

from servodyn.control.motion import motion_path
from servodyn.hal.config import config_from_dict, load_config
from servodyn.model.modelfile import model_from_dict
from servodyn.tools.cli import main
from servodyn.tools.size import run_size
from servodyn.validation import judge, sizing

ARM3 = """
name = "arm3"
[[body]]
name = "upper"
parent = "base"
  [[body.dof]]
  name = "shoulder"
  motor = "XM430-W350"
  axis = [0.0, 1.0, 0.0]
  lower = -3.0
  upper = 3.0
  [[body.solid]]
  type = "cylinder"
  mass = 0.05
  radius = 0.01
  length = 0.2
  rpy = [3.141592653589793, 0.0, 0.0]
  [[body.solid]]                       # the elbow's servo
  part = "XM430-W350"
  pos = [0.0, 0.0, -0.2]
[[body]]
name = "fore"
parent = "upper"
pos = [0.0, 0.0, -0.2]
  [[body.dof]]
  name = "elbow"
  motor = "XM430-W350"
  axis = [0.0, 1.0, 0.0]
  lower = -3.0
  upper = 3.0
  [[body.solid]]
  type = "cylinder"
  mass = 0.04
  radius = 0.01
  length = 0.15
  rpy = [3.141592653589793, 0.0, 0.0]
  [[body.solid]]                       # the wrist's servo
  part = "XM430-W350"
  pos = [0.0, 0.0, -0.15]
[[body]]
name = "hand"
parent = "fore"
pos = [0.0, 0.0, -0.15]
  [[body.dof]]
  name = "wrist"
  motor = "XM430-W350"
  axis = [0.0, 1.0, 0.0]
  lower = -3.0
  upper = 3.0
  [[body.solid]]
  type = "sphere"
  mass = 0.08
  radius = 0.03
  pos = [0.0, 0.0, -0.05]
"""
# a few servos of very different strength and mass (brute force: 5^3 sets)
FEW = ("XC330-T288", "XM430-W210", "XM430-W350", "XM540-W150", "XM540-W270")


def swing_csv(path, seconds=0.8, raised=1.2, amplitude=0.6):
    """Every joint swinging sinusoidally about a raised pose: gravity and inertia both load it."""
    t = np.arange(int(round(seconds / 1e-3)) + 1) * 1e-3
    w = 2 * np.pi / seconds
    q = raised + amplitude * np.sin(w * t)[:, None] * np.ones(3)
    qd = amplitude * w * np.cos(w * t)[:, None] * np.ones(3)
    qdd = -amplitude * w**2 * np.sin(w * t)[:, None] * np.ones(3)
    names = ("shoulder", "elbow", "wrist")
    header = ["t"] + [f"{p}_{n}" for p in ("q", "qd", "qdd") for n in names]
    rows = np.hstack([t[:, None], q, qd, qdd])
    np.savetxt(path, rows, delimiter=",", header=",".join(header), comments="")
    return str(path)


@pytest.fixture(scope="module")
def arm3(tmp_path_factory):
    folder = tmp_path_factory.mktemp("arm3")
    (folder / "arm3.toml").write_text(ARM3)
    return folder / "arm3.toml", swing_csv(folder / "swing.csv")


def restricted(model, motion, names=FEW, scale=1.0):
    base = model_from_dict(sizing.load_model_data(str(model))[0])
    p = sizing.problem(str(model), [motion_path(motion, base)], voltage=12.0, time_scale=scale)
    p.limits = {n: lim for n, lim in p.limits.items() if n in names}
    return p


def full_judge(p, choice):
    """The validator itself on a whole configuration with these servos mounted."""
    model = p.model(sizing.mounted(p.data, p.places, choice))
    data = sizing.config_data("brute", p.model_ref, p.dofs, choice, p.voltage, p.period, p.servos)
    config = replace(config_from_dict(data, base=p.folder), model=model)
    return [judge(config, m, p.time_scale, model=model, voltage=p.voltage, margin=p.margin) for m in p.motions]


def test_greedy_equals_brute_force(arm3):
    """The hand-inward greedy's bill is the lightest of every passing assignment of the few servos
    (5^3 = 125 sets, each judged whole by the validator), and its own set passes."""
    model, motion = arm3
    p = restricted(model, motion)
    found = sizing.size(p)["sizing"]
    assert found.passed
    greedy_mass = sum(sizing.part_mass(s) for s in found.choice.values())
    passing = []
    for combo in itertools.product(sorted(p.limits), repeat=len(p.dofs)):
        choice = dict(zip(p.dofs, combo))
        if all(j.passed for j in full_judge(p, choice)):
            passing.append(sum(sizing.part_mass(s) for s in combo))
    assert passing, "the case must have passing sets"
    # grams: the same bill to the gram (the masses are data-sheet figures in grams)
    assert greedy_mass == pytest.approx(min(passing), abs=1e-9)
    # not a trivial case: some sets fail, and the shoulder needs more than the lightest servo
    assert len(passing) < 5 ** 3
    assert found.choice["shoulder"] != "XC330-T288"


def test_joint_ratios_equal_the_validators(arm3):
    """Sizing checks one joint at a time (its torque without its own rotor, plus the candidate's
    armature times its acceleration): the ratios equal the whole validator's to rounding."""
    model, motion = arm3
    p = restricted(model, motion)
    found = sizing.size(p)["sizing"]
    judged = full_judge(p, found.choice)[0]
    for k, dof in enumerate(p.dofs):
        row = next(r for r in found.rows[dof] if r.servo == found.choice[dof])
        peak = float(judged.result.ratios[row.worst_check][:, k].max())
        assert row.worst_ratio == pytest.approx(peak, rel=1e-9), dof


def test_written_files_pass_and_lighter_fails(arm3, tmp_path):
    """`servodyn size` writes a configuration `servodyn validate` passes; at every joint each
    lighter usable catalogue servo, put in the chosen one's place, fails some check."""
    model, motion = arm3
    out = tmp_path / "sized"
    code = main(["size", str(model), "--motion", motion, "--supply-voltage", "12", "--out", str(out), "--json"])
    assert code == 0
    report = json.loads((out / "size.json").read_text())
    assert main(["validate", str(out / "config.toml"), motion, "--out", str(tmp_path / "v")]) == 0
    config = load_config(out / "config.toml")
    assert [j.servo.name for j in config.joints] == [report["joints"][d]["servo"] for d in config.model.dof_names]
    p = restricted(model, motion, names=tuple(sizing.catalogue("dynamixel")))
    choice = {d: report["joints"][d]["servo"] for d in p.dofs}
    assert sum(map(sizing.part_mass, choice.values())) == pytest.approx(report["servo_mass_kg"], abs=1e-12)
    for dof in p.dofs:
        lighter = [n for n in p.limits if sizing.part_mass(n) < sizing.part_mass(choice[dof]) - 1e-12]
        for name in lighter:
            judged = full_judge(p, choice | {dof: name})
            assert not all(j.passed for j in judged), f"{name} at {dof} passes yet is lighter"


def test_replica_forehand_no_heavier_than_its_own(tmp_path):
    """The replica's forehand at its configuration's time scale: every joint's servo no heavier
    than the replica's own, and the report says where the replica has margin to spare."""
    scale = load_config("replica").swing_time_scale
    report = run_size("replica", ["tennis_forehand"], time_scale=scale, supply_voltage=12.0, out=tmp_path,
                      say=lambda *a, **k: None)
    assert report["passed"] and all(v["passed"] for v in report["validated"].values())
    for dof, j in report["joints"].items():
        assert j["mass_kg"] <= sizing.part_mass(j["original"]) + 1e-12, dof
    # the replica's 1.156 kg of servos against the sized bill: lighter by more than a gram
    assert report["servo_mass_kg"] < 3 * 0.165 + 4 * 0.082 - 1e-3
    from servodyn.tools.size import text
    assert "margin to spare at r_shoulder_rotation" in text(report)


def test_nothing_passes_names_joint_check_and_time_scale(arm3):
    """Played 4x faster only the few servos: none passes; the report names the joint and check,
    and at the time scale it finds, the set it gives passes the whole validator."""
    model, motion = arm3
    p = restricted(model, motion, scale=0.25)
    outcome = sizing.size(p)
    found = outcome["sizing"]
    assert not found.passed and found.failed_dof in p.dofs
    fit = outcome["fit"]
    assert fit["time_scale"] is not None and fit["time_scale"] > 0.25
    p_fit = restricted(model, motion, scale=fit["time_scale"])
    assert all(j.passed for j in full_judge(p_fit, fit["choice"]))
    # 1 % below it no set passes (the bisection's tolerance)
    assert not sizing.greedy(p_fit, fit["time_scale"] * 0.98, p.margin).passed


def test_bad_input_is_one_line(capsys):
    assert main(["size", "replica", "--motion", "tennis_forehand", "--time-scale", "-1"]) == 2
    assert main(["size", "nosuch.urdf", "--motion", "tennis_forehand"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("servodyn: error:") for line in err)
    assert "time-scale" in err[0] and ".toml" in err[1]


# ---------------------------------------------------------------------------- validate, many motions

def hold_csv(path, pose, seconds=0.3):
    t = np.arange(int(round(seconds / 1e-3)) + 1) * 1e-3
    names = load_config("replica").model.dof_names
    header = ["t"] + [f"q_{n}" for n in names] + [f"qd_{n}" for n in names] + [f"qdd_{n}" for n in names]
    q = np.tile(pose, (len(t), 1))
    np.savetxt(path, np.hstack([t[:, None], q, 0 * q, 0 * q]), delimiter=",", header=",".join(header),
               comments="")
    return str(path)


def test_validate_jobs_same_verdicts_dir_and_glob(tmp_path, capsys):
    """Three motions (two holds that pass, one with the elbow past its stop), as a folder and as a
    glob: --jobs 2 gives the verdicts and ratios --jobs 1 gives, the exit status the worst."""
    folder = tmp_path / "motions"
    folder.mkdir()
    hold_csv(folder / "a_hang.csv", [0.0] * 7)
    hold_csv(folder / "b_bent.csv", [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    hold_csv(folder / "c_out.csv", [0.0, 0.0, 0.0, -0.3, 0.0, 0.0, 0.0])   # elbow past its stop
    runs = {}
    for jobs, spec in ((1, str(folder)), (2, str(folder / "*.csv"))):
        out = tmp_path / f"out{jobs}"
        code = main(["validate", "replica", spec, "--jobs", str(jobs), "--out", str(out)])
        summary = json.loads((out / "summary.json").read_text())
        runs[jobs] = (code, [(m["name"], m["passed"], m["worst"]["ratio"]) for m in summary["motions"]])
        assert [p.name for p in sorted(out.iterdir()) if p.is_dir()] == ["a_hang", "b_bent", "c_out"]
    assert runs[1] == runs[2]
    code, verdicts = runs[1]
    assert [v[1] for v in verdicts] == [True, True, False]   # the elbow 0.3 rad past its lower limit
    assert code == 1
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith(("PASS", "FAIL"))]
    assert len(lines) == 6


def test_validate_bad_motion_among_many_is_exit_2(tmp_path, capsys):
    good = hold_csv(tmp_path / "good.csv", [0.0] * 7)
    (tmp_path / "bad.csv").write_text("t,q_nothing\n0,0\n")
    code = main(["validate", "replica", good, str(tmp_path / "bad.csv"), "--out", str(tmp_path / "o")])
    assert code == 2
    out = capsys.readouterr().out
    assert "PASS" in out and "ERROR" in out
    assert main(["validate", "replica", str(tmp_path / "none*.csv"), "--out", str(tmp_path / "o")]) == 2
