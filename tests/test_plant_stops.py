"""The simulated arm's joints stop at the model's limits, their mechanical range (sim/plant.py): an
arm left with torque off hangs on its stops as the real one does. Without them the replicas'
elbows sagged 0.02-0.10 rad past full extension within 5 s of the simulator starting, so a swing
begun a few seconds after `servodyn sim` found a joint outside its limits and refused to start."""

from __future__ import annotations

import numpy as np
import pytest

from servodyn.hal.config import load_config
from servodyn.sim.robot import PUSHED, SimulatedRobot
from servodyn.sim.plant import STOP_TIME_CONSTANT

HOST_MARGIN = 0.05      # rad past a limit the host's range check lets by (hal)


@pytest.mark.parametrize("name", ["replica", "replica_can", "replica_mixed"])
def test_an_arm_with_torque_off_hangs_on_its_stops(name):
    """3 s of gravity from the neutral pose (the elbow at full extension, its lower stop): no joint
    goes more than 20 mrad past a stop as a falling link lands on it (its speed over the spring's
    100 rad/s), and none rests more than 1 mrad past one (the spring's give under the weight)."""
    arm = SimulatedRobot(load_config(name))
    model = arm.model
    worst = 0.0
    while arm.time < 3.0:
        arm.advance(0.01)
        past = np.minimum(arm.q - model.lower, 0.0) + np.maximum(arm.q - model.upper, 0.0)
        worst = max(worst, float(np.abs(past).max()))
    assert worst < 0.02, f"{name}: a joint went {worst:.4f} rad past its stop"
    assert float(np.abs(past).max()) < 1e-3, f"{name}: a joint rests {np.abs(past).max():.4f} rad past its stop"
    assert np.isfinite(arm.q).all() and np.isfinite(arm.qd).all()


def test_a_stop_only_pushes_back():
    """Past the upper stop and moving in: the spring-damper pushes back. Past it and leaving
    fast: no torque at all (a damper alone would hold the joint on the stop); inside: none."""
    arm = SimulatedRobot(load_config("replica")).port()
    plant, k = arm.plant, 3
    plant.q[:] = 0.5 * (plant.lower + plant.upper)
    plant.qd[:] = 0.0
    assert not plant.stop_torque().any(), "inside every limit: no stop acts"
    plant.q[k], plant.qd[k] = plant.upper[k] + 0.01, 0.0
    tau = plant.stop_torque()
    w = 1.0 / STOP_TIME_CONSTANT
    assert tau[k] == pytest.approx(-plant._stop_inertia[k] * w * w * 0.01, rel=1e-12), "the spring"
    assert np.count_nonzero(tau) == 1, "only the joint past its stop"
    plant.qd[k] = -10.0                                  # leaving the stop faster than the spring pushes
    assert plant.stop_torque()[k] == 0.0, "a joint leaving its stop is not held on it"


def test_a_pushed_joint_stays_past_its_stop():
    """The "pushed" fault is a push past the stop, which gives: the joint is still beyond its
    configured limit a tick later, where the host sees it (the safe stop the fault is for)."""
    config = load_config("replica")
    arm = SimulatedRobot(config).port()
    arm.inject_fault(4, "pushed")
    k = [s.id for s in arm.servos].index(4)
    arm.advance(config.control_period)
    limit = arm.joints[k].position_limits[1]
    assert arm.q[k] > limit + HOST_MARGIN, f"{arm.q[k]:.3f} rad: pushed back inside {limit + HOST_MARGIN:.3f}"
    assert arm.q[k] == pytest.approx(limit + PUSHED, abs=0.05), "the push holds, the stop gave"
