"""The joint-torque regressor (firmware/core/regressor.c) against Pinocchio's
computeJointTorqueRegressor, and against the core's own RNEA (tau = Y pi + armature qdd)."""

import numpy as np
import pytest

import servodyn
from conftest import random_state, rel_err
from servodyn.model.samples import random_model

# Y is a sum of the same products as the RNEA's forward and backward passes: both libraries land
# within a few ulps of each other, as the RNEA itself does (test_rnea.RNEA_TOL)
REGRESSOR_TOL = 1e-9
BUILTINS = ["human_arm", "human15", "replica", "replica_dm", "replica_mixed"]


def _cross(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def moved_parameters(R, p):
    """The 10x10 linear map from a body's parameters in its own frame to the same body's in a
    frame where its origin sits at p and its axes are turned by R (parent_R_child): h' = R h + m p,
    I_O' = R I_O R' + m(|p|² 1 − p p') + 2 p·(R h) 1 − p (R h)' − (R h) p'."""
    def one(pi):
        m, h = pi[0], pi[1:4]
        xx, xy, yy, xz, yz, zz = pi[4:]
        I = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        Rh = R @ h
        I2 = R @ I @ R.T + m * (p @ p * np.eye(3) - np.outer(p, p)) + 2 * (p @ Rh) * np.eye(3) \
            - np.outer(p, Rh) - np.outer(Rh, p)
        return np.array([m, *(Rh + m * p), I2[0, 0], I2[0, 1], I2[1, 1], I2[0, 2], I2[1, 2], I2[2, 2]])
    return np.column_stack([one(e) for e in np.eye(10)])


def pinocchio_regressor(model, pin_twin, q, qd, qdd):
    """Pinocchio's regressor with its columns mapped to servodyn's bodies. Pinocchio's parameters
    are in its joint frames (the URDF's link frames; a welded body merged into the joint it hangs
    from; the massless links between the dofs of one joint take none), servodyn's in the core's
    body frames: each body takes its joint's 10 columns through the fixed transform between the
    two frames, read from both libraries' poses at q; a body welded to the base has none."""
    pin = pin_twin.pin
    Y = pin.computeJointTorqueRegressor(pin_twin.model, pin_twin.data, pin_twin.to_pin_q(q),
                                        pin_twin.to_pin(qd), pin_twin.to_pin(qdd))
    Y = np.asarray(Y).reshape(model.nv, -1)[pin_twin.index]
    pin.forwardKinematics(pin_twin.model, pin_twin.data, pin_twin.to_pin_q(q))
    R_world, p_world = model.body_poses(q)
    out = np.zeros((model.nv, 10 * model.nbody))
    for i in range(model.nbody):
        k = i
        while k >= 0 and pin_twin.body_joint[k] is None:
            k = model.bodies[k].parent
        if k < 0:
            continue          # welded to the fixed base: its parameters never act
        jid = pin_twin.body_joint[k]
        joint = pin_twin.data.oMi[jid]
        R = joint.rotation.T @ R_world[i]
        p = joint.rotation.T @ (p_world[i] - joint.translation)
        out[:, 10 * i:10 * i + 10] = Y[:, 10 * (jid - 1):10 * jid] @ moved_parameters(R, p)
    return out


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_matches_pinocchio(name, twin):
    model = servodyn.load_model(name)
    pin_twin = twin(model)
    rng = np.random.default_rng(23)
    for _ in range(20):
        q, qd, qdd = random_state(rng, model)
        err = rel_err(model.regressor(q, qd, qdd), pinocchio_regressor(model, pin_twin, q, qd, qdd))
        assert err <= REGRESSOR_TOL, f"{name}: the regressor differs from Pinocchio's by {err:.2e} relative"


def test_random_trees_match_pinocchio(twin):
    """Random trees and chains of 1-3-dof joints with arbitrary axes: the multi-dof joints'
    coupled axes are where a regressor goes wrong first."""
    rng = np.random.default_rng(2323)
    worst = 0.0
    for trial in range(20):
        model = random_model(rng, int(rng.integers(1, 25)), chain=trial % 2 == 1)
        pin_twin = twin(model)
        q, qd, qdd = random_state(rng, model)
        worst = max(worst, rel_err(model.regressor(q, qd, qdd), pinocchio_regressor(model, pin_twin, q, qd, qdd)))
    assert worst <= REGRESSOR_TOL, f"the regressor differs from Pinocchio's by {worst:.2e} on some model"


@pytest.mark.parametrize("name", BUILTINS)
def test_regressor_times_parameters_is_rnea(name):
    """Y(q, qd, qdd)·pi + armature·qdd is the core's RNEA, batched over 50 states in one call."""
    model = servodyn.load_model(name)
    rng = np.random.default_rng(5)
    states = [random_state(rng, model) for _ in range(50)]
    q, qd, qdd = (np.array([s[k] for s in states]) for k in range(3))
    Y = model.regressor(q, qd, qdd)
    assert Y.shape == (50, model.nv, 10 * model.nbody), "one (nv, 10 nbody) block per state"
    predicted = Y @ model.inertial_parameters() + model.armature * qdd
    err = rel_err(predicted, model.inverse_dynamics(q, qd, qdd))
    assert err <= REGRESSOR_TOL, f"{name}: Y pi differs from the RNEA by {err:.2e} relative"
    single = model.regressor(q[7], qd[7], qdd[7])
    assert np.array_equal(single, Y[7]), "a batch is the same C call per row: bit-identical"


def test_free_root_regressor_is_rnea():
    """A floating base: its six rows are the wrench (force, then moment) the root needs."""
    model = servodyn.load_model("human15", free_root=True)
    rng = np.random.default_rng(9)
    q, qd, qdd = random_state(rng, model)
    tau = model.regressor(q, qd, qdd) @ model.inertial_parameters() + model.armature * qdd
    err = rel_err(tau, model.inverse_dynamics(q, qd, qdd))
    assert err <= REGRESSOR_TOL, f"free root: Y pi differs from the RNEA by {err:.2e} relative"


def test_bad_input_is_refused():
    arm = servodyn.load_model("human_arm")
    with pytest.raises(ValueError, match=r"qd must have shape \(7,\)"):
        arm.regressor(np.zeros(7), np.zeros(6), np.zeros(7))
    with pytest.raises(ValueError, match="qdd has a non-finite value"):
        arm.regressor(np.zeros(7), np.zeros(7), np.full(7, np.nan))
    with pytest.raises(FloatingPointError, match="regressor: non-finite result at row 1"):
        arm.regressor(np.zeros((2, 7)), np.array([np.zeros(7), np.full(7, 1e200)]), np.zeros((2, 7)))
