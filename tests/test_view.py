"""`servodyn view` without a browser: the solids the arm is drawn from (their meshes against the
inertia the dynamics uses), the URDF export's visual geometry, the page's state as viser holds it
(the pose is the forward kinematics, the shaping editor's torques are the batched RNEA of the edited
motion, the validator's verdict), a logged run, and the live feed the loop calls.

The page itself in a real browser: test_view_browser.py."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import trimesh

import servodyn
from servodyn.control.motion import load_motion
from servodyn.model.shapes import box_sides, local_mesh, solid_mesh
from servodyn.view import ViewError, Viewer, load_subject, log_timeline, open_view, share_rgb

from helpers import quiet, run_cli, wait_until



def _volume(solid) -> float:
    d = solid.dims
    if solid.draw == "box":
        return float(np.prod(box_sides(solid)))
    return {"cylinder": lambda: math.pi * d[0] ** 2 * d[1],
            "sphere": lambda: 4 / 3 * math.pi * d[0] ** 3,
            "ellipsoid": lambda: 4 / 3 * math.pi * d[0] * d[1] * d[2],
            "frustum": lambda: math.pi * d[2] * (d[0] ** 2 + d[0] * d[1] + d[1] ** 2) / 3}[solid.kind]()


@pytest.mark.parametrize("name", ["human15", "replica", "replica_dm", "replica_mixed"])
def test_every_solid_is_a_closed_mesh_of_its_volume(name):
    """Each primitive's mesh is watertight and outward (positive volume), and holds the solid's
    volume to within the polygon's shortfall (96 segments: under 0.5 %)."""
    model = servodyn.load_model(name)
    solids = [s for b in model.bodies for s in b.solids]
    assert len(solids) >= len(model.bodies), "every body of a built-in model keeps its solids for drawing"
    for solid in solids:
        mesh = trimesh.Trimesh(*local_mesh(solid, segments=96), process=False)
        assert mesh.is_watertight, f"{solid.kind} mesh has holes"
        assert mesh.volume == pytest.approx(_volume(solid), rel=5e-3), \
            f"{solid.kind} {solid.dims}: mesh volume {mesh.volume:.6g} m^3, the solid's {_volume(solid):.6g}"


def test_a_servo_drawn_as_a_box_has_the_inertia_the_dynamics_uses():
    """The replica's servo housings are ellipsoids of the housing's inertia, drawn as the box they
    stand for: that box, at the servo's mass, has the ellipsoid's inertia (trimesh integrates it)."""
    model = servodyn.load_model("replica")
    boxes = [s for b in model.bodies for s in b.solids if s.draw == "box"]
    assert len(boxes) == 6, "the six moving servos' housings"
    for solid in boxes:
        mesh = trimesh.Trimesh(*local_mesh(solid), process=False)
        mesh.density = solid.mass / mesh.volume
        a, b, c = solid.dims
        ellipsoid = solid.mass / 5 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        assert np.allclose(np.diag(mesh.moment_inertia), ellipsoid, rtol=1e-9), \
            "the drawn box and the modelled ellipsoid differ in inertia"
    sides = sorted(box_sides(boxes[0]) * 1e3)
    assert sides == pytest.approx([33.5, 44.0, 58.5], abs=0.01), "S2 is an XM540-W270: 33.5 x 58.5 x 44 mm"


def test_a_body_drawn_is_where_its_mass_is():
    """Placed in its body's frame, each one-solid body's mesh has its centroid at the body's centre
    of mass (the dynamics'), to 1 mm."""
    model = servodyn.load_model("human_arm")
    for body in model.bodies:
        (solid,) = body.solids
        mesh = trimesh.Trimesh(*solid_mesh(solid, segments=96), process=False)
        assert np.allclose(mesh.center_mass, body.com, atol=1e-3), \
            f"{body.name}: mesh centroid {mesh.center_mass} against com {body.com}"


@pytest.mark.parametrize("name", ["human15", "replica", "replica_dm"])
def test_urdf_export_carries_the_solids_as_visuals(tmp_path, name):
    """The export's links carry one visual per solid; yourdfpy loads it with its meshes, and the
    visuals' bounding box at q = 0 is the one of the servodyn meshes placed by forward kinematics."""
    import yourdfpy
    model = servodyn.load_model(name)
    path = tmp_path / f"{name}.urdf"
    model.to_urdf(path)
    urdf = yourdfpy.URDF.load(str(path), load_meshes=True, build_collision_scene_graph=False)
    links = {link.name: link for link in urdf.robot.links}
    for body in model.bodies:
        assert len(links[body.name].visuals) == len(body.solids), f"{body.name}: one visual per solid"
    bounds = urdf.scene.bounds
    R, p = model.user_poses(model.neutral_q())
    points = np.vstack([p[i] + solid_mesh(s, segments=96)[0] @ R[i].T
                        for i, b in enumerate(model.bodies) for s in b.solids])
    assert np.allclose(bounds, [points.min(axis=0), points.max(axis=0)], atol=2e-3), \
        f"the URDF's visuals span {bounds}, servodyn's solids {points.min(axis=0)}..{points.max(axis=0)}"


def test_subject_is_a_configuration_or_a_model():
    config, model = load_subject("replica")
    assert config is not None and config.name == "replica", "'replica' names the configuration first"
    config, model = load_subject("human15")
    assert config is None and model.name == "human15"
    with pytest.raises(ViewError, match="nothing: no such file, and not a built-in configuration"):
        load_subject("nothing")


@pytest.fixture(scope="module")
def viewer():
    v = open_view("replica", http_port=0, say=quiet)
    yield v
    v.close()


def test_the_drawn_pose_is_the_forward_kinematics(viewer):
    """Every body's scene frame sits where the model's forward kinematics puts it."""
    tl = viewer.timeline
    viewer.seek(1.0)
    k = tl.index(1.0)
    R, p = viewer.model.user_poses(tl.planned[k])
    for frame, Ri, pi in zip(viewer.arm.frames, R, p):
        assert np.allclose(frame.position, pi, atol=1e-9), "body origin drawn off its forward kinematics"
        w, x, y, z = frame.wxyz
        from servodyn.model.rotations import quat_to_matrix
        assert np.allclose(quat_to_matrix([x, y, z, w]), Ri, atol=1e-9), "body drawn turned"
    assert "r_shoulder_flexion" in viewer.readout.content and f"t = {tl.t[k]:.3f} s" in viewer.readout.content


def test_play_advances_the_cursor_and_the_plots_follow(viewer):
    """Playing moves the time cursor (polled: no rate is asserted); the plots' window holds it."""
    viewer.seek(0.0)
    viewer.player["playing"].value = True
    try:
        wait_until(lambda: viewer.cursor_t != 0.0, timeout=30)
    finally:
        viewer.player["playing"].value = False
    with viewer.lock:            # the player's thread moves cursor, slider and plots under this lock
        t = viewer.cursor_t
        slider = viewer.player["time"].value
        ranges = [handle.scales["x"]["range"] for handle in viewer.plots.values()]
    assert t > 0.0, "the player did not move the cursor"
    assert slider == pytest.approx(t), "the time slider follows the cursor"
    for lo, hi in ranges:
        assert lo <= t <= hi, f"the plot shows {lo:.2f}..{hi:.2f} s, the cursor is at {t:.2f} s"


def test_shaping_a_keyframe_recomputes_torques_and_verdict(viewer, tmp_path):
    """One keyframe's elbow angle changed: the editor's torque profile is the RNEA of the edited
    motion (computed here independently), the verdict comes from the validator; a keyframe moved
    past its neighbour is refused and changes nothing; the saved file loads back."""
    ed = viewer.editor
    model = viewer.model
    before = ed.motion
    k = 5
    q_k = before.q[k].copy()
    q_k[model.dof_names.index("r_elbow_flexion")] += math.radians(20)
    assert ed.set_keyframe(k, before.t[k], q_k), ed.verdict.content
    traj = ed.motion.sample(1e-3, ed.time_scale)
    peak = np.abs(model.inverse_dynamics(traj.q, traj.qd, traj.qdd)).max(axis=0)
    assert np.allclose(np.abs(viewer.timeline.tau).max(axis=0), peak, rtol=1e-9, atol=1e-9), \
        "the page's torque profile is not the edited motion's inverse dynamics"
    assert ", ".join(f"{p:.3f}" for p in peak) in ed.verdict.content, "the readout shows the new peaks"
    assert "PASS" in ed.verdict.content, ed.verdict.content
    # the same edit at time scale 1 (the forehand at human speed) is more than the servos can do
    fast = ed.time_scale
    ed.time_scale = 1.0
    ed.update()
    assert "FAIL" in ed.verdict.content and "r_shoulder" in ed.verdict.content, ed.verdict.content
    ed.time_scale = fast
    edited = ed.motion
    assert not ed.set_keyframe(k, before.t[k + 1] + 0.01, q_k), "a keyframe past the next one is refused"
    assert "refused" in ed.verdict.content and ed.motion is edited, "the refused edit changed nothing"
    ed.save_to = tmp_path / "edited.toml"
    again = load_motion(ed.save(), model)
    assert np.array_equal(again.q, edited.q) and np.array_equal(again.t, edited.t), "saved keyframes read back"


@pytest.mark.slow
def test_a_logged_run_plays_planned_against_measured(tmp_path):
    """A short motion on the loopback configuration (the model alone behind the HAL) with the live
    feed as the loop's observer: the feed saw every tick, drew frames, and the run's log replays with
    the tracking error between the ghost (planned) and the solid arm (measured)."""
    from servodyn.hal.config import CONFIGS_DIR
    from runs import run_swing
    config = tmp_path / "replica_loopback.toml"
    config.write_text((CONFIGS_DIR / "replica.toml").read_text().replace('kind = "dynamixel"', 'kind = "loopback"')
                      .replace("baud = 4000000", "baud = 1000000"))
    cfg, model = load_subject(str(config))
    motion = tmp_path / "reach.toml"
    motion.write_text('name = "reach"\n' + "".join(
        f"[[keyframe]]\nt = {t}\nq = {{ " + ", ".join(f"{n} = {a}" for n, a in zip(model.dof_names, q)) + " }\n"
        for t, q in ((0.0, [0.3, 0.2, 0, 0.5, 0, 0, 0]), (0.3, [0.5, 0.3, 0.1, 0.9, 0.1, 0, 0]))))
    v = Viewer(cfg, model, http_port=0, say=quiet)
    try:
        feed = v.live()
        summary = run_swing(str(config), out=tmp_path / "run", motion=str(motion), observer=feed.observe, say=quiet)
        assert summary["completed"], summary.get("error")
        wait_until(lambda: feed.frames > 0, timeout=30)
        feed.stop()
        homing = 2001
        assert feed.ticks == homing + summary["ticks"], "the observer saw every tick, homing and motion"
        assert feed.frames >= 1, "the live view drew the arm"
        v.close()
        v = open_view(str(config), log=str(tmp_path / "run"), http_port=0, say=quiet)
        tl = v.timeline
        assert len(tl.t) == summary["ticks"] and tl.measured is not None
        error = np.abs(tl.planned - tl.measured).max()
        assert error == pytest.approx(summary["tracking_max_rad"], rel=1e-6), \
            "the replayed tracking error is the run's"
        assert v.ghost.frames[0].visible, "the planned arm is shown as a ghost beside the measured one"
        assert "error °" in v.readout.content
    finally:
        v.close()


def test_bad_log_and_share_colours(tmp_path):
    _, model = load_subject("replica")
    (tmp_path / "swing_log.csv").write_text("t,q_a\n0,1\n")
    with pytest.raises(ViewError, match="not a swing log of model 'replica'"):
        log_timeline(model, None, tmp_path)
    assert share_rgb(0.0)[1] > share_rgb(0.0)[0], "no load is green"
    assert share_rgb(1.5) == share_rgb(1.0) and share_rgb(1.0)[0] == 255 and share_rgb(1.0)[1] < 100, \
        "at and past the limit is red"


@pytest.mark.parametrize("args, message", [
    (["nothing"], "nothing: no such file, and not a built-in configuration"),
    (["--http-port", "99999"], "argument --http-port: must be from 0 to 65535"),
    (["--host", "192.0.2.1"], "cannot serve on 192.0.2.1:8080"),
    (["--time-scale", "0"], "argument --time-scale: must be a positive number"),
    (["--motion", "LOG"], "unknown column 'q_x'"),
    (["--log", "LOG"], "not a swing log of model 'replica'"),
])
def test_view_command_bad_input_is_one_line(tmp_path, args, message):
    """Bad input is one line and exit 2, before anything is served (viser itself would fail inside
    its own thread on an address it cannot bind)."""
    log = tmp_path / "swing_log.csv"
    log.write_text("t,q_x\n0,1\n")
    args = [str(log) if a == "LOG" else a for a in args]
    res = run_cli("view", *args)
    assert res.returncode == 2, f"exit {res.returncode}: {res.stderr}"
    assert res.stderr.count("\n") == 1 and message in res.stderr, res.stderr


def test_a_trajectory_csv_plays_with_its_torques(tmp_path):
    """A trajectory CSV is played (not edited): its torques are the RNEA of the validator's
    sampling of it, and its share of the servos' limits the validator's torque-speed ratio."""
    from servodyn.control.motion import motion_path
    from servodyn.validation import Limits, check
    config, model = load_subject("replica")
    csv = tmp_path / "reach.csv"
    rows = [f"{t},{0.5 * t},{0.2 * t},0,{0.3 + 0.4 * t},0,0,0" for t in (0.0, 0.5, 1.0)]
    csv.write_text("t," + ",".join(f"q_{n}" for n in model.dof_names) + "\n" + "\n".join(rows) + "\n")
    v = open_view("replica", motion=str(csv), http_port=0, say=quiet)
    try:
        assert v.editor is None, "a CSV has no keyframes to shape"
        result = check(model, Limits.of(config, config.supply.voltage), motion_path(str(csv), model).at_scale(1.0))
        assert np.array_equal(v.timeline.tau, result.tau) and np.array_equal(v.timeline.share, result.ratios["torque_speed"])
    finally:
        v.close()


def test_dragging_the_hand_solves_ik_and_the_verdict_follows(viewer):
    """Drag events on the hand's gizmo (as viser delivers them): each is one IK solve from the
    keyframe's pose, the keyframe's hand lands on the gizmo (1e-9 m), the torques shown are the
    edited motion's; the swivel slider turns the elbow with the hand held; a target out of reach
    is refused on the verdict line and changes nothing; the drag's end puts the gizmo back on the hand."""
    from types import SimpleNamespace
    ed = viewer.editor
    hand = ed.hand
    ed.key.value = 3
    q0 = ed.motion.q[ed.k].copy()
    _, p0 = hand.arm.hand(q0)
    hand._on_drag(SimpleNamespace(phase="start"))
    for step in range(1, 6):
        hand.gizmo.position = tuple(p0 + step * np.array([0.004, -0.002, 0.003]))
        hand._on_drag(SimpleNamespace(phase="update"))
        _, p = hand.arm.hand(ed.motion.q[ed.k])
        assert np.abs(p - hand.gizmo.position).max() < 1e-9, "the keyframe's hand is on the gizmo"
    hand._on_drag(SimpleNamespace(phase="end"))
    q1 = ed.motion.q[ed.k].copy()
    assert np.degrees(np.abs(q1 - q0)).max() > 0.5, "the drag moved the keyframe"
    assert np.array_equal(q1[4:], q0[4:]), "without 'Turn the hand too' the wrist keeps its angles"
    traj = ed.motion.sample(1e-3, ed.time_scale)
    peak = np.abs(viewer.model.inverse_dynamics(traj.q, traj.qd, traj.qdd)).max(axis=0)
    assert ", ".join(f"{v:.3f}" for v in peak) in ed.verdict.content, "the readout is the dragged motion's"
    assert "reach 0." in hand.reach.content, hand.reach.content
    # the swivel slider: the elbow turns about the shoulder-wrist line, the hand stays
    hand.swivel.value = round(math.degrees(hand.arm.swivel_of(q1[hand.arm.q_index])) + 10.0, 1)
    assert hand.solve_to(*hand._hand(), swivel=True), ed.verdict.content
    q2 = ed.motion.q[ed.k]
    assert hand.arm.swivel_of(q2[hand.arm.q_index]) == pytest.approx(math.radians(hand.swivel.value), abs=1e-9)
    assert np.abs(hand.arm.hand(q2)[1] - hand.arm.hand(q1)[1]).max() < 1e-9, "the hand held"
    # out of reach: refused, nothing changed, and the gizmo back on the hand at the drag's end
    edits = ed.edits
    hand.gizmo.position = (0.0, -1.0, 0.0)
    hand._on_drag(SimpleNamespace(phase="update"))
    assert "refused" in ed.verdict.content and "out of reach" in ed.verdict.content, ed.verdict.content
    assert ed.edits == edits, "a refused drag changes no keyframe"
    hand._on_drag(SimpleNamespace(phase="end"))
    assert np.abs(np.asarray(hand.gizmo.position) - hand.arm.hand(ed.motion.q[ed.k])[1]).max() < 1e-9


def test_a_drag_delivered_in_a_burst_is_handled_in_order_and_the_gizmo_follows_the_next_keyframe(viewer):
    """Drag events queued as viser's loop receives them — a start, 40 updates faster than IK, an
    end — are handled in that order by the one worker: the last update is solved (the hand ends on
    the last target to 1e-9 m), not every one; the drag has ended (a start handled after its end, as
    viser's thread pool could do, left the gizmo deaf to the keyframes); and selecting another
    keyframe then moves the gizmo to its hand."""
    import asyncio
    from types import SimpleNamespace
    ed = viewer.editor
    hand = ed.hand
    ed.key.value = 2
    q0 = ed.motion.q[ed.k].copy()
    _, p0 = hand.arm.hand(q0)
    solves = hand.solves
    asyncio.run(hand._receive(SimpleNamespace(phase="start")))
    for step in range(1, 41):
        hand.gizmo.position = tuple(p0 + step * np.array([0.0005, -0.00025, 0.0004]))
        asyncio.run(hand._receive(SimpleNamespace(phase="update")))
    last = np.asarray(hand.gizmo.position, dtype=float)
    asyncio.run(hand._receive(SimpleNamespace(phase="end")))
    wait_until(lambda: not (hand._events or hand.dragging or hand.solves == solves), timeout=30, every=0.01)
    assert not hand._events and not hand.dragging, "the worker handled the drag through its end"
    assert 1 <= hand.solves - solves <= 40, hand.solves - solves
    _, p = hand.arm.hand(ed.motion.q[ed.k])
    assert np.abs(p - last).max() < 1e-9, "the keyframe's hand is on the last target"
    ed.key.value = 4
    _, p4 = hand.arm.hand(ed.motion.q[3])
    wait_until(lambda: np.abs(np.asarray(hand.gizmo.position) - p4).max() <= 1e-9, timeout=10, every=0.01)
    assert np.abs(np.asarray(hand.gizmo.position) - p4).max() < 1e-9, "the gizmo moved to keyframe 4's hand"


def test_swing_view_waits_for_a_browser_before_the_swing(tmp_path):
    """`swing --view`'s page (tools.view.live_viewer) returns only once a browser has the page drawn:
    a lock-step swing is over in seconds, before a page opened later could draw. The URL is said
    first (on stderr in the command); then a client as the page's script is to viser (its websocket,
    and the camera it reports once it has drawn the scene) ends the wait within the deadline."""
    import threading
    import msgspec
    import viser
    from viser._messages import ViewerCameraMessage
    from websockets.sync.client import connect
    from servodyn.tools.view import live_viewer
    said, result = [], []
    waiting = threading.Thread(target=lambda: result.append(live_viewer("replica", port=0,
                                                                        say=lambda *a, **k: said.append(a[0]))))
    waiting.start()
    deadline = time.monotonic() + 60
    while not said and time.monotonic() < deadline:
        time.sleep(0.05)
    assert said and "http://127.0.0.1:" in said[0] and "Ctrl-C" in said[0], said
    url = said[0].split("open ", 1)[1].split(" ", 1)[0]
    time.sleep(0.5)
    assert not result, "it returned before any browser had the page"
    camera = ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=(1.0, 0.0, 0.0), fov=1.0, near=0.01, far=100.0,
                                 image_height=600, image_width=800, look_at=(0.0, 0.0, 0.0), up_direction=(0.0, 0.0, 1.0))
    with connect(url.replace("http://", "ws://"), subprotocols=[f"viser-v{viser.__version__}"],
                 open_timeout=30, max_size=None) as page:
        time.sleep(0.5)
        assert not result, "a page that has not drawn yet does not end the wait"
        page.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
        waiting.join(timeout=30)
        assert result, "a browser has the page, and the wait did not end"
    viewer, feed = result[0]
    try:
        assert viewer.title == "servodyn — replica", viewer.title
        assert feed.ticks == 0, "no tick before the swing"
    finally:
        viewer.close()


def test_a_source_clip_whose_frame_time_would_fill_the_memory_is_one_line(tmp_path):
    """view --source CLIP.bvh with `Frame Time: 1e-9`: the overlay would resample the clip at 1 GHz
    on the motion's clock (tens of GiB for a 2 s motion); it is refused in one line, exit 2, before
    anything is sampled or served."""
    import subprocess
    import sys
    _, model = load_subject("replica")
    csv = tmp_path / "reach.csv"
    csv.write_text("t," + ",".join(f"q_{n}" for n in model.dof_names) + "\n"
                   + "".join(f"{t},0,0,0,{0.3 + 0.2 * t},0,0,0\n" for t in (0.0, 1.0, 2.0)))
    clip = tmp_path / "clip.bvh"
    clip.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation "
                    "Xrotation Yrotation\n  End Site\n  {\n    OFFSET 0 1 0\n  }\n}\nMOTION\nFrames: 2\n"
                    "Frame Time: 1e-9\n0 0 0 0 0 0\n0 0 0 0 0 0\n")
    with pytest.raises(ViewError, match="Frame Time:? 1e-09 s"):
        open_view("replica", motion=str(csv), source=str(clip), http_port=0, say=quiet)
    res = subprocess.run([sys.executable, "-m", "servodyn.tools.cli", "view", "--motion", str(csv), "--source",
                          str(clip), "--port", "0"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, f"exit {res.returncode}: {res.stderr}"
    assert res.stderr.count("\n") == 1 and "Frame Time" in res.stderr, res.stderr


def test_the_so101_view_plays_its_own_motion():
    """`servodyn view --config so101` with no --motion plays the configuration's motion, its pick
    (6 s at its 2.5 ms period: 2401 samples), not the forehand its model lacks the dofs for."""
    v = open_view("so101", http_port=0, say=quiet)
    try:
        assert v.model.name == "so101" and len(v.timeline.t) == 2401 and v.timeline.t[-1] == pytest.approx(6.0)
    finally:
        v.close()
