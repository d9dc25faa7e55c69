"""Inverse kinematics (servodyn.model.ik, `servodyn ik`): exact on random poses of every S-R-S arm,
never outside the limits, cold solves that succeed, agreement with pink (Pinocchio's IK) and
with Pinocchio's forward kinematics, the refusals, paths with a speed bound, and the command."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servodyn.model import ik, load_model
from servodyn.model.rotations import rpy_to_matrix

from helpers import run_cli

SRS_ARMS = ("human_arm", "replica", "replica_dm", "replica_mixed")
EXACT = 1e-9          # m and rad: the closed form is exact up to rounding (the bound)


def random_poses(arm, n, seed):
    """n random poses inside the limits and the hand's frame at each."""
    rng = np.random.default_rng(seed)
    qs = rng.uniform(arm.lower, arm.upper, size=(n, arm.n))
    return qs, [arm.hand(q) for q in qs]


# ---------------------------------------------------------------------------- structure and FK

@pytest.mark.parametrize("name,upper_arm,forearm", [("human_arm", 0.3255, 0.2555), ("replica", 0.30, 0.25),
                                                    ("replica_dm", 0.30, 0.25), ("replica_mixed", 0.30, 0.25)])
def test_srs_structure_is_read_off_the_models_axes(name, upper_arm, forearm):
    arm = ik.Arm.of(load_model(name))
    assert arm.srs is not None, f"{name} is S-R-S (shoulder axes meet, wrist axes meet): {arm.why_not_srs}"
    # the stretched arm reaches upper arm + forearm (the model files' segment lengths)
    assert arm.srs.max_reach == pytest.approx(upper_arm + forearm, abs=1e-12), "reach = the two segments"
    assert np.linalg.norm(arm.srs.S) < 1e-12, "the shoulder centre is the base origin in these models"


def test_a_chain_that_is_not_srs_says_why():
    model = load_model("human_arm")
    from dataclasses import replace
    bodies = list(model.bodies)
    # move the wrist axes off the hand's origin: no longer S-R-S
    bodies[2] = replace(bodies[2], pos=bodies[2].pos + np.array([0.02, 0.0, 0.0]))
    from servodyn.model import Model
    bent = Model(bodies, name="bent")
    moved = ik.Arm.of(bent)
    assert moved.srs is None and moved.why_not_srs, "an offset wrist is not S-R-S"
    with pytest.raises(ik.IkError, match="no closed form"):
        ik.solve(bent, [0.2, -0.1, -0.3], method="srs")


@pytest.mark.parametrize("name", ["human_arm", "replica"])
def test_hand_frame_is_pinocchios(name, tmp_path):
    """The hand the solver aims is the URDF link Pinocchio computes (1e-12 m and rad)."""
    import pinocchio as pin
    model = load_model(name)
    arm = ik.Arm.of(model)
    model.to_urdf(tmp_path / "arm.urdf")
    pm = pin.buildModelFromUrdf(str(tmp_path / "arm.urdf"))
    pd = pm.createData()
    frame = pm.getFrameId(model.body_names[arm.end])
    qs, hands = random_poses(arm, 50, seed=11)
    for q, (R, p) in zip(qs, hands):
        pin.framesForwardKinematics(pm, pd, q)
        assert np.abs(pd.oMf[frame].rotation - R).max() < 1e-12, "hand rotation as Pinocchio's"
        assert np.abs(pd.oMf[frame].translation - p).max() < 1e-12, "hand position as Pinocchio's"


# ---------------------------------------------------------------------------- exact, in limits, cold

def test_the_replicas_share_one_chain():
    """replica_dm and replica_mixed have replica's axes, pivots, hand frame and limits (to 1e-12):
    the same inverse kinematics, so 2,000 poses of the replica speak for them; they get 200 each."""
    base = ik.Arm.of(load_model("replica"))
    for name in ("replica_dm", "replica_mixed"):
        arm = ik.Arm.of(load_model(name))
        for key in ("axis", "point", "end_R", "end_p", "lower", "upper"):
            assert np.abs(getattr(arm, key) - getattr(base, key)).max() < 1e-12, f"{name}: {key} differs"


@pytest.mark.parametrize("name,poses", [("human_arm", 2000), ("replica", 2000), ("replica_dm", 200),
                                        ("replica_mixed", 200)])
@pytest.mark.slow
def test_exact_in_limits_and_cold_solves_succeed_on_random_poses(name, poses):
    model = load_model(name)
    arm = ik.Arm.of(model)
    qs, hands = random_poses(arm, poses, seed=sum(map(ord, name)))
    solved, worst_p, worst_r = 0, 0.0, 0.0
    for R, p in hands:
        try:
            r = ik.solve(model, p, R)               # cold: no previous pose
        except ik.IkError:
            continue
        solved += 1
        x = r.q[arm.q_index]
        assert np.all(x >= arm.lower) and np.all(x <= arm.upper), f"{name}: a solution outside the limits"
        worst_p, worst_r = max(worst_p, r.position_error), max(worst_r, r.rotation_error)
    assert solved >= 0.99 * len(hands), f"{name}: {solved}/{len(hands)} cold solves, the issue asks >= 99 %"
    assert worst_p <= EXACT and worst_r <= EXACT, f"{name}: worst error {worst_p:.1e} m, {worst_r:.1e} rad"


@pytest.mark.parametrize("name", ["human_arm", "replica"])
def test_position_only_cold_solves_are_exact_and_in_limits(name):
    model = load_model(name)
    arm = ik.Arm.of(model)
    _, hands = random_poses(arm, 300, seed=7)
    for _, p in hands:
        r = ik.solve(model, p)
        x = r.q[arm.q_index]
        assert r.position_error <= EXACT, f"{name}: {r.position_error:.1e} m from a reachable target"
        assert np.all(x >= arm.lower) and np.all(x <= arm.upper), f"{name}: outside the limits"


def test_the_previous_pose_is_found_again_branch_and_swivel():
    """Solved from the pose that produced the target, the nearest branch is that pose itself."""
    model = load_model("human_arm")
    arm = ik.Arm.of(model)
    qs, hands = random_poses(arm, 300, seed=3)
    for q, (R, p) in zip(qs, hands):
        r = ik.solve(model, p, R, q_prev=q)
        assert np.abs(r.q - q).max() < 1e-8, "the same branch and swivel as the previous pose"


def test_gimbal_lock_of_the_shoulder_is_solved_exactly():
    """Abduction 90° (the humerus on the flexion axis) leaves flexion and rotation one line."""
    model = load_model("human_arm")
    arm = ik.Arm.of(model)
    q = np.radians([30.0, 90.0, -20.0, 60.0, 10.0, 5.0, 5.0])
    R, p = arm.hand(q)
    for q_prev in (None, q + 0.01):
        r = ik.solve(model, p, R, q_prev=q_prev)
        assert r.position_error <= EXACT and r.rotation_error <= EXACT, "exact at the lock"


def test_swivel_is_honoured_and_reported():
    model = load_model("replica")
    arm = ik.Arm.of(model)
    target = [0.25, -0.15, -0.2]
    for degrees in (-30.0, 0.0, 25.0):
        r = ik.solve(model, target, swivel=math.radians(degrees))
        assert r.swivel == pytest.approx(math.radians(degrees), abs=1e-12), "the swivel asked for"
        assert arm.swivel_of(r.q[arm.q_index]) == pytest.approx(math.radians(degrees), abs=1e-9), \
            "and the one the pose has"


# ---------------------------------------------------------------------------- refusals

def test_out_of_reach_is_refused_with_the_distances():
    model = load_model("replica")
    with pytest.raises(ik.OutOfReach, match=r"out of reach: the target is 0\.700 m from the shoulder, "
                                            r"the arm reaches 0\.550 m"):
        ik.solve(model, [0.0, -0.7, 0.0])


def test_no_swivel_inside_the_limits_is_refused():
    model = load_model("human_arm")
    # a reachable hand position with an orientation that no in-limit wrist gives at any swivel
    p = [0.2946608899365203, -0.017217853626759927, 0.2988009894525502]
    R = np.array([[0.7582987881957592, -0.3215355579360719, 0.5670959643689784],
                  [0.6267381525729955, 0.1201875342142642, -0.7699053479025089],
                  [0.17939407997543105, 0.939238969380122, 0.2926566631182941]])
    with pytest.raises(ik.NoSwivel, match="no swivel inside the limits"):
        ik.solve(model, p, R, method="srs")
    with pytest.raises(ik.IkError):
        ik.solve(model, p, R)          # least squares from 13 starts finds none either


@pytest.mark.parametrize("bad", [[np.nan, 0, 0], [0, 0], "abc"])
def test_a_bad_target_is_one_clear_error(bad):
    with pytest.raises(ik.IkError, match="three finite numbers"):
        ik.solve(load_model("human_arm"), bad)


# ---------------------------------------------------------------------------- least squares

@pytest.mark.slow
def test_damped_least_squares_alone_succeeds_cold_and_stays_in_limits():
    model = load_model("human_arm")
    arm = ik.Arm.of(model)
    _, hands = random_poses(arm, 100, seed=21)
    solved = 0
    for R, p in hands:
        try:
            r = ik.solve(model, p, R, method="dls")
        except ik.IkError:
            continue
        solved += 1
        assert r.method == "dls"
        assert r.position_error <= 1e-9 and r.rotation_error <= 1e-9, "converged to the target"
        x = r.q[arm.q_index]
        assert np.all(x >= arm.lower) and np.all(x <= arm.upper), "bounds, not clipping"
    assert solved >= 99, f"{solved}/100 cold least-squares solves with restarts"


def test_a_chain_that_is_not_srs_falls_back_to_least_squares():
    """human15's hand hangs below three spine dofs: the closed form holds them, least squares moves them."""
    model = load_model("human15")
    arm = ik.Arm.of(model)
    assert arm.n == 10, "spine 3 + arm 7"
    rng = np.random.default_rng(4)
    for _ in range(10):
        q = model.neutral_q()
        q[arm.q_index] = rng.uniform(arm.lower, arm.upper)
        R, p = arm.hand(q)
        r = ik.solve(model, p, R)
        assert r.position_error <= 1e-9 and r.rotation_error <= 1e-9, f"{r.method}: reached"


# ---------------------------------------------------------------------------- pink

@pytest.mark.parametrize("name,orientation", [("human_arm", True), ("replica", True), ("human_arm", False)])
def test_agrees_with_pink_on_reachable_targets(name, orientation, tmp_path):
    """pink (Pinocchio's differential IK, a QP per step) converges to a pose reaching the target;
    the closed form at pink's swivel, nearest pink's pose, is that same pose."""
    pin = pytest.importorskip("pinocchio")
    pink = pytest.importorskip("pink")
    from pink.tasks import FrameTask
    model = load_model(name)
    arm = ik.Arm.of(model)
    model.to_urdf(tmp_path / "arm.urdf")
    pm = pin.buildModelFromUrdf(str(tmp_path / "arm.urdf"))
    rng = np.random.default_rng(5)
    agreed = 0
    for _ in range(20):
        q_true = rng.uniform(arm.lower + 0.2, arm.upper - 0.2)
        R, p = arm.hand(q_true)
        conf = pink.Configuration(pm, pm.createData(), np.clip(q_true + rng.normal(0, 0.3, 7), arm.lower, arm.upper))
        task = FrameTask(model.body_names[arm.end], position_cost=1.0,
                         orientation_cost=1.0 if orientation else 0.0, lm_damping=1e-6)
        task.set_target(pin.SE3(R, p))
        for _ in range(200):
            conf.integrate_inplace(pink.solve_ik(conf, [task], 0.01, solver="daqp"), 0.01)
            if np.linalg.norm(task.compute_error(conf)[:3 if not orientation else 6]) < 1e-11:
                break
        q_pink = conf.q.copy()
        R_pink, p_pink = arm.hand(q_pink)
        assert np.linalg.norm(p_pink - p) < 1e-9, "pink reached the target"
        r = ik.solve(model, p, R if orientation else None, q_prev=q_pink, swivel=arm.swivel_of(q_pink))
        assert np.abs(r.q - q_pink).max() < 1e-8, f"the same pose as pink's: {np.abs(r.q - q_pink).max():.1e} rad"
        agreed += 1
    assert agreed == 20


# ---------------------------------------------------------------------------- paths

@pytest.mark.slow
def test_path_keeps_the_swivel_continuous_and_the_speed_bound():
    model = load_model("replica")
    t = np.linspace(0, 1, 101)
    positions = np.stack([0.25 + 0.1 * np.sin(2 * np.pi * t), -0.15 + 0.1 * t, -0.25 + 0.2 * t], axis=1)
    free = ik.solve_path(model, positions, dt=0.01)
    assert free.position_error.max() <= EXACT, "every sample reached"
    assert np.abs(np.diff(free.swivel)).max() < math.radians(2), "no swivel jump between 10 ms samples"
    bound = 0.5                                                  # rad/s, slower than the path needs
    slow = ik.solve_path(model, positions, q0=free.q[0], dt=0.01, max_speed=bound)
    assert np.abs(np.diff(slow.q, axis=0)).max() <= bound * 0.01 * (1 + 1e-9), "never faster than the bound"
    assert slow.slowed.any() and slow.position_error.max() > 1e-3, "held back, and the error says how far"


def test_path_refusal_names_the_sample():
    model = load_model("replica")
    positions = np.array([[0.2, -0.1, -0.2], [0.2, -0.1, -0.2], [0.9, 0.0, 0.0]])
    with pytest.raises(ik.OutOfReach, match="sample 3 of 3: out of reach"):
        ik.solve_path(model, positions)


# ---------------------------------------------------------------------------- the command

def test_cli_one_pose_prints_every_dof_reach_and_error():
    res = run_cli("ik", "replica", "--to", "0.3,-0.1,-0.2", "--rpy", "0,-90,0", "--swivel", "30")
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    model = load_model("replica")
    q = np.radians([float(next(line for line in lines if line.startswith(d)).split()[1]) for d in model.dof_names])
    R, p = ik.Arm.of(model).hand(q)
    assert np.abs(p - [0.3, -0.1, -0.2]).max() < 1e-5, "the printed angles (3 decimals of a degree) reach it"
    assert np.abs(R - rpy_to_matrix(np.radians([0, -90, 0]))).max() < 1e-4, "and turn the hand so"
    assert "swivel 30.00°" in res.stdout and "reach 0.680" in res.stdout, res.stdout


def test_cli_refusals_are_one_line():
    res = run_cli("ik", "replica", "--to", "0.9,0,0")
    assert res.returncode == 1 and res.stderr.strip().count("\n") == 0, "a refusal: exit 1, one line"
    assert "out of reach" in res.stderr
    res = run_cli("ik", "replica", "--to", "0.9,x,0")
    assert res.returncode == 2 and "--to must be three numbers" in res.stderr, res.stderr
    res = run_cli("ik", "replica")
    assert res.returncode == 2 and "either --to" in res.stderr, res.stderr


def test_cli_path_writes_a_trajectory_that_reaches_the_targets(tmp_path):
    from servodyn.control.trajectory import read_trajectory_csv
    targets = tmp_path / "targets.csv"
    targets.write_text("t,x,y,z\n0,0.25,-0.15,-0.30\n0.5,0.35,-0.05,-0.10\n1.0,0.30,0.05,0.05\n")
    out = tmp_path / "motion.csv"
    res = run_cli("ik", "replica", "--path", targets, "-o", out, "--dt", "0.01")
    assert res.returncode == 0, res.stderr
    model = load_model("replica")
    traj = read_trajectory_csv(out, model.dof_names)
    assert len(traj.t) == 101 and not traj.derived, "dense samples every 10 ms, with their own qd and qdd"
    arm = ik.Arm.of(model)
    for k, want in ((0, [0.25, -0.15, -0.30]), (50, [0.35, -0.05, -0.10]), (100, [0.30, 0.05, 0.05])):
        assert np.abs(arm.hand(traj.q[k])[1] - want).max() < 1e-12, f"sample {k} on its target row"
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x,y,z\n0,0.2,-0.1,-0.2\n0.5,nan,0,0\n")
    res = run_cli("ik", "replica", "--path", bad, "-o", out)
    assert res.returncode == 2 and "row 3: a NaN" in res.stderr, res.stderr


def test_cli_path_with_orientations_turns_the_hand_through_each_row(tmp_path):
    from servodyn.control.trajectory import read_trajectory_csv
    rows = [(0.0, 0.25, -0.15, -0.25, 0.0, -1.2, 0.0), (0.4, 0.3, -0.1, -0.2, 0.2, -1.4, 0.1),
            (0.8, 0.3, -0.05, -0.15, 0.1, -1.5, 0.3)]
    targets = tmp_path / "targets.csv"
    targets.write_text("t,x,y,z,roll,pitch,yaw\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    out = tmp_path / "motion.csv"
    res = run_cli("ik", "human_arm", "--path", targets, "-o", out, "--dt", "0.05")
    assert res.returncode == 0, res.stderr
    model = load_model("human_arm")
    traj = read_trajectory_csv(out, model.dof_names)
    arm = ik.Arm.of(model)
    for k, row in zip((0, 8, 16), rows):
        R, p = arm.hand(traj.q[k])
        assert np.abs(p - row[1:4]).max() < 1e-12 and np.abs(R - rpy_to_matrix(row[4:])).max() < 1e-12, \
            f"sample {k}: the hand at row t = {row[0]} s, turned as the row says"
