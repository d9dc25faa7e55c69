"""Inverse dynamics (firmware/core/rnea.c) against Pinocchio, the independent oracle."""

import numpy as np
import pytest

import servodyn
from conftest import random_state, rel_err
from servodyn.model.samples import random_model

# RNEA is a forward sum of products: both libraries land within a few ulps of each other
RNEA_TOL = 1e-9


@pytest.mark.parametrize("name", ["human_arm", "human15", "replica", "replica_dm", "replica_mixed"])
def test_builtin_matches_pinocchio(name, twin):
    model = servodyn.load_model(name)
    pin = twin(model)
    rng = np.random.default_rng(7)
    for _ in range(50):
        q, qd, qdd = random_state(rng, model)
        err = rel_err(model.inverse_dynamics(q, qd, qdd), pin.rnea(q, qd, qdd))
        assert err <= RNEA_TOL, f"{name}: rnea differs from Pinocchio by {err:.2e} relative"


@pytest.mark.slow
def test_random_trees_and_chains_match_pinocchio(twin):
    """200 random models up to 88 dofs, 1-3-dof joints, arbitrary axes, placements, full inertias."""
    rng = np.random.default_rng(2026)
    worst = 0.0
    for trial in range(200):
        ndof = int(rng.integers(1, 89)) if trial % 4 else 88
        model = random_model(rng, ndof, chain=trial % 2 == 1)
        pin = twin(model)
        for _ in range(3):
            q, qd, qdd = random_state(rng, model)
            worst = max(worst, rel_err(model.inverse_dynamics(q, qd, qdd), pin.rnea(q, qd, qdd)))
    print(f"worst relative difference to Pinocchio RNEA over 200 models: {worst:.2e}")
    assert worst <= RNEA_TOL, f"rnea differs from Pinocchio by {worst:.2e} relative on some model"


def test_external_wrenches_match_pinocchio(twin):
    """Per-body wrenches (the end-effector load f_{n+1}, n_{n+1} among them)."""
    rng = np.random.default_rng(11)
    for trial in range(20):
        model = random_model(rng, int(rng.integers(3, 30)))
        pin = twin(model)
        q, qd, qdd = random_state(rng, model)
        f_ext = rng.normal(size=(model.nbody, 6)) * 20
        err = rel_err(model.inverse_dynamics(q, qd, qdd, f_ext), pin.rnea(q, qd, qdd, f_ext))
        assert err <= RNEA_TOL, f"model {trial}: rnea with f_ext differs by {err:.2e}"


def test_end_effector_load_is_static_torque():
    """Holding a 10 N downward load in the hand, the arm hanging at 90° flexion: the shoulder
    flexion torque grows by 10 N times the horizontal lever arm of the hand's origin."""
    arm = servodyn.load_model("human_arm")
    q = np.zeros(arm.nq)
    q[arm.dof_names.index("r_shoulder_flexion")] = np.pi / 2
    zero = np.zeros(arm.nq)
    R, p = arm.body_poses(q)
    hand = arm.body_names.index("r_hand")
    f_ext = np.zeros((arm.nbody, 6))
    # the load in the hand's user frame: rotate world (0, 0, -10) into it
    user_R_world = (R[hand] @ arm.frame_rot[hand].T).T
    f_ext[hand, 3:] = user_R_world @ np.array([0.0, 0.0, -10.0])
    extra = arm.inverse_dynamics(q, zero, zero, f_ext) - arm.inverse_dynamics(q, zero, zero)
    lever = np.hypot(p[hand][0], p[hand][1])
    k = arm.dof_names.index("r_shoulder_flexion")
    assert abs(abs(extra[k]) - 10.0 * lever) <= 1e-9 * 10.0 * lever, (extra[k], 10.0 * lever)
    gravity = arm.inverse_dynamics(q, zero, zero)[k]
    assert extra[k] * gravity > 0, \
        f"a downward load adds to the torque holding the arm's own weight: {extra[k]:.3f} vs {gravity:.3f} N m"


def test_batch_equals_single_calls():
    arm = servodyn.load_model("human_arm")
    rng = np.random.default_rng(3)
    q, qd, qdd = (rng.normal(size=(64, arm.nq)) for _ in range(3))
    batch = arm.inverse_dynamics(q, qd, qdd)
    singles = np.array([arm.inverse_dynamics(q[k], qd[k], qdd[k]) for k in range(64)])
    assert batch.shape == (64, arm.nq), "one row of torques per row of the batch"
    assert np.array_equal(batch, singles), "a batch is the same C call per row: bit-identical"


def test_float_build_matches_double_on_builtins():
    """The MCU's single-precision arithmetic (servodyn._core32, same source) within 1e-4; the
    replicas with their motors' armature too."""
    rng = np.random.default_rng(5)
    for name in ("human_arm", "human15", "replica", "replica_dm"):
        model = servodyn.load_model(name)
        for _ in range(50):
            q, qd, qdd = random_state(rng, model)
            double = model.inverse_dynamics(q, qd, qdd)
            single = model.inverse_dynamics(q, qd, qdd, precision="float")
            err = rel_err(single, double)
            assert err <= 1e-4, f"{name}: float rnea differs by {err:.2e}"


def test_nonfinite_input_is_refused():
    arm = servodyn.load_model("human_arm")
    q = np.zeros(arm.nq)
    q[2] = np.nan
    with pytest.raises(ValueError, match="q has a non-finite value"):
        arm.inverse_dynamics(q, np.zeros(arm.nq), np.zeros(arm.nq))
    with pytest.raises(ValueError, match=r"shape \(7,\)"):
        arm.inverse_dynamics(np.zeros(6), np.zeros(arm.nq), np.zeros(arm.nq))


@pytest.mark.parametrize("which,value", [("qd", 1e154), ("qdd", 1e308)])
def test_overflowing_input_raises_and_names_the_row(which, value):
    """Finite inputs whose torques overflow: the core zeroes the result and counts a warning;
    the binding turns that into an error naming the row, never a torque of 0 (qd² of 1e154 at
    every dof is 1e308, and the sums over the chain overflow)."""
    arm = servodyn.load_model("human_arm")
    state = {k: np.zeros((3, arm.nq)) for k in ("q", "qd", "qdd")}
    state[which][2] = value
    with pytest.raises(FloatingPointError, match="inverse dynamics: non-finite result at row 2"):
        arm.inverse_dynamics(state["q"], state["qd"], state["qdd"])
    with pytest.raises(FloatingPointError, match="row 0"):
        arm.inverse_dynamics(state["q"][2], state["qd"][2], state["qdd"][2], precision="float")


@pytest.mark.parametrize("seed", range(6))
def test_free_root_matches_pinocchio_free_flyer(seed, twin):
    """The paper's FREE node: body 0 floats with 6 dofs (origin, unit quaternion), against
    Pinocchio's free-flyer on human15 and on random trees, with external wrenches."""
    rng = np.random.default_rng(seed)
    model = servodyn.load_model("human15", free_root=True) if seed == 0 else _random_free_model(rng)
    pin = twin(model)
    for _ in range(10):
        q, qd, qdd = random_state(rng, model)
        f_ext = rng.normal(size=(model.nbody, 6)) * 10
        err = rel_err(model.inverse_dynamics(q, qd, qdd, f_ext), pin.rnea(q, qd, qdd, f_ext))
        assert err <= RNEA_TOL, f"free-root rnea differs from Pinocchio by {err:.2e}"


def _random_free_model(rng):
    """A random tree whose body 0 floats free (the generator's body 0 hangs from the base)."""
    from dataclasses import replace

    from servodyn import Body, Model
    model = random_model(rng, int(rng.integers(3, 40)))
    first = model.bodies[0]
    bodies = [Body(name=first.name, parent=-1, pos=np.zeros(3), rot=np.eye(3), mass=first.mass,
                   com=first.com, inertia=first.inertia, free=True)]
    # body 0's own dofs give way to the free joint; bodies on the base move onto body 0
    rest = [replace(b, parent=max(b.parent, 0)) for b in model.bodies[1:]]
    return Model(bodies + rest, name="random_free")


# ------------------------------------------------------------------ armature

def _with_random_armature(rng, model, scale=0.05):
    """The model with a random armature on every hinge and ball dof, up to `scale` kg m²: as large
    as the links' own inertias or larger, as a geared motor's reflected rotor is."""
    return model.with_armature({d.name: float(rng.uniform(0, scale)) for b in model.bodies for d in b.dofs})


def _core_with_armature(model, armature):
    """The C core of `model` with `armature` on every velocity dof, a free root's six included
    (which the Model API leaves at 0: no motor drives a floating body)."""
    from servodyn import _core
    return _core.Core(**{**model._arrays, "armature": armature})


@pytest.mark.parametrize("name", ["replica", "replica_dm", "replica_mixed"])
def test_replica_armature_is_its_motors(name):
    """Each replica dof carries its motor's reflected rotor inertia (parts.toml), 0.01-0.16 kg m²,
    and the paper's models none: their experiments stay as they were."""
    from servodyn.model.modelfile import parts
    model = servodyn.load_model(name)
    motors = [d.motor for b in model.bodies for d in b.dofs]
    assert all(motors), f"{name}: every dof names the motor that drives it"
    assert np.array_equal(model.armature, [parts()[m]["armature"] for m in motors]), \
        f"{name}: a dof's armature is its motor's"
    assert 0.01 <= model.armature.min() and model.armature.max() <= 0.16, f"{name}: {model.armature}"
    for paper in ("human_arm", "human15"):
        assert not servodyn.load_model(paper).armature.any(), f"{paper}: a human arm has no motors"


def test_armature_matches_pinocchio(twin):
    """Random trees and chains (1-3-dof joints) and the built-in models with a random armature on
    every dof: RNEA equals Pinocchio's with model.armature to 1e-9, and M(q) equals Pinocchio's
    CRBA of the rigid bodies plus diag(armature)."""
    rng = np.random.default_rng(77)
    models = [servodyn.load_model(n) for n in ("human_arm", "human15", "replica", "replica_dm")]
    models += [random_model(rng, int(rng.integers(1, 40)), chain=k % 2 == 1) for k in range(30)]
    worst_tau = worst_m = 0.0
    for k, rigid in enumerate(models):
        model = _with_random_armature(rng, rigid)
        pin = twin(model)
        for _ in range(5):
            q, qd, qdd = random_state(rng, model)
            worst_tau = max(worst_tau, rel_err(model.inverse_dynamics(q, qd, qdd), pin.rnea(q, qd, qdd)))
        pin.set_armature(np.zeros(model.nv))
        M_rigid = pin.pin.crba(pin.model, pin.data, pin.to_pin_q(q))
        M_rigid = np.triu(M_rigid) + np.triu(M_rigid, 1).T
        expected = M_rigid[np.ix_(pin.index, pin.index)] + np.diag(model.armature)
        worst_m = max(worst_m, rel_err(model.mass_matrix(q), expected))
    print(f"armature: worst RNEA difference {worst_tau:.2e}, worst M(q) difference {worst_m:.2e}")
    assert worst_tau <= RNEA_TOL, f"rnea with armature differs from Pinocchio by {worst_tau:.2e}"
    assert worst_m <= RNEA_TOL, f"M(q) differs from Pinocchio's CRBA + diag(armature) by {worst_m:.2e}"


def free_models_with_armature(rng, twin, count=5):
    """(model, its core, its Pinocchio twin) of random free-root models with a random armature on
    every dof, a free root's six included (set on the core and the twin alone)."""
    for _ in range(count):
        model = _with_random_armature(rng, _random_free_model(rng))
        armature = model.armature
        armature[:6] = rng.uniform(0, 0.05, 6)
        pin = twin(model)
        pin.set_armature(armature)
        yield model, _core_with_armature(model, armature), pin


def test_free_root_armature_matches_pinocchio(twin):
    """A floating body 0 with an armature on all six of its dofs too: RNEA against Pinocchio's
    free-flyer with the same model.armature."""
    rng = np.random.default_rng(78)
    for model, core, pin in free_models_with_armature(rng, twin):
        for _ in range(5):
            q, qd, qdd = random_state(rng, model)
            err = rel_err(core.rnea(q, qd, qdd), pin.rnea(q, qd, qdd))
            assert err <= RNEA_TOL, f"free-root rnea with armature differs from Pinocchio by {err:.2e}"


@pytest.mark.parametrize("armature", [-1e-3, float("nan"), float("inf")])
def test_bad_armature_is_refused(armature):
    """A negative or non-finite armature: a ModelError naming the dof (Python) and the body (C)."""
    model = servodyn.load_model("human_arm")
    with pytest.raises(servodyn.ModelError, match="dof 'r_elbow_flexion': the armature must be a finite"):
        model.with_armature({"r_elbow_flexion": armature})
    with pytest.raises(ValueError, match="body 1: an armature must be a finite number >= 0"):
        _core_with_armature(model, [0, 0, 0, armature, 0, 0, 0])
