"""Gains a real servo can live with (host/control/schedule.py, the error low-pass of
firmware/core/control.c, the chatter figure of servodyn.loop): the PD's bandwidth is bounded by
the sensors' resolution against each joint's torque scale, the low-pass of its errors keeps the
discrete closed loop damped, and the chatter figure measures what it says. The swing's own
figures (chatter and tracking on the simulated replica) are asserted in tests/test_swing.py and
tests/test_swing_can.py, on the swings those files already run."""

import math

import numpy as np
import pytest

from servodyn.control.motion import motion_path
from servodyn.control.schedule import (Sensors, error_lowpass, plan_gains, planned_torque_scale,
                                       resolution_bandwidth, scheduled_gains)
from servodyn.control.timing import (HOME_DURATION, MAX_BANDWIDTH, MIN_STIFFNESS,
                                     QUANTUM_SHARE, SMALL_TIME_STEP)
from servodyn.control.schedule import homing
from servodyn.hal.backend import joint_sensors
from servodyn.hal.can.frames import to_float
from servodyn.hal.config import load_config
from servodyn.hal.dynamixel.units import ServoMap
from servodyn.loop import CHATTER_CUTOFF_HZ, chatter


def _plan(name):
    config = load_config(name)
    swing = motion_path("tennis_forehand", config.model).at_scale(config.swing_time_scale, config.control_period)
    return config, swing


@pytest.fixture(scope="module")
def replica():
    config, swing = _plan("replica")
    sensors = joint_sensors(config)
    return config, swing, sensors, plan_gains(config.model, swing, sensors)


def test_dynamixel_sensor_steps_are_the_units_own():
    """One count of Present Position and Present Velocity, decoded by the HAL's own unit map, is
    the step the gains are planned against (0.088° and 0.229 rpm on the replica's servos)."""
    config = load_config("replica")
    units = ServoMap.from_joints(config.joints)
    sensors = joint_sensors(config)
    n = len(config.joints)
    tick = np.abs(units.from_ticks(np.full(n, 2049)) - units.from_ticks(np.full(n, 2048)))
    unit = np.abs(units.from_velocity_units(np.ones(n, dtype=int)) - units.from_velocity_units(np.zeros(n, dtype=int)))
    assert sensors.position_step == pytest.approx(tick, rel=1e-12), "one encoder tick at the joint"
    assert sensors.velocity_step == pytest.approx(unit, rel=1e-12), "one velocity unit at the joint"
    assert np.degrees(sensors.position_step[0]) == pytest.approx(360 / 4096, rel=1e-12), "0.088° a tick"


def test_can_sensor_steps_are_the_frames_own():
    """A CAN motor's MIT reply: two adjacent position (16-bit) and velocity (12-bit) codes decode
    to the planned steps."""
    config = load_config("replica_can")
    sensors = joint_sensors(config)
    for k, joint in enumerate(config.joints):
        r = joint.options["ranges"]
        dp = to_float(1001, -r.p_max, r.p_max, 16) - to_float(1000, -r.p_max, r.p_max, 16)
        dv = to_float(1001, -r.v_max, r.v_max, 12) - to_float(1000, -r.v_max, r.v_max, 12)
        assert sensors.position_step[k] == pytest.approx(dp / joint.gear_ratio, rel=1e-9), joint.dof
        assert sensors.velocity_step[k] == pytest.approx(dv / joint.gear_ratio, rel=1e-9), joint.dof


def test_resolution_bandwidth_is_the_root_of_the_bound():
    """I (w² dq + 2 w dv) = QUANTUM_SHARE x scale at the returned w, for a position-only, a
    velocity-only and a mixed sensor; infinite for exact sensors (no bound)."""
    inertia, scale = np.array([0.05, 0.05, 0.05, 0.05]), np.array([0.2, 0.2, 0.2, 0.2])
    sensors = Sensors(position_step=np.array([1.5e-3, 0.0, 1.5e-3, 0.0]), velocity_step=np.array([0.0, 0.024, 0.024, 0.0]))
    w = resolution_bandwidth(inertia, sensors, scale)
    assert np.isinf(w[3]), "exact sensors: nothing to bound"
    torque = inertia[:3] * (w[:3]**2 * sensors.position_step[:3] + 2 * w[:3] * sensors.velocity_step[:3])
    assert torque == pytest.approx(QUANTUM_SHARE * scale[:3], rel=1e-12), "the bound holds with equality"


def test_exact_sensors_leave_the_gains_as_they_were():
    """Without sensors (or with exact ones) the gains are the stiffness-based ones."""
    config, swing = _plan("replica")
    q = swing.q[len(swing.q) // 2]
    exact = Sensors(position_step=np.zeros(7), velocity_step=np.zeros(7))
    kp, kd = scheduled_gains(config.model, q)
    kp_exact, kd_exact = scheduled_gains(config.model, q, exact, np.ones(7))
    assert kp_exact == pytest.approx(kp, rel=1e-12) and kd_exact == pytest.approx(kd, rel=1e-12)


def test_every_joint_keeps_the_quantisation_bound(replica):
    """Along homing and the swing, at every knot: one count of each sensor commands at most
    QUANTUM_SHARE of the joint's torque scale, unless the joint is at its stiffness floor
    (MIN_STIFFNESS, the servo's friction), which wins. On the replica the wrist is bounded (its
    rotor-dominated inertia turned one tick and one velocity unit into 56 % of its torque) and nothing
    needs the floor."""
    config, swing, sensors, (home, motion) = replica
    rest = homing(config.model.neutral_q(), swing.q[0], HOME_DURATION, swing.t[1] - swing.t[0])
    scale = planned_torque_scale(config.model, rest, swing)
    for schedule in (home, motion):
        quantum = sensors.quantum_torque(schedule.kp, schedule.kd)
        floored = schedule.kp <= MIN_STIFFNESS * (1 + 1e-9)
        assert np.all((quantum <= QUANTUM_SHARE * scale * (1 + 1e-9)) | floored), \
            f"largest share {np.max(quantum / scale):.3f} > {QUANTUM_SHARE}"
        assert not floored.any(), "the replica's joints stay above the friction floor"
    wrist = config.model.dof_names.index("r_wrist_flexion")
    share = sensors.quantum_torque(motion.kp, motion.kd)[:, wrist] / scale[wrist]
    assert share.max() == pytest.approx(QUANTUM_SHARE, rel=1e-6), "the wrist's bandwidth is the bound's"


def test_error_lowpass_keeps_the_discrete_loop_damped(replica):
    """The closed loop of one joint (inertia I, the PD on its low-passed errors, the torque held
    a control period, dt = 1 ms) keeps a damping ratio of at least 0.9 at every bandwidth the
    planning can give, up to MAX_BANDWIDTH, with the cut-off at ERROR_FILTER_RATIO times the
    bandwidth; a cut-off at the bandwidth itself would leave it nearly oscillating (the check
    can fail)."""
    dt = SMALL_TIME_STEP

    def damping(w, a):
        kp, kd = w * w, 2 * w      # per unit inertia
        ef, vf = np.array([a, 0, 1 - a, 0]), np.array([0, a, 0, 1 - a])
        u = kp * ef + kd * vf
        # state (e, e', e_f, e'_f before this tick); e'' = -u over the held period
        A = np.array([np.array([1, dt, 0, 0]) - dt * dt / 2 * u, np.array([0, 1, 0, 0]) - dt * u, ef, vf])
        s = np.log(np.linalg.eigvals(A).astype(complex)) / dt
        return float(np.min(-s.real / np.abs(s)))

    config, swing, sensors, (home, motion) = replica
    planned = np.concatenate([2 * home.kp / home.kd, 2 * motion.kp / motion.kd]).ravel()
    for w in [*np.linspace(planned.min(), planned.max(), 5), 20.0, 50.0, MAX_BANDWIDTH]:
        zeta = damping(w, float(error_lowpass(w, dt)))
        assert zeta >= 0.9, f"damping {zeta:.2f} at {w:.1f} rad/s"
    assert damping(20.0, float(1 - math.exp(-20.0 * dt))) < 0.5, "a cut-off at the bandwidth is underdamped"


def test_schedules_carry_the_low_pass_of_their_highest_bandwidth(replica):
    config, swing, sensors, (home, motion) = replica
    for schedule in (home, motion):
        expect = error_lowpass((2 * schedule.kp / schedule.kd).max(axis=0), config.control_period)
        assert schedule.error_lowpass == pytest.approx(expect, rel=1e-12)
        assert np.all((schedule.error_lowpass > 0) & (schedule.error_lowpass < 1)), "a filter, not a hold"
    _, no_sensors = plan_gains(config.model, swing)
    assert np.all(no_sensors.error_lowpass == 0), "exact sensors: no filter"


def test_chatter_measures_the_part_above_the_cutoff():
    """A 1 Hz torque of 1 N m plus 10 mN m at 100 Hz: the chatter is the 100 Hz part, rms
    0.01/√2 over the peak (the 20 Hz Butterworth run both ways passes 0.16 % of 100 Hz and
    takes 6e-6 of 1 Hz: 1 % covers both), peak to peak 0.02 sin 72° N m (sampled 10 a period); the smooth joint has none.
    Whole periods, as a swing from rest to rest: the filter's ends then add nothing."""
    dt = 1e-3
    t = np.arange(0, 2001) * dt
    tau = np.column_stack([np.sin(2 * np.pi * t) + 0.01 * np.sin(2 * np.pi * 100 * t), np.sin(2 * np.pi * t)])
    share, p2p = chatter(tau, dt)
    peak = np.abs(tau[:, 0]).max()
    assert share[0] == pytest.approx(0.01 / math.sqrt(2) / peak, rel=0.01)
    assert p2p[0] == pytest.approx(0.02 * math.sin(0.4 * math.pi), rel=0.01), "its samples' extremes, at ±72°"
    assert share[1] < 1e-4, "a 1 Hz motion is no chatter"
    assert chatter(tau[: int(0.5 / CHATTER_CUTOFF_HZ / dt)], dt) is None, "under a period of the cut-off"
