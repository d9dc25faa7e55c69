"""The simulated plant takes contact (sim/contact.py, sim/plant.py's `wrenches`): the wrenches it
applies against Pinocchio's dynamics with Pinocchio's own kinematics, a push on a held arm against
Pinocchio's integration, obstacles and pushes in a swing (lock-step and real time), the command
line's refusals."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import tomlkit

from conftest import rel_err
from helpers import run_cli
from runs import run_swing
from servodyn.hal.config import load_config
from servodyn.hal.contact_spec import Plane, Push, Sphere
from servodyn.sim.contact import LOG_COLUMNS, Contacts, Kinematics, body_points
from servodyn.sim.plant import Plant

CONFIG = load_config("replica")
MODEL = CONFIG.model
# the runs here score what the simulator applies, not what the run detects (tests/test_contact_run.py):
# the contact watch is off, so a swing goes on against what it meets
UNWATCHED = replace(CONFIG, safety=replace(CONFIG.guards, contact=False))


def unwatched_file(folder) -> str:
    """replica.toml with the contact watch off, for a command line."""
    doc = tomlkit.parse(CONFIG.path.read_text())
    doc["safety"]["contact"] = False
    path = folder / "replica_unwatched.toml"
    path.write_text(tomlkit.dumps(doc))
    return str(path)


def pinocchio_wrenches(twin, q, rows):
    """Pinocchio's external forces (one per joint, its local frame) for world forces at world points,
    placed by Pinocchio's own forward kinematics."""
    pin = twin.pin
    pin.forwardKinematics(twin.model, twin.data, twin.to_pin_q(q))
    fext = [pin.Force.Zero() for _ in range(twin.model.njoints)]
    for body, force, point in rows:
        placement = twin.data.oMi[twin.body_joint[body]]
        local_force = placement.rotation.T @ force
        local_point = placement.actInv(point)
        fext[twin.body_joint[body]] += pin.Force(local_force, np.cross(local_point, local_force))
    return fext


def pinocchio_com(twin, q, body):
    """A body's centre of mass in the world, by Pinocchio."""
    twin.pin.forwardKinematics(twin.model, twin.data, twin.to_pin_q(q))
    joint = twin.body_joint[body]
    return twin.data.oMi[joint].act(twin.model.inertias[joint].lever)


def test_kinematics_are_the_models_user_frames():
    """The contact's own kinematics (plain floats, for speed) against the model's user_poses, and
    the points' velocities against a finite difference of them."""
    rng = np.random.default_rng(3)
    kinematics = Kinematics(MODEL)
    for _ in range(20):
        q, qd = rng.uniform(MODEL.lower, MODEL.upper), rng.normal(size=MODEL.nv) * 3
        R, p, w, v = kinematics(q, qd)
        R0, p0 = MODEL.user_poses(q)
        assert np.abs(R - R0).max() <= 1e-14 and np.abs(p - p0).max() <= 1e-14, "the same frames as the model's"
        h = 1e-6       # central differences: O(h²) off, and rounding 1e-16 / h
        (R1, p1), (R2, p2) = MODEL.user_poses(q + h * qd), MODEL.user_poses(q - h * qd)
        assert np.abs((p1 - p2) / (2 * h) - v).max() <= 1e-8, "origin velocities: their positions' rate"
        spin = np.einsum("bij,bkj->bik", (R1 - R2) / (2 * h), R0)         # Ṙ Rᵀ = [ω]×
        assert np.abs(spin[:, [2, 0, 1], [1, 2, 0]] - w).max() <= 1e-8, "angular velocities likewise"


def test_wrenches_match_pinocchio_aba(twin):
    """On random states of the replica: a push at a random body's centre of mass and two obstacles
    the arm is sunk into; the accelerations the plant's wrenches give (the C core's forward
    dynamics) against Pinocchio's aba with the same world forces put on its joints by its own
    kinematics. The pushes' points against Pinocchio's centres of mass."""
    pin_twin = twin(MODEL)
    rng = np.random.default_rng(31)
    touched = set()
    for trial in range(20):
        q, qd = rng.uniform(MODEL.lower, MODEL.upper), rng.normal(size=MODEL.nv)
        tau = rng.normal(size=MODEL.nv) * 2
        R, p = MODEL.user_poses(q)
        # an obstacle round a random sample point of a random body, a plane through the hand's middle
        body = int(rng.integers(MODEL.nbody))
        local = body_points(MODEL.bodies[body])
        centre = p[body] + R[body] @ local[rng.integers(len(local))] + rng.normal(size=3) * 0.01
        normal = rng.normal(size=3)
        hand = p[-1] + R[-1] @ np.asarray(MODEL.bodies[-1].com)
        obstacles = [Sphere(tuple(centre), 0.04, stiffness=rng.uniform(1e4, 1e5)), Plane(tuple(normal), normal @ hand)]
        contacts = Contacts(MODEL, obstacles)
        pushed = int(rng.integers(MODEL.nbody))
        contacts.schedule(Push(MODEL.body_names[pushed], tuple(rng.normal(size=3) * 20), 0.0))
        f_ext = contacts(0.0, q, qd)
        rows = [(MODEL.body_names.index(r[1]), np.array(r[3:6]), np.array(r[6:9])) for r in contacts.log]
        assert any(r[2].startswith("obstacle") for r in contacts.log), f"trial {trial}: the arm is in an obstacle"
        touched |= {r[0] for r in rows}
        push_row = next(r for r in contacts.log if r[2] == "push 0")
        assert np.abs(np.array(push_row[6:9]) - pinocchio_com(pin_twin, q, pushed)).max() <= 1e-12, \
            "a push acts at the body's centre of mass, where Pinocchio has it"
        mine = MODEL.forward_dynamics(q, qd, tau, f_ext)
        pin = pin_twin.pin
        theirs = pin.aba(pin_twin.model, pin_twin.data, pin_twin.to_pin_q(q), pin_twin.to_pin(qd), pin_twin.to_pin(tau),
                         pinocchio_wrenches(pin_twin, q, rows))[pin_twin.index]
        free = MODEL.forward_dynamics(q, qd, tau)
        assert rel_err(theirs, free) > 1e-3, "the wrenches change the accelerations"
        assert rel_err(mine, theirs) <= 1e-9, f"trial {trial}: qdd {mine} vs Pinocchio's {theirs}"
    assert len(touched) >= 5, f"contacts on most of the 7 bodies over the trials, got {sorted(touched)}"


class HeldDrive:
    """A drive whose horn gives a constant torque: the arm held against gravity at its start pose."""

    def __init__(self, torque: float):
        self.torque = torque

    def set_present(self, position, velocity, current) -> None:
        pass

    def output_current(self, position, velocity, dt) -> float:
        return 0.0

    def output_torque(self, current, velocity) -> float:
        return self.torque


def test_a_push_moves_a_held_arm_as_pinocchio_integrates_it(twin):
    """The arm held at rest by constant joint torques (its gravity torques there); 10 N at the
    hand's centre of mass from 20 ms for 50 ms. The plant's motion against RK4 on Pinocchio's aba,
    the force at Pinocchio's centre of mass held over each 1 ms step as the plant holds it: still
    before the push, the same path during and after it, within 1e-9 rad."""
    pin_twin = twin(MODEL)
    pin = pin_twin.pin
    q0 = np.clip(np.array([0.3, 0.4, 0.2, 0.8, 0.1, 0.2, 0.1]), MODEL.lower + 0.3, MODEL.upper - 0.3)
    gravity = MODEL.inverse_dynamics(q0, np.zeros(MODEL.nv), np.zeros(MODEL.nv))
    joints = [SimpleNamespace(dof=d, direction=1.0, gear_ratio=1.0, zero_offset=0.0) for d in MODEL.dof_names]
    plant = Plant(MODEL, joints, [HeldDrive(g) for g in gravity], small_time_step=1e-3, q0=q0)
    plant.wrenches = contacts = Contacts(MODEL)
    force, hand = np.array([0.0, 6.0, -8.0]), MODEL.nbody - 1
    contacts.schedule(Push(MODEL.body_names[hand], tuple(force), 0.02, 0.05))

    def acceleration(q, qd, fext):
        return pin.aba(pin_twin.model, pin_twin.data, pin_twin.to_pin_q(q), pin_twin.to_pin(qd), pin_twin.to_pin(gravity),
                       fext)[pin_twin.index]

    q, qd, dt = q0.copy(), np.zeros(MODEL.nv), 1e-3
    worst, moved = 0.0, 0.0
    for step in range(120):
        t = step * dt
        pushing = 0.02 - 1e-9 <= t < 0.07 - 1e-9
        fext = pinocchio_wrenches(pin_twin, q, [(hand, force, pinocchio_com(pin_twin, q, hand))] if pushing else [])
        k1 = (qd, acceleration(q, qd, fext))         # RK4 with the wrench held in the joints' frames
        k2 = (qd + dt / 2 * k1[1], acceleration(q + dt / 2 * k1[0], qd + dt / 2 * k1[1], fext))
        k3 = (qd + dt / 2 * k2[1], acceleration(q + dt / 2 * k2[0], qd + dt / 2 * k2[1], fext))
        k4 = (qd + dt * k3[1], acceleration(q + dt * k3[0], qd + dt * k3[1], fext))
        q = q + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        qd = qd + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        plant.advance(dt)
        worst = max(worst, float(np.abs(plant.q - q).max()))
        moved = max(moved, float(np.abs(plant.q - q0).max()))
        if step == 19:
            assert np.abs(plant.q - q0).max() <= 1e-12, "held still until the push"
    assert moved >= 0.01, f"10 N at the hand moves the arm by more than 0.01 rad in 0.1 s, got {moved:.4f}"
    assert worst <= 1e-9, f"the plant's path differs from Pinocchio's by {worst:.2e} rad"
    status = contacts.status()
    assert status["onset_time"] == pytest.approx(0.02, abs=1e-9) and status["body"] == "r_hand"
    assert status["peak_force_n"] == pytest.approx(10.0, rel=1e-12) and status["force_n"] == 0.0
    assert len(contacts.log) == 50, "one row a step of the push's 50 ms"


def test_a_stiff_contact_adds_no_energy():
    """The limp arm falls 1 cm onto a plane of 1000 N/mm, the stiffest taken (the plant cuts its
    1 ms step into 10 pieces there): a passive contact, so the arm's energy never exceeds what it
    started with, and it sinks no deeper than the fall's energy can push it."""
    joints = [SimpleNamespace(dof=d, direction=1.0, gear_ratio=1.0, zero_offset=0.0) for d in MODEL.dof_names]
    q0 = np.clip(np.array([1.2, 0.3, 0.0, 0.3, 0.0, 0.0, 0.0]), MODEL.lower, MODEL.upper)
    plant = Plant(MODEL, joints, [HeldDrive(0.0) for _ in MODEL.dof_names], small_time_step=1e-3, q0=q0)
    probe = Contacts(MODEL)
    R, p, _, _ = probe.kinematics(q0, np.zeros(MODEL.nv))
    lowest = float((p[probe.owner] + np.einsum("pij,pj->pi", R[probe.owner], probe.points))[:, 2].min())
    plant.wrenches = contacts = Contacts(MODEL, [Plane((0.0, 0.0, 1.0), lowest - 0.01, stiffness=1e6)])
    assert contacts.substeps(1e-3) == 10, "the step cut in 10: whole, it gains energy (this test fails with 1)"
    start = sum(MODEL.energy(q0, np.zeros(MODEL.nv)))
    most, deepest = -np.inf, 0.0
    for _ in range(500):
        plant.advance(1e-3)
        most = max(most, sum(MODEL.energy(plant.q, plant.qd)))
        deepest = max([deepest] + [row[-1] for row in contacts.log[-10:]])
    assert contacts.status()["onset_time"] is not None, "the arm reaches the plane"
    assert most <= start + 1e-6, f"energy {most:.6f} J over the start's {start:.6f} J"
    # the spring can hold at most what the fall released, the whole weight over the 1 cm drop and the sinking
    bound = np.sqrt(2 * MODEL.total_mass * 9.81 * 0.0105 / 1e6)
    assert 0 < deepest <= bound, f"sunk {deepest * 1e3:.3f} mm into a plane of 1000 N/mm (at most {bound * 1e3:.3f})"


def plane_crossing_time(swing, plane: Plane) -> float:
    """When the planned motion first puts a sample point of the arm inside the plane (the model's own
    user_poses, the swing's clock)."""
    points = [body_points(b) for b in MODEL.bodies]
    for t, q in zip(swing.t, swing.q):
        R, p = MODEL.user_poses(q)
        for body, local in enumerate(points):
            if ((p[body] + local @ R[body].T) @ plane.normal < plane.offset).any():
                return float(t)
    raise AssertionError("the planned motion never enters the plane")


@pytest.mark.slow
def test_a_swing_through_a_plane_reports_the_contact(tmp_path):
    """The replica's forehand through a wall at y = -0.3 m (the hand sweeps to y = -0.54): the
    simulator reports a contact at the hand's end of the arm, its onset on the swing's clock within
    20 ms of when the planned motion first enters the wall, a peak force and the log."""
    from servodyn.control.motion import motion_path
    wall = Plane((0.0, 1.0, 0.0), -0.3)
    summary = run_swing(UNWATCHED, tmp_path, obstacles=(wall,), figure=False)
    contact = summary["sim_contact"]
    swing = motion_path("tennis_forehand", MODEL).at_scale(CONFIG.time_scale_for("tennis_forehand"),
                                                             CONFIG.control_period)
    planned = plane_crossing_time(swing, wall)
    assert contact["body"] in ("r_forearm", "r_wrist_link", "r_hand"), contact
    assert contact["onset_t_s"] == pytest.approx(planned, abs=0.02), f"planned {planned:.3f} s, {contact}"
    assert 5.0 <= contact["peak_force_n"] <= 1000.0 and contact["obstacles"] == 1 and contact["log_rows"] > 100
    # the watch off, the wall holds the hand back until the following-error guard stops the swing
    assert summary["stop_reason"] == "following_error", summary["error"]


def first_jolt(path, ticks: int = 2, threshold: float = 0.1) -> float:
    """The swing log's first time any joint's measured speed changed by more than `threshold` rad/s
    over the last `ticks` ticks (a held arm sags by a few hundredths of that; 40 N at the hand
    accelerates a joint by about 100 rad/s²)."""
    with open(path) as f:
        rows = list(csv.DictReader(f))
    speeds = np.array([[float(r[k]) for k in rows[0] if k.startswith("qd_")] for r in rows])
    change = np.abs(speeds[ticks:] - speeds[:-ticks]).max(axis=1)
    return float(rows[ticks + int(np.argmax(change > threshold))]["t"])


def push_swing(out, realtime: bool):
    push = Push("r_hand", (0.0, 40.0, 0.0), 0.3, 0.1)
    # 40 N throws the soft hold 8.7° off after the push: the following error let go, these runs time the push
    pushed = replace(UNWATCHED, safety=replace(UNWATCHED.guards, following_error=(1.0,) * MODEL.nv))
    summary = run_swing(pushed, out, hold=0.6, contacts=(push,), realtime=realtime, figure=False)
    return summary, push


def test_a_push_lands_at_its_swing_time_in_lockstep(tmp_path):
    """A held pose with 40 N at the hand from 0.3 s: the simulator's onset on the swing's clock within
    a tick of 0.3 s, and the arm's measured speeds jolt within three ticks after."""
    summary, push = push_swing(tmp_path, realtime=False)
    period = CONFIG.control_period
    contact = summary["sim_contact"]
    assert contact["onset_t_s"] == pytest.approx(push.start, abs=period), contact
    assert contact["peak_force_n"] == pytest.approx(40.0) and contact["log_rows"] == round(push.duration / period)
    jolt = first_jolt(tmp_path / "swing_log.csv")
    assert push.start <= jolt <= push.start + 3 * period, f"the arm jolts at {jolt:.4f} s"


@pytest.mark.parametrize("args, says", [
    (["--contact", "r_hand:0,0@1"], "3 finite numbers"),
    (["--contact", "r_hand0,0,1@1"], "BODY:FX,FY,FZ@T[+D]"),
    (["--contact", "r_hand:0,0,1@1+0"], "positive number of seconds"),
    (["--contact", "r_hnd:0,0,-10@1"], "bodies: r_shoulder_pitch_link"),
    (["--obstacle", "cube:0,0,0,1"], "plane:NX,NY,NZ,D[@K]"),
    (["--obstacle", "sphere:0,0,0,0.1@0"], "stiffness"),
    (["--obstacle", "plane:0,0,1,0.5", "--port", "/dev/ttyUSB0"], "not on a real port"),
])
def test_a_bad_contact_is_one_line_and_exit_2(tmp_path, args, says):
    result = run_cli("swing", *args, "--out", tmp_path)
    assert result.returncode == 2 and says in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not (tmp_path / "swing_log.csv").exists(), "nothing ran"


def test_the_child_process_takes_obstacles_and_pushes(tmp_path):
    """The simulator in its own process (the replica's one Dynamixel bus): obstacles from its
    command line, a push and the log over its control socket, JSON both ways."""
    from servodyn.sim.serve import serve
    with serve(CONFIG, "lockstep", obstacles=[Sphere((0.0, 0.0, -0.9), 0.05)]) as server:
        assert type(server).__name__ == "SimProcess"
        server.schedule_push(Push("r_forearm", (1.0, 2.0, 2.0), 0.0), origin=0.0)
        status = server.status()
        log = server.contact_log()
    assert status["contact"]["obstacles"] == 1 and status["contact"]["pushes"][0]["body"] == "r_forearm"
    assert status["contact"]["onset_time"] is None, "the plant has not moved: nothing applied yet"
    assert log == {"columns": list(LOG_COLUMNS), "rows": []}
    json.dumps(status)


def test_sim_takes_obstacles_for_a_swing_on_its_port(tmp_path):
    """`servodyn sim --obstacle`: a simulator in its own process with a soft ball (1 N/mm) under the
    hanging hand (its lowest points about 2 mm into it); a swing holding the pose on its port; at
    Ctrl-C the sim says when the contact began (the plant's first step) and on which body."""
    import signal
    from helpers import PTY, sim_process
    with sim_process("--lockstep", "--obstacle", "sphere:0.0175,-0.003,-0.713,0.06@1000") as (proc, banner):
        result = run_cli("swing", "--config", unwatched_file(tmp_path), "--port", PTY.findall("".join(banner))[0],
                         "--hold", "0.3", "--out", tmp_path / "run")
        proc.send_signal(signal.SIGINT)
        said = proc.communicate(timeout=30)[0]
    assert result.returncode == 0, result.stderr
    assert "contact: first at 0.000 s on r_hand" in said, said
