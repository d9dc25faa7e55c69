"""Speed near people (host/validation/people.py, `servodyn validate --near-people`): the points'
Jacobians and effective masses against Pinocchio, ISO/TS 15066 A.3's permitted speeds against the
caps the contact plan derived from them, the plan's peak speeds and effective masses on the
built-in configurations, the fastest passing time scale, and the command's report and exit status."""

import json

import numpy as np
import pytest

from servodyn.control.motion import motion_path
from servodyn.errors import InputError
from servodyn.hal.config import load_config
from servodyn.model import load_model
from servodyn.report.validation import validate
from servodyn.validation import people

from conftest import pinocchio_direct, random_state
from helpers import quiet, run_cli

EXACT = 1e-12     # relative: the same rigid-body arithmetic in two libraries, to rounding


@pytest.mark.parametrize("name", ["replica", "replica_dm", "human_arm"])
def test_jacobian_and_cartesian_inertia_are_pinocchios(name):
    """J_v of every contact point (body frame) against Pinocchio's getFrameJacobian (LOCAL) on a frame
    at the point, and J_v M⁻¹ J_vᵀ against Pinocchio's crba (armature on its diagonal), at random
    states; the effective mass along a random direction follows from both."""
    import pinocchio as pin
    model = load_model(name)
    weightless = people.weightless_model(model)
    pm = pinocchio_direct(model)
    points = people.contact_points(model)
    frames = [pm.addFrame(pin.Frame(f"{p.name}_{p.key}", pm.getJointId(model.bodies[p.body].dofs[-1].name),
                                    pin.SE3(np.eye(3), p.local), pin.FrameType.OP_FRAME)) for p in points]
    data = pm.createData()
    rng = np.random.default_rng(7)
    assert np.any(model.armature > 0) or name == "human_arm", "the servos' armature is in the replicas' M"
    for _ in range(5):
        q, qd, _ = random_state(rng, model)
        pin.computeJointJacobians(pm, data, q)
        pin.updateFramePlacements(pm, data)
        M = pin.crba(pm, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        for point, frame in zip(points, frames):
            J_pin = pin.getFrameJacobian(pm, data, frame, pin.ReferenceFrame.LOCAL)[:3]
            J = people.point_jacobian(weightless, point, q)[0]
            assert np.abs(J - J_pin).max() <= EXACT * max(1.0, np.abs(J_pin).max()), (point.name, point.key)
            speed, mass, inverse = people.point_motion(weightless, point, q[None], qd[None])
            expected = J_pin @ np.linalg.solve(M, J_pin.T)
            assert np.abs(inverse[0] - expected).max() <= EXACT * np.abs(expected).max(), (point.name, point.key)
            v = J_pin @ qd
            u = v / np.linalg.norm(v)
            assert speed[0] == pytest.approx(np.linalg.norm(v), rel=EXACT)
            assert mass[0] == pytest.approx(1.0 / (u @ expected @ u), rel=1e-10), "m_eff = 1/(uᵀ J M⁻¹ Jᵀ u)"


def test_contact_points_are_the_coms_and_the_hands_tip():
    """Every moving link with mass is checked at its centre of mass; the hand also at the farthest
    point of its solids (on the replica, the rim of the 70 mm hand plate, 110 mm from the wrist)."""
    model = load_model("replica")
    points = people.contact_points(model)
    assert [p.name for p in points if p.key == "com"] == list(model.body_names), "all 7 links move and have mass"
    tip, = [p for p in points if p.key == "tip"]
    assert tip.name == "r_hand"
    assert np.linalg.norm(tip.local) == pytest.approx(0.110, abs=1e-3), "the plate's far edge (replica.toml)"


def test_a_ball_joint_is_refused_in_one_line():
    with pytest.raises(InputError, match="hinge joints"):
        people.contact_points(load_model("human_arm").with_ball_joints())


@pytest.mark.parametrize("mass, caps", [
    # the contact plan's caps "at the arm's largest effective mass" (plan.md, Speed caps that follow
    # from goal 8), rounded there to 0.1 m/s for the replica and 0.01 m/s for replica_dm
    (1.87, {"hand": (1.5, 0.05), "lower arm": (1.6, 0.05), "chest": (1.3, 0.05)}),
    (2.88, {"hand": (1.45, 0.005), "lower arm": (1.47, 0.005), "chest": (1.08, 0.005)}),
])
def test_permitted_speeds_are_the_plans_caps(mass, caps):
    regions = {r.name: r for r in people.REGIONS}
    for name, (speed, tolerance) in caps.items():
        assert float(people.permitted_speed(mass, regions[name])) == pytest.approx(speed, abs=tolerance), name


def test_a_heavier_robot_is_permitted_less_but_never_below_the_heavy_limit():
    """v falls as the reduced mass grows, towards F/sqrt(m_H k) for an infinitely heavy robot."""
    hand = people.REGIONS[0]
    speeds = people.permitted_speed(np.array([0.1, 1.0, 10.0, 1e9]), hand)
    assert np.all(np.diff(speeds) < 0)
    assert speeds[-1] == pytest.approx(hand.force_n / np.sqrt(hand.mass_kg * hand.stiffness_n_m), rel=1e-6)


def hand(config, scale, armature=True):
    """The hand's centre of mass over the forehand at `scale`: (peak speed, moving effective masses)."""
    config = load_config(config)
    model = config.model if armature else config.model.with_armature({d: 0.0 for d in config.model.dof_names})
    traj = motion_path("tennis_forehand", model).at_scale(scale, config.control_period)
    point = people.contact_points(model)[-2]
    assert (point.name, point.key) == (model.body_names[-1], "com")
    speed, mass, _ = people.point_motion(people.weightless_model(model), point, traj.q, traj.qd)
    return float(speed.max()), mass[~np.isnan(mass)]


# the contact plan's figures (plan.md §3 and figures.md §6, from a prototype on the same model and
# motion), quoted to 0.01: a tolerance of 0.006 covers their rounding and the control period's sampling
@pytest.mark.parametrize("config, scale, peak", [
    ("replica", 4, 1.01), ("replica", 2, 2.02), ("replica", 1, 4.03), ("replica_can", 2.5, 1.61)])
def test_the_plans_peak_hand_speeds(config, scale, peak):
    assert hand(config, scale)[0] == pytest.approx(peak, abs=0.006)


@pytest.mark.parametrize("config, armature, low, high", [
    ("replica", True, 0.47, 1.87), ("replica", False, 0.09, 0.22), ("replica_can", True, 0.82, 2.88)])
def test_the_plans_effective_masses_at_the_hand(config, armature, low, high):
    """Over every moving sample of the forehand (the plan's range): the armature makes the 0.99 kg
    replica hit like 0.5-1.9 kg, where its links alone give 0.09-0.22 kg."""
    _, masses = hand(config, 4 if config == "replica" else 2.5, armature)
    assert masses.min() == pytest.approx(low, abs=0.006)
    assert masses.max() == pytest.approx(high, abs=0.006)


def test_the_fastest_passing_time_scale_passes_and_a_little_faster_fails():
    """The search's answer against the check itself: passes at it, fails 0.2 % faster; and the
    speeds scale as 1/s, so the answer is the worst ratio at scale 1 to within the sampling."""
    config = load_config("replica")
    model, period = config.model, config.control_period
    path = motion_path("tennis_forehand", model)
    scale, how = people.fit_near_people(model, path, period)
    assert scale is not None, how
    assert people.near_people(model, path.at_scale(scale, period))["passed"]
    assert not people.near_people(model, path.at_scale(scale * 0.998, period))["passed"]
    worst = max(link["worst_ratio"] for link in people.near_people(model, path.at_scale(1.0, period))["links"].values())
    assert scale == pytest.approx(worst, rel=2e-3)


def test_the_report_keeps_its_keys_and_adds_near_people():
    config = load_config("replica")
    plain = validate(config, "tennis_forehand", say=quiet)
    report = validate(config, "tennis_forehand", near_people=True, say=quiet)
    assert set(plain) <= set(report), "every key of the report without --near-people is kept"
    near = report["near_people"]
    assert set(near["links"]) == set(config.model.body_names)
    row = near["links"]["r_hand"]
    assert {"peak_speed_m_s", "effective_mass_kg", "limiting_region", "permitted_speed_m_s", "passed"} <= set(row)
    assert row["point"] == "farthest point of its solids from its joint", "the hand's tip is its fastest point"
    assert row["points"]["com"]["peak_speed_m_s"] == pytest.approx(1.01, abs=0.006), "the plan's 1.01 m/s at 4"
    assert near["no_contact"]["regions"] == ["skull and forehead", "face"]
    assert report["passed"] and near["passed"], "the forehand at the replica's own time scale 4 passes"
    assert 2 < report["near_people_time_scale"] < 4, "the plan: outside at 2, inside at 4"


def test_cli_exit_status_and_the_printed_table(tmp_path):
    """Exit 0 at replica_mixed's own time scale; exit 1 at 2.4, where every servo check passes (its
    fit is about 1.55) but the links are too fast near people (the search: about 2.456)."""
    ok = run_cli("validate", "replica_mixed", "tennis_forehand", "--near-people", "--out", tmp_path / "a")
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "PASS near people" in ok.stdout and "r_hand" in ok.stdout
    bad = run_cli("validate", "replica_mixed", "tennis_forehand", "--time-scale", 2.4, "--near-people",
                  "--out", tmp_path / "b")
    report = json.loads((tmp_path / "b" / "report.json").read_text())
    assert not report["violations"], "every servo check passes at 2.4: the failure is near people alone"
    assert bad.returncode == 1, bad.stdout + bad.stderr
    assert not report["passed"] and not report["near_people"]["passed"]
    assert "FAIL: near people, " in bad.stdout, "the first link too fast, in one line"
    assert report["near_people_time_scale"] == pytest.approx(2.4555, abs=2e-3)
