"""The SO-101 as a built-in model, configuration and motion: its URDF's gravity loads (against the
figures arms.md derived from the URDF by its own forward kinematics), `servodyn sim --config so101`'s
line (DESIGN.md's contract), the validator naming the overloaded shoulder, and the swing on the
simulated Feetech bus, its feed-forward through PWM against LeRobot's position-only control."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from servodyn.control.motion import motion_path
from servodyn.hal.config import load_config
from servodyn.hal.feetech.table import STEP, Mode
from servodyn.model import load_model
from servodyn.sim.robot import SimulatedRobot

from helpers import run_cli, sim_process
from runs import run_swing

DOFS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


def test_model_has_the_urdfs_gravity_loads_and_inertias():
    """Over 20 000 random poses in the joint limits, the largest gravity torque (no armature) is
    arms.md's, derived from the URDF by an independent forward kinematics: shoulder_lift 0.86,
    elbow_flex 0.45, wrist_flex 0.12 N m (to their 0.01 rounding); the link inertia about the elbow
    0.0086 and wrist_flex 0.0010 kg m² at q = 0 (same source); moving mass 0.485 kg (URDF links
    without the fixed base, 0.632 - 0.147)."""
    model = load_model("so101")
    assert model.dof_names == DOFS
    bare = model.with_armature({d: 0.0 for d in DOFS})
    rng = np.random.default_rng(101)
    q = rng.uniform(bare.lower, bare.upper, size=(20_000, 6))
    gravity = np.abs(bare.inverse_dynamics(q, np.zeros_like(q), np.zeros_like(q))).max(axis=0)
    assert gravity[1:4] == pytest.approx([0.86, 0.45, 0.12], abs=0.006)
    inertia = np.diag(bare.mass_matrix(np.zeros(6)))
    assert inertia[2] == pytest.approx(0.0086, abs=5e-5) and inertia[3] == pytest.approx(0.0010, abs=5e-5)
    assert sum(b.mass for b in model.bodies) == pytest.approx(0.632 - 0.147, abs=1e-3)
    assert np.diag(model.mass_matrix(np.zeros(6)) - bare.mass_matrix(np.zeros(6))) == pytest.approx(0.0284, abs=1e-9)


def test_sim_prints_the_feetech_line():
    """DESIGN.md's contract: `servodyn sim --config so101` names the Feetech bus, its rate and the six
    servos' IDs, then the pseudo-terminal."""
    with sim_process("--config", "so101") as (proc, banner):
        line = next(b for b in banner if b.startswith("simulated"))
        assert re.fullmatch(r"simulated Feetech bus 'arm' of 'so101' \(1000000 baud\): servos 1, 2, 3, 4, 5, 6 on "
                            r"/dev/pts/\d+", line.strip()), line


def test_validate_names_the_overloaded_shoulder(tmp_path):
    """The pick at 5 V (the SO-101's bill of materials) fails on shoulder_lift alone, by its
    torque-speed envelope (and the duty that torque needs at its speed, the check a servo driven by
    PWM gets in place of current): exit 1, and report.json's violations name that joint."""
    result = run_cli("validate", "so101", "so101_pick", "--out", tmp_path)
    assert result.returncode == 1, result.stdout + result.stderr
    report = json.loads((tmp_path / "report.json").read_text())
    found = {(v["dof"], v["check"]) for v in report["violations"]}
    assert ("shoulder_lift", "torque_speed") in found and {dof for dof, _ in found} == {"shoulder_lift"}, found
    assert 1.0 < report["violations"][0]["worst_ratio"] < 1.3
    assert "FAIL (torque_speed)" in next(line for line in result.stdout.splitlines() if "shoulder_lift" in line)


def test_the_configuration_names_its_own_motion(tmp_path):
    """so101's `[swing] motion` is its pick: a swing given no --motion plays it (refused, as the pick at
    5 V is, naming it and its fix), and a configuration naming a motion that is neither built in nor a
    file is refused in one line."""
    assert load_config("so101").swing_motion == "so101_pick"
    result = run_cli("swing", "--config", "so101", "--out", tmp_path)
    assert result.returncode == 2 and "'so101_pick' at time scale 1" in result.stderr, result.stderr
    assert "servodyn validate so101 so101_pick --fit" in result.stderr
    bad = tmp_path / "bad.toml"
    from servodyn.hal.config import builtin_configs
    bad.write_text(builtin_configs()["so101"].read_text().replace('motion = "so101_pick"', 'motion = "nope"'))
    result = run_cli("validate", bad, "so101_pick")
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "swing: 'motion' 'nope' is neither a built-in motion" in result.stderr


def position_only_error(config, motion: str = "so101_pick") -> float:
    """The largest tracking error (rad) of LeRobot's control on the same simulated servos: each
    servo in position mode (0) with its gains 16/0/32, Goal_Position each period, no feed-forward."""
    robot = SimulatedRobot(config, q0=np.zeros(6))
    path = motion_path(motion, config.model).at_scale(1.0, config.control_period)
    robot.plant.q[:] = path.q[0]
    robot.plant.publish()
    for servo in robot.drives:
        servo.write(33, bytes((Mode.POSITION,)))
        servo.write(21, bytes((16, 32, 0)))
        servo.write(40, b"\x01")
    worst = 0.0
    for q in path.q:
        for joint, servo, target in zip(config.joints, robot.drives, q):
            ticks = round((joint.direction * joint.gear_ratio * target + joint.zero_offset) / STEP)
            servo.write(42, ticks.to_bytes(2, "little"))
        robot.advance(config.control_period)
        worst = max(worst, float(np.abs(robot.q - q).max()))
    return worst


@pytest.mark.slow
def test_swing_plays_the_pick_on_the_simulated_feetech_bus(tmp_path):
    """`servodyn swing --config so101 --motion so101_pick --force` (forced past the shoulder's
    verdict, on the simulated bus only): the run completes, every joint within 0.5 deg, and its
    largest error is at least 3x smaller than position-only control's on the same servos (the
    issue's goal for feed-forward through PWM)."""
    summary = run_swing("so101", tmp_path, motion="so101_pick", force=True, figure=False)
    assert summary["completed"] and summary["error"] is None, summary.get("error")
    assert summary["tracking_max_rad"] < np.radians(0.5)
    baseline = position_only_error(load_config("so101"))
    assert baseline > 3 * summary["tracking_max_rad"], (baseline, summary["tracking_max_rad"])


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_swing_learns_the_simulated_feetech_bus_clock(mode):
    """A swing given the pseudo-terminal of `servodyn sim --config so101 [--lockstep]` asks the bus
    which clock its plant keeps (a one-byte READ past the STS table) and gets it."""
    from servodyn.hal.served_clock import served_clock
    from servodyn.sim.transport.pty import PtyServer
    config = load_config("so101")
    with PtyServer(SimulatedRobot(config).port("arm"), mode) as server:
        assert served_clock(config, "arm", server.path) == mode


def test_the_backend_reads_each_tick_and_names_a_faulty_servo():
    """FeetechBus on the simulated bus: a read gives q = 0 at the start pose (2048 steps) with the
    servos' Present Voltage (5.0 V, the supply) and Temperature; a PWM duty written reaches the
    servo as Goal_Time with its sign bit; an overload bit in a servo's status is a
    ServoHardwareError naming its joint; a silent servo a ServoTimeoutError naming it."""
    from servodyn.hal.bus import JointCommand, make_bus
    from servodyn.hal.errors import ServoHardwareError, ServoTimeoutError
    from servodyn.sim.serve import serve
    config = load_config("so101")
    with serve(config, "lockstep", process=False) as served:
        bus = make_bus(config, **served.buses["arm"])
        with bus:
            state = bus.read_state()
            assert np.abs(state.q).max() < STEP and bus.present["voltage"] == pytest.approx([5.0] * 6)
            assert np.isfinite(bus.present["temperature"]).all()
            bus.write(JointCommand.torque(np.array([0.0, -0.5, 0.0, 0.0, 0.0, 0.0])))
            bus.read_state()           # answered after the write's bytes (no reply) were taken in
            servo = served.robot.servo(2)
            assert servo.get("goal_time") == bus.duties([0.0, -0.5, 0, 0, 0, 0], state.qd)[1] < 0
            served.inject_fault(2, "overload")
            with pytest.raises(ServoHardwareError, match="shoulder_lift"):
                bus.read_state()
            served.clear_faults()
            served.inject_fault(4, "silent")
            with pytest.raises(ServoTimeoutError, match="wrist_flex"):
                bus.read_state()
