"""The controller step (firmware/core/control.c) and closed-form control of the swing."""

import numpy as np
import pytest

import servodyn
from servodyn.control import ControlConfig, Controller
from servodyn.control.motion import load_motion

ARM = servodyn.load_model("human_arm")
SWING = load_motion("tennis_forehand", ARM).sample(1e-3)


def test_feedforward_is_held_for_time_step():
    """Feed-forward mode: tau = RNEA at the desired state of the update tick, the same for the
    next update_ticks - 1 ticks, whatever the measured state does."""
    c = Controller(ARM, ControlConfig(mode="feedforward", time_step=5e-3), q_start=SWING.q[0])
    k0 = 400
    expected = ARM.inverse_dynamics(SWING.q[k0], SWING.qd[k0], SWING.qdd[k0])
    c._c.reset()
    for k in range(k0 - 5 * 80, k0):         # tick counts to k0 - 400 + 400: an update lands on k0
        c.step(SWING.q[k], SWING.qd[k], SWING.qdd[k], SWING.q[k], SWING.qd[k])
    taus = [c.step(SWING.q[k], SWING.qd[k], SWING.qdd[k], SWING.q[k] + 0.1, SWING.qd[k])
            for k in range(k0, k0 + 5)]
    assert np.array_equal(taus[0], expected), "the update tick's torque is RNEA(desired), exactly"
    for tau in taus[1:]:
        assert np.array_equal(tau, expected), "held (zero-order) until the next update"


def test_computed_torque_on_the_trajectory_is_inverse_dynamics():
    """With the measured state on the desired one, computed torque reduces to RNEA(desired)."""
    c = Controller(ARM, ControlConfig(mode="computed_torque", time_step=1e-3), q_start=SWING.q[0])
    for k in (0, 500, 1150):
        tau = c.step(SWING.q[k], SWING.qd[k], SWING.qdd[k], SWING.q[k], SWING.qd[k])
        expected = ARM.inverse_dynamics(SWING.q[k], SWING.qd[k], SWING.qdd[k])
        assert np.allclose(tau, expected, rtol=1e-12, atol=1e-12), \
            f"tick {k}: no tracking error, so no feedback term; the torque is RNEA(desired) to rounding"


def test_pd_adds_the_joint_feedback():
    c = Controller(ARM, ControlConfig(mode="feedforward_pd", time_step=1e-3), q_start=SWING.q[0])
    k = 700
    e = np.linspace(-0.01, 0.01, ARM.nv)
    tau = c.step(SWING.q[k], SWING.qd[k], SWING.qdd[k], SWING.q[k] - e, SWING.qd[k])
    ff = ARM.inverse_dynamics(SWING.q[k], SWING.qd[k], SWING.qdd[k])
    assert np.allclose(tau, ff + c.kp * e, rtol=1e-12, atol=1e-12), \
        "RNEA(desired) plus kp times the position error (the velocity error is zero)"


def test_limits_clamp_and_count_as_limiting_not_faults():
    c = Controller(ARM, ControlConfig(mode="feedforward_pd", tau_max=2.0), q_start=SWING.q[0])
    tau = c.step(SWING.q[1100], SWING.qd[1100], SWING.qdd[1100], SWING.q[1100], SWING.qd[1100])
    assert np.abs(tau).max() == pytest.approx(2.0), \
        "clamped to tau_max: the swing at tick 1100 asks 10.4 N·m of the shoulder flexion"
    assert c.status == 1 and c._c.nlimited == 1 and c._c.nfault == 0, \
        f"status {c.status} (1 = SD_STATUS_LIMITED), {c._c.nlimited} limited, {c._c.nfault} faults"


def test_nonfinite_input_is_refused_before_the_core():
    """The binding refuses a NaN with a clear error (the core's own fault path, zero torque and
    a fault count, is tested in tests/c/test_control.c)."""
    c = Controller(ARM, q_start=SWING.q[0])
    q = SWING.q[10].copy()
    q[3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        c.step(SWING.q[10], SWING.qd[10], SWING.qdd[10], q, SWING.qd[10])


@pytest.mark.parametrize("mode,spoil", [
    ("computed_torque", lambda q_d, q, qd: qd.__setitem__(6, 1e160)),       # RNEA(measured): v x v overflows
    ("feedforward_pd", lambda q_d, q, qd: (q_d.__setitem__(6, 1.7e308),     # e = q_d - q overflows
                                           q.__setitem__(6, -1.7e308))),
])
def test_overflow_raises_not_a_zero_or_a_clamp(mode, spoil):
    """Finite inputs whose torque is not finite: the core zeroes every torque and flags the step
    (SD_STATUS_OVERFLOW, 4); the binding raises instead of handing back that zero (or, before,
    an inf clamped to tau_max as if it were a torque)."""
    c = Controller(ARM, ControlConfig(mode=mode, tau_max=5.0), q_start=SWING.q[0])
    q_d, q, qd = SWING.q[10].copy(), SWING.q[10].copy(), SWING.qd[10].copy()
    spoil(q_d, q, qd)
    with pytest.raises(FloatingPointError, match="non-finite torque at tick 0"):
        c.step(q_d, SWING.qd[10], SWING.qdd[10], q, qd)
    assert c.status == 4 and c._c.nfault == 1, f"status {c.status} (4 = SD_STATUS_OVERFLOW), {c._c.nfault} faults"
    tau = c.step(SWING.q[11], SWING.qd[11], SWING.qdd[11], SWING.q[11], SWING.qd[11])
    assert c.status in (0, 1) and np.abs(tau).max() > 0.1, "the next good step commands torque again"


def test_float_and_double_controllers_agree():
    """The same steps in the MCU's single precision: torques within 1e-4 of the largest torque."""
    run = Controller(ARM, q_start=SWING.q[0]).run(ARM, SWING)
    double = Controller(ARM, q_start=SWING.q[0])
    single = Controller(ARM, q_start=SWING.q[0], precision="float")
    worst = 0.0
    for k in range(0, len(run.t), 70):
        args = (run.q_d[k], run.qd_d[k], SWING.qdd[k], run.q[k], run.qd[k])
        double.reset()
        single.reset()
        worst = max(worst, np.abs(double.step(*args) - single.step(*args)).max())
    scale = np.abs(run.tau).max()
    assert worst <= 1e-4 * scale, f"float controller differs by {worst / scale:.2e} of the peak torque"


def test_feedforward_cuts_tracking_error():
    """The paper's point: the same PD with the inverse-dynamics feed-forward tracks the swing
    far better (measured 33.8 deg without, 2.8 deg with, at time_step = 10 small steps)."""
    pd = Controller(ARM, ControlConfig(mode="pd"), q_start=SWING.q[0]).run(ARM, SWING)
    ff = Controller(ARM, ControlConfig(mode="feedforward_pd"), q_start=SWING.q[0]).run(ARM, SWING)
    assert pd.completed and ff.completed, "both plants stay finite to the end of the swing"
    ratio = np.abs(pd.error).max() / np.abs(ff.error).max()
    assert ratio >= 5, f"feed-forward cut the largest error only {ratio:.1f}x"


@pytest.mark.parametrize("config,message", [
    (ControlConfig(time_step=1.5e-3), "whole multiple"),
    (ControlConfig(mode="magic"), "mode must be one of"),
    (ControlConfig(kp=-1.0), "negative or not finite"),
])
def test_bad_configuration(config, message):
    with pytest.raises(ValueError, match=message):
        Controller(ARM, config)


def test_ball_joints_cannot_be_controlled():
    with pytest.raises(ValueError, match="simulation only"):
        Controller(ARM.with_ball_joints())
