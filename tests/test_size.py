"""servodyn size (host/report/sizing.py over host/validation/sizing.py) and validate over many motions: the
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
from servodyn.report.sizing import run_size
from servodyn.validation import judge, sizing

from helpers import quiet

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


def restricted(model, motion, names=FEW, scale=1.0, payload=0.0):
    base = model_from_dict(sizing.load_model_data(str(model))[0])
    p = sizing.problem(str(model), [motion_path(motion, base)], voltage=12.0, time_scale=scale, payload=payload)
    p.limits = {n: lim for n, lim in p.limits.items() if n in names}
    return p


def full_judge(p, choice):
    """The validator itself on a whole configuration with these servos mounted."""
    model = p.model(sizing.mounted(p.data, p.places, choice))
    data = sizing.config_data("brute", p.model_ref, p.dofs, choice, p.voltage, p.period, p.servos)
    config = replace(config_from_dict(data, base=p.folder), model=model)
    return [judge(config, m, p.time_scale, model=model, voltage=p.voltage, margin=p.margin) for m in p.motions]


def brute_force(p):
    """Every assignment of the few servos to the three joints (5^3 = 125 sets), each judged whole
    by the validator at margin 1: set -> (servo mass, passed, the worst ratio of a joint's own
    checks a servo changes over every joint, the worst of every check but position)."""
    sets = {}
    for combo in itertools.product(sorted(p.limits), repeat=len(p.dofs)):
        judged = full_judge(p, dict(zip(p.dofs, combo)))
        ratios = [j.result.ratios for j in judged]
        joint_worst = max(float(r[c].max()) for r in ratios for c in sizing.SERVO_CHECKS)
        overall = max(float(r[c].max(initial=0.0)) for r in ratios for c in r if c != "position")
        sets[combo] = (sum(sizing.part_mass(s) for s in combo), all(j.passed for j in judged), joint_worst, overall)
    return p, sets


@pytest.fixture(scope="module")
def brute(arm3):
    return brute_force(restricted(*arm3))


@pytest.fixture(scope="module")
def brute_loaded(arm3):
    """Played 3x slower with 0.3 kg in the hand: gravity binds, so reserve costs mass."""
    return brute_force(restricted(*arm3, scale=3.0, payload=0.3))


def test_greedy_equals_brute_force(brute):
    """The hand-inward greedy's bill is the lightest of every passing assignment of the few servos
    (5^3 = 125 sets, each judged whole by the validator), and its own set passes."""
    p, sets = brute
    found = sizing.size(p)["sizing"]
    assert found.passed
    greedy_mass = sum(sizing.part_mass(s) for s in found.choice.values())
    passing = [mass for mass, passed, _, _ in sets.values() if passed]
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


@pytest.mark.slow
def test_written_files_pass_and_lighter_fails(arm3, tmp_path):
    """`servodyn size` writes a configuration `servodyn validate` passes; at every joint each
    lighter usable catalogue servo, put in the chosen one's place, fails some check."""
    model, motion = arm3
    out = tmp_path / "sized"
    code = main(["size", str(model), "--motion", motion, "--supply-voltage", "12", "--margin", "1", "--out", str(out), "--json"])
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
                      say=quiet)
    assert report["passed"] and all(v["passed"] for v in report["validated"].values())
    for dof, j in report["joints"].items():
        assert j["mass_kg"] <= sizing.part_mass(j["original"]) + 1e-12, dof
    # the replica's 1.156 kg of servos against the sized bill: lighter by more than a gram
    assert report["servo_mass_kg"] < 3 * 0.165 + 4 * 0.082 - 1e-3
    from servodyn.report.sizing import text
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


@pytest.mark.slow
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
    printed = capsys.readouterr()
    lines = [line for line in (printed.out + printed.err).splitlines() if line.startswith(("PASS", "FAIL"))]
    assert len(lines) == 6, "a verdict for each motion, of each run"


@pytest.mark.slow
def test_validate_bad_motion_among_many_is_exit_2(tmp_path, capsys):
    good = hold_csv(tmp_path / "good.csv", [0.0] * 7)
    (tmp_path / "bad.csv").write_text("t,q_nothing\n0,0\n")
    code = main(["validate", "replica", good, str(tmp_path / "bad.csv"), "--out", str(tmp_path / "o")])
    assert code == 2
    printed = capsys.readouterr()
    assert "PASS" in printed.out + printed.err and "ERROR" in printed.out + printed.err
    assert main(["validate", "replica", str(tmp_path / "none*.csv"), "--out", str(tmp_path / "o")]) == 2


@pytest.mark.slow
def test_margin_objective_equals_brute_force(brute_loaded):
    """--objective margin: the smallest worst ratio any set of the few servos reaches (the brute
    force's least, over the 125 sets, of the largest ratio a servo changes over every joint and
    motion), found by the bisection to MARGIN_TOLERANCE, and at that reserve the lightest set."""
    p, sets = brute_loaded
    outcome = sizing.size(p, objective="margin")
    found, reached = outcome["sizing"], outcome["reached_margin"]
    assert found.passed and reached is not None
    best = min(worst for _, passed, worst, _ in sets.values() if passed)
    # the bisection stops once its bracket is MARGIN_TOLERANCE of its top: reached is in
    # [best, best / (1 - tolerance)], the least reserve sizing can promise to that tolerance
    assert best <= reached <= best / (1 - sizing.MARGIN_TOLERANCE) + 1e-12
    chosen = tuple(found.choice[d] for d in p.dofs)
    mass, passed, worst, overall = sets[chosen]
    assert passed and worst <= reached + 1e-12
    # the lightest of the sets within that reserve, to the gram
    within = [m for m, ok, w, _ in sets.values() if ok and w <= reached + 1e-12]
    assert mass == pytest.approx(min(within), abs=1e-9)
    # not the mass objective's answer: reserve costs mass here
    lightest = sizing.size(p)["sizing"].choice
    assert sum(map(sizing.part_mass, lightest.values())) < mass - 1e-3
    # the robot-wide checks (bus, supply) stay within it too: the written set validates at that margin
    assert overall <= reached + 1e-12


# ---------------------------------------------------------------------------- mounting a servo

def _housing(data, dof):
    return next(h for h in sizing.housings(data) if h.dof == dof)


def _centre(data, place):
    """The housing's centroid in its carrier's frame (a round motor's pos is its back face)."""
    solid = data["body"][place.carrier]["solid"][place.solid]
    R = sizing.rpy_to_matrix(solid.get("rpy", [0.0, 0.0, 0.0]))
    return np.asarray(solid["pos"], dtype=float) + R @ np.array([0.0, 0.0, sizing._centroid(solid["part"])])


@pytest.mark.parametrize("model, dof, servo", [
    ("replica", "r_elbow_flexion", "XM540-W270"),        # a larger box servo
    ("replica", "r_wrist_deviation", "XC330-T288"),      # a smaller one
    ("replica_dm", "r_elbow_flexion", "DM-J4310"),       # a shorter round motor
    ("replica", "r_forearm_pronation", "DM-J4340"),      # a round motor for a box servo
])
def test_a_resized_housing_keeps_its_horn_face(model, dof, servo):
    """Another servo in a housing's place: its output flange where the old one's was (to 1e-12 m),
    its centre on the same side of the shaft line, off it in proportion to the housing's height
    (a box servo's shaft lies towards one end of H) or on it (a round motor), and the housing
    grown or shrunk behind the flange by the difference of the depths along the shaft."""
    data = sizing.load_model_data(model)[0]
    place = _housing(data, dof)
    old_part = data["body"][place.carrier]["solid"][place.solid]["part"]
    before_face, before_centre = sizing.flange_centre(data, place), _centre(data, place)
    after = sizing.mounted(data, sizing.housings(data), {dof: servo})
    after_face, after_centre = sizing.flange_centre(after, place), _centre(after, place)
    assert np.allclose(after_face, before_face, atol=1e-12, rtol=0), "the horn face stays"
    point, axis = sizing.shaft_line(data, place)
    def across(c):
        v = c - point
        return v - axis * (axis @ v)
    def along(c):
        return abs(float(axis @ (before_face - c)))     # from the centre to the flange (the dof's
                                                        # axis may point either way along the shaft)
    scale_old, scale_new = sizing._shaft_offset_scale(old_part), sizing._shaft_offset_scale(servo)
    expected = across(before_centre) * (scale_new / scale_old if scale_old else 0.0)
    assert np.allclose(across(after_centre), expected, atol=1e-12, rtol=0), "the offset from the shaft"
    # the centroid sits half the housing's depth behind the flange, before and after
    depth = lambda part: sizing._flange(part) - sizing._centroid(part)
    assert along(before_centre) == pytest.approx(depth(old_part), abs=1e-12)
    assert along(after_centre) == pytest.approx(depth(servo), abs=1e-12)
    # the model builds, and weighs the difference of the two housings more
    model_before = model_from_dict(data)
    model_after = model_from_dict(after)
    assert model_after.total_mass - model_before.total_mass == pytest.approx(
        sizing.part_mass(servo) - sizing.part_mass(old_part), abs=1e-12)


def test_a_part_without_armature_is_never_a_candidate(arm3, monkeypatch, capsys):
    """An unknown rotor inertia is not 0 (0 would make the servo look easier to drive): a part
    whose armature parts.toml lacks is left out with its reason, in the report and its printout,
    and mounting it is refused with one line."""
    from servodyn.model.modelfile import parts
    monkeypatch.setitem(parts()["XC330-T288"], "armature", None)
    model, motion = arm3
    p = restricted(model, motion)
    assert "XC330-T288" not in p.limits
    assert p.reasons["XC330-T288"].startswith("no armature in parts.toml")
    data = sizing.load_model_data(str(model))[0]
    with pytest.raises(sizing.SizingError, match="XC330-T288: no armature"):
        sizing.mounted(data, sizing.housings(data), {"wrist": "XC330-T288"})
    assert main(["size", str(model), "--motion", motion, "--supply-voltage", "12", "--margin", "1", "--out",
                 str(model.parent / "no_armature"), "--yes"]) == 0
    printed = capsys.readouterr()
    assert "XC330-T288 (no armature in parts.toml" in printed.out + printed.err
    report = json.loads((model.parent / "no_armature" / "size.json").read_text())
    assert "XC330-T288" not in {j["servo"] for j in report["joints"].values()}
