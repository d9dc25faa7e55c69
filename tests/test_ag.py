"""Direct dynamics (firmware/core/ag.c): Armstrong-Green recursion against Pinocchio's ABA,
and ABA(RNEA(qdd)) = qdd."""

import numpy as np
import pytest

import servodyn
from conftest import random_state, rel_err
from servodyn.model.samples import random_model

FORWARD_TOL = 1e-9


@pytest.mark.parametrize("name", ["human_arm", "human15"])
def test_builtin_matches_pinocchio(name, twin):
    model = servodyn.load_model(name)
    pin = twin(model)
    rng = np.random.default_rng(8)
    for _ in range(50):
        q, qd, _ = random_state(rng, model)
        tau = rng.normal(size=model.nq) * 5
        err = rel_err(model.forward_dynamics(q, qd, tau), pin.aba(q, qd, tau))
        assert err <= FORWARD_TOL, f"{name}: forward dynamics differ from Pinocchio by {err:.2e}"


@pytest.mark.slow
def test_random_trees_and_chains_match_pinocchio(twin):
    """200 random models up to 88 dofs. Forward dynamics solve M qdd = tau - h, so two correct
    implementations differ by about eps * cond(M): where cond(M) <= 1e6 the accelerations must
    agree to 1e-9. On every model each library's qdd must satisfy the other's equations of
    motion equally well: the residual of servodyn's qdd in Pinocchio's RNEA within 1e-9 of
    tau or within 10x the residual of Pinocchio's qdd in servodyn's RNEA. (Each ABA is a little
    more consistent with its own RNEA: the two models' kinematics round differently, and
    cond(M) reaches 1e9 on long random chains.)"""
    rng = np.random.default_rng(4)
    worst_conditioned, worst_residual, n_conditioned = 0.0, 0.0, 0
    for trial in range(200):
        ndof = int(rng.integers(1, 89)) if trial % 4 else 88
        model = random_model(rng, ndof, chain=trial % 2 == 1)
        pin = twin(model)
        q, qd, _ = random_state(rng, model)
        tau = rng.normal(size=model.nq) * 10
        mine, theirs = model.forward_dynamics(q, qd, tau), pin.aba(q, qd, tau)
        residual = rel_err(pin.rnea(q, qd, mine), tau)
        residual_pin = rel_err(model.inverse_dynamics(q, qd, theirs), tau)
        assert residual <= max(1e-9, 10 * residual_pin), \
            f"model {trial}: residual {residual:.2e} vs Pinocchio's {residual_pin:.2e}"
        worst_residual = max(worst_residual, residual)
        if np.linalg.cond(model.mass_matrix(q)) <= 1e6:
            n_conditioned += 1
            worst_conditioned = max(worst_conditioned, rel_err(mine, theirs))
    print(f"{n_conditioned} well-conditioned models: worst qdd difference {worst_conditioned:.2e}; "
          f"worst torque residual over all 200: {worst_residual:.2e}")
    assert n_conditioned >= 50, "the random models should be mostly well conditioned"
    assert worst_conditioned <= FORWARD_TOL, \
        f"qdd differs from Pinocchio's by {worst_conditioned:.2e} on a model with cond(M) <= 1e6"


def test_external_wrenches_match_pinocchio(twin):
    rng = np.random.default_rng(12)
    for trial in range(20):
        model = random_model(rng, int(rng.integers(3, 20)))
        pin = twin(model)
        q, qd, _ = random_state(rng, model)
        tau = rng.normal(size=model.nq) * 5
        f_ext = rng.normal(size=(model.nbody, 6)) * 20
        mine = model.forward_dynamics(q, qd, tau, f_ext)
        residual = rel_err(pin.rnea(q, qd, mine, f_ext), tau)
        assert residual <= 1e-9, f"model {trial}: residual with f_ext {residual:.2e}"


@pytest.mark.parametrize("name", ["human_arm", "human15"])
def test_forward_of_inverse_is_identity(name):
    model = servodyn.load_model(name)
    rng = np.random.default_rng(9)
    q, qd, qdd = (np.array(x) for x in zip(*(random_state(rng, model) for _ in range(200))))
    back = model.forward_dynamics(q, qd, model.inverse_dynamics(q, qd, qdd))
    err = rel_err(back, qdd)
    assert err <= 1e-10, f"{name}: forward(inverse(qdd)) differs from qdd by {err:.2e}"


def test_overflowing_input_raises_and_names_the_row():
    """A finite velocity whose accelerations overflow: an error naming the row, never qdd = 0."""
    arm = servodyn.load_model("human_arm")
    qd = np.zeros((2, arm.nq))
    qd[1] = 1e154
    with pytest.raises(FloatingPointError, match="forward dynamics: non-finite result at row 1"):
        arm.forward_dynamics(np.zeros((2, arm.nq)), qd, np.zeros((2, arm.nq)))


def test_float_build_matches_double_on_builtins():
    """The MCU's single precision (servodyn._core32, same source). Forward dynamics amplify
    rounding by cond(M), up to 2.5e3 on human_arm and 3e6 on human15 (light hands and feet on a
    heavy trunk), so the float accelerations are held to what float can promise: they satisfy
    the double equations of motion within 1e-5 relative (backward error), and differ from the
    double ones by at most 10 * eps_float * cond(M). The replicas with their motors' armature too."""
    eps_float = float(np.finfo(np.float32).eps)
    rng = np.random.default_rng(6)
    for name in ("human_arm", "human15", "replica", "replica_dm"):
        model = servodyn.load_model(name)
        worst_residual, worst_ratio = 0.0, 0.0
        for _ in range(50):
            q, qd, _ = random_state(rng, model)
            tau = model.inverse_dynamics(q, qd, rng.normal(size=model.nq))
            single = model.forward_dynamics(q, qd, tau, precision="float")
            double = model.forward_dynamics(q, qd, tau)
            worst_residual = max(worst_residual, rel_err(model.inverse_dynamics(q, qd, single), tau))
            bound = 10 * eps_float * np.linalg.cond(model.mass_matrix(q))
            worst_ratio = max(worst_ratio, rel_err(single, double) / bound)
        print(f"{name}: float forward dynamics backward error {worst_residual:.1e}, "
              f"forward error at most {worst_ratio:.2f} of 10 eps cond(M)")
        assert worst_residual <= 1e-5, f"{name}: float qdd residual {worst_residual:.2e}"
        assert worst_ratio <= 1.0, f"{name}: float qdd error {worst_ratio:.2f} x the bound"


@pytest.mark.parametrize("seed", range(6))
def test_free_root_matches_pinocchio_free_flyer(seed, twin):
    """Direct dynamics with a floating body 0: the root's full 6x6 articulated inertia is solved
    at the end of the inbound pass; against Pinocchio's ABA with a free-flyer."""
    from test_rnea import _random_free_model
    rng = np.random.default_rng(100 + seed)
    model = servodyn.load_model("human15", free_root=True) if seed == 0 else _random_free_model(rng)
    pin = twin(model)
    for _ in range(10):
        q, qd, _ = random_state(rng, model)
        tau = rng.normal(size=model.nv) * 5
        f_ext = rng.normal(size=(model.nbody, 6)) * 10
        mine, theirs = model.forward_dynamics(q, qd, tau, f_ext), pin.aba(q, qd, tau, f_ext)
        if np.linalg.cond(model.mass_matrix(q)) <= 1e6:
            err = rel_err(mine, theirs)
            assert err <= FORWARD_TOL, f"free-root forward dynamics differ by {err:.2e}"
        residual = rel_err(pin.rnea(q, qd, mine, f_ext), tau)
        assert residual <= 1e-8, f"free-root qdd residual in Pinocchio's RNEA {residual:.2e}"


@pytest.mark.parametrize("armature", [False, True])
def test_ball_joints_match_pinocchio_spherical(armature):
    """human15 floating free with its 3-dof joints as ball joints (quaternion coordinates),
    against Pinocchio built joint by joint with spherical joints: inverse and direct dynamics;
    also with a random armature on every dof (the 3x3 D of a ball joint)."""
    import pinocchio as pin
    from conftest import pinocchio_direct
    from test_rnea import _with_random_armature
    model = servodyn.load_model("human15", free_root=True).with_ball_joints()
    if armature:
        model = _with_random_armature(np.random.default_rng(22), model)
    pm = pinocchio_direct(model)
    pd = pm.createData()
    assert (pm.nq, pm.nv) == (model.nq, model.nv), "a quaternion (4 q, 3 v) per ball joint in both builds"
    rng = np.random.default_rng(21)
    for _ in range(10):
        q = pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq))
        qd, qdd = rng.normal(size=(2, model.nv))
        tau = model.inverse_dynamics(q, qd, qdd)
        assert rel_err(tau, pin.rnea(pm, pd, q, qd, qdd)) <= 1e-9, \
            "ball-joint inverse dynamics differ from Pinocchio's spherical joints"
        assert rel_err(model.forward_dynamics(q, qd, tau), pin.aba(pm, pd, q, qd, tau)) <= 1e-9, \
            "ball-joint forward dynamics differ from Pinocchio's spherical joints"


def test_ball_and_hinge_parametrizations_move_alike():
    """The same bodies as ball joints or as chains of hinges, from the same pose at rest: after
    0.2 s of RK4 every centre of mass is in the same place (1e-9 m)."""
    hinges = servodyn.load_model("human15", free_root=True)
    balls = hinges.with_ball_joints()
    rng = np.random.default_rng(2)
    q_h = hinges.neutral_q()
    q_h[7:] = rng.uniform(-0.6, 0.6, hinges.nq - 7)
    q_b = balls.q_from(hinges, q_h)
    q_h, _ = hinges.step(q_h, np.zeros(hinges.nv), np.zeros(hinges.nv), 2.5e-4, nsteps=800)
    q_b, _ = balls.step(q_b, np.zeros(balls.nv), np.zeros(balls.nv), 2.5e-4, nsteps=800)
    assert np.abs(hinges.com_positions(q_h) - balls.com_positions(q_b)).max() <= 1e-9, \
        "largest centre-of-mass gap (m) between the ball-joint and the hinge-chain motion"


# ------------------------------------------------------------------ armature

def test_armature_matches_pinocchio(twin):
    """The armature adds to each joint's D = S' IA S (1-, 2- and 3-dof joints): the built-in
    models with their own armature (the replicas) or a random one, and random trees and chains,
    against Pinocchio's ABA with model.armature; and ABA(RNEA(qdd)) = qdd."""
    from test_rnea import _with_random_armature
    rng = np.random.default_rng(79)
    models = [servodyn.load_model(n) for n in ("replica", "replica_dm", "replica_mixed")]
    models += [_with_random_armature(rng, servodyn.load_model(n)) for n in ("human_arm", "human15")]
    models += [_with_random_armature(rng, random_model(rng, int(rng.integers(1, 40)), chain=k % 2 == 1))
               for k in range(30)]
    worst, worst_roundtrip = 0.0, 0.0
    for model in models:
        pin = twin(model)
        for _ in range(5):
            q, qd, qdd = random_state(rng, model)
            tau = rng.normal(size=model.nv) * 5
            if np.linalg.cond(model.mass_matrix(q)) <= 1e6:
                worst = max(worst, rel_err(model.forward_dynamics(q, qd, tau), pin.aba(q, qd, tau)))
            tau = model.inverse_dynamics(q, qd, qdd)
            worst_roundtrip = max(worst_roundtrip, rel_err(model.forward_dynamics(q, qd, tau), qdd))
    print(f"armature: worst qdd difference to Pinocchio {worst:.2e}, ABA(RNEA(qdd)) {worst_roundtrip:.2e}")
    assert worst <= FORWARD_TOL, f"forward dynamics with armature differ from Pinocchio by {worst:.2e}"
    assert worst_roundtrip <= 1e-9, f"ABA(RNEA(qdd)) differs from qdd by {worst_roundtrip:.2e}"


def test_free_root_armature_matches_pinocchio(twin):
    """An armature on a free root's six dofs too (the 6x6 solve), against Pinocchio's free-flyer."""
    from test_rnea import free_models_with_armature
    rng = np.random.default_rng(80)
    for model, core, pin in free_models_with_armature(rng, twin):
        for _ in range(5):
            q, qd, _ = random_state(rng, model)
            tau = rng.normal(size=model.nv) * 5
            err = rel_err(core.forward(q, qd, tau), pin.aba(q, qd, tau))
            assert err <= FORWARD_TOL, f"free-root forward dynamics with armature differ by {err:.2e}"
