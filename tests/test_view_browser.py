"""`servodyn view` in a real browser: Debian's chromium, headless, with software WebGL
(SwiftShader), driven through the Chrome DevTools protocol (a websocket; `websockets`, which viser
itself uses, is the client).

The page loads from an in-process viser server; the test reads the page's text (the model reported
loaded), takes screenshots and compares the arm shown with the arm hidden (pixels that differ from
the background where the arm stands), and types a new angle into one keyframe's number field the
way a person would (focus, select, type, Enter): the torque readout the page shows changes to the
torques of the edited motion.

No timing is asserted: every wait polls until its condition holds, with a generous deadline."""

from __future__ import annotations

import numpy as np
import pytest

from browser import SCREEN, Browser, settle, wait_for
from servodyn.view import open_view

from helpers import quiet

pytestmark = pytest.mark.slow      # a headless browser

CANVAS_RIGHT = 780       # px: the GUI panel covers the page right of about here


@pytest.fixture(scope="module")
def page():
    viewer = open_view("replica", http_port=0, say=quiet)
    try:
        with Browser() as browser:
            browser.open(viewer.url)
            yield viewer, browser
    finally:
        viewer.close()


def _arm_pixels(browser, viewer) -> tuple[np.ndarray, np.ndarray]:
    """(screenshot with the arm, mask of the scene's pixels that change when it is hidden); each
    screenshot is taken once the page has stopped changing."""
    def differs():
        shown = settle(browser)
        viewer.arm.show(False)
        try:
            wait_for(lambda: not np.array_equal(browser.screenshot(), shown), "the page to redraw without the arm",
                     deadline=20)
            hidden = settle(browser)
        except AssertionError:
            return None
        finally:
            viewer.arm.show(True)
        mask = np.abs(shown - hidden).max(axis=2) > 24
        mask[:, CANVAS_RIGHT:] = False
        return (shown, mask) if mask.sum() > 500 else None
    return wait_for(differs, "the arm to be drawn", every=1.0)


def test_a_can_arm_is_drawn_from_its_own_solids():
    """replica_can's page: its model replica_dm (round Damiao housings), 2.51 kg, the validator's
    verdict at the configuration's own 2.5 ms period (a 1 ms sample fails its bus check), and the
    arm drawn in the middle of the canvas. First in the file, so that its browser is closed before
    the shared page's opens."""
    viewer = open_view("replica_can", http_port=0, say=quiet)
    try:
        with Browser() as browser:
            browser.open(viewer.url)
            text = wait_for(lambda: (lambda t: t if "loaded: 7 bodies, 7 dofs" in t else None)(browser.text()),
                            "the page to report the model loaded")
            assert "model 'replica_dm' loaded" in text and "2.51 kg" in text, text[:500]
            assert "PASS: every joint within every servo limit" in text, f"the verdict at 2.5 ms: {text[:800]}"
            _, mask = _arm_pixels(browser, viewer)
            ys, xs = np.nonzero(mask)
            assert len(xs) > 500 and 150 < xs.mean() < CANVAS_RIGHT - 50, \
                f"{len(xs)} pixels of arm centred at x = {xs.mean() if len(xs) else 0:.0f}"
    finally:
        viewer.close()


def test_page_reports_the_model_and_draws_the_arm(page, tmp_path):
    viewer, browser = page
    text = wait_for(lambda: (lambda t: t if "loaded: 7 bodies, 7 dofs" in t else None)(browser.text()),
                    "the page to report the model loaded")
    assert "model 'replica' loaded" in text and "PASS" in text, text[:500]
    title = wait_for(lambda: (lambda t: t if t != "Viser" else None)(browser.eval("document.title")),
                     "the page's title to be servodyn's")
    assert title == "servodyn — replica", f"the browser tab reads {title!r}"
    shown, mask = _arm_pixels(browser, viewer)
    ys, xs = np.nonzero(mask)
    assert len(xs) > 500, f"only {len(xs)} pixels differ where the arm stands"
    # the arm stands in the middle of the 3-D canvas, not in the panel or at the page's edge
    cx, cy = xs.mean(), ys.mean()
    assert 150 < cx < CANVAS_RIGHT - 50 and 100 < cy < SCREEN[1] - 100, f"the arm's pixels centre at ({cx:.0f}, {cy:.0f})"
    from PIL import Image
    Image.fromarray(shown.astype(np.uint8)).save(tmp_path / "view.png")


def test_typing_a_keyframe_angle_updates_the_torque_readout(page):
    """Keyframe 1's elbow angle is typed into its number field; the page's torque readout changes
    to the peaks of the edited motion's inverse dynamics."""
    viewer, browser = page
    ed = viewer.editor
    wait_for(lambda: "edits: 0" in browser.text(), "the shaping panel")
    before = browser.text()
    assert browser.type_into("r_elbow_flexion (°)", "40"), "no number field for the elbow's angle on the page"
    wait_for(lambda: ed.edits >= 1, "the edit to reach the server")
    assert ed.motion.q[0, viewer.model.dof_names.index("r_elbow_flexion")] == pytest.approx(np.radians(40), abs=1e-6), \
        "the typed angle became keyframe 1's elbow angle"
    traj = ed.motion.sample(1e-3, ed.time_scale)
    peak = np.abs(viewer.model.inverse_dynamics(traj.q, traj.qd, traj.qdd)).max(axis=0)
    readout = ", ".join(f"{p:.3f}" for p in peak)
    after = wait_for(lambda: (lambda t: t if readout in t else None)(browser.text()),
                     "the page to show the edited motion's torques")
    assert readout not in before and "edits: 1" in after, "the torque readout changed with the keyframe"



def _projector(browser, viewer):
    """World point → page pixel, from the camera the page reports to the server (OpenCV axes:
    x right, y down, z forward; a vertical field of view) and the canvas's place on the page."""
    import math
    from servodyn.model.rotations import quat_to_matrix
    client = wait_for(lambda: next(iter(viewer.server.get_clients().values()), None), "the page's client")
    cam = client.camera
    wait_for(lambda: cam.fov > 0, "the page's camera")
    left, top, width, height = browser.eval("(() => { const r = document.querySelector('canvas')"
                                            ".getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()")
    w, x, y, z = cam.wxyz
    R = quat_to_matrix([x, y, z, w])
    f = (height / 2) / math.tan(cam.fov / 2)

    def project(X):
        c = R.T @ (np.asarray(X, dtype=float) - cam.position)
        return np.array([left + width / 2 + f * c[0] / c[2], top + height / 2 + f * c[1] / c[2]])
    return project


def _drag_hand_outwards(browser, viewer, pixels: float):
    """Press on the gizmo's arrow that points farthest from the shoulder and drag it `pixels`
    along the arrow with the mouse, as a person would; returns the arrow's world direction."""
    import time
    from servodyn.model.rotations import quat_to_matrix
    hand = viewer.editor.hand
    settle(browser)              # the page has drawn the gizmo where the server put it
    project = _projector(browser, viewer)
    centre = np.asarray(hand.gizmo.position, dtype=float)
    w, x, y, z = hand.gizmo.wxyz
    axes = quat_to_matrix([x, y, z, w]).T                      # rows: the gizmo's x, y, z in the world
    outwards = axes[int(np.argmax(axes @ (centre - hand.arm.srs.S)))]
    grab = project(centre + 0.8 * hand.gizmo.scale * outwards)
    along = grab - project(centre)
    along /= np.linalg.norm(along)
    mouse = lambda kind, p, **kw: browser.call("Input.dispatchMouseEvent", type=kind, x=float(p[0]), y=float(p[1]),
                                               **kw)
    mouse("mouseMoved", grab)
    mouse("mousePressed", grab, button="left", buttons=1, clickCount=1)
    steps = max(int(pixels // 3), 1)
    for i in range(1, steps + 1):
        mouse("mouseMoved", grab + along * pixels * i / steps, button="left", buttons=1)
        time.sleep(0.03)
    mouse("mouseReleased", grab + along * pixels, button="left", buttons=0, clickCount=1)
    return outwards


def test_dragging_the_hand_gizmo_moves_the_keyframe_and_the_verdict(page):
    """The hand's transform gizmo of keyframe 4 dragged with the mouse along its outward arrow:
    inverse kinematics moves keyframe 4's angles (the page's fields show them), the hand follows
    the gizmo, and the page's torque readout becomes the edited motion's; dragged far past the
    arm's reach, the page shows the refusal and the keyframe stays inside the limits."""
    viewer, browser = page
    ed, hand = viewer.editor, viewer.editor.hand
    assert hand is not None, "the replica's editor has a hand gizmo"
    wait_for(lambda: "Drag the hand" in browser.text(), "the drag panel")
    ed.key.value = 4
    q_before = ed.motion.q[ed.k].copy()
    R, p = hand.arm.hand(q_before)
    assert np.abs(np.asarray(hand.gizmo.position) - p).max() < 1e-9, "the gizmo sits on keyframe 4's hand"
    solves = hand.solves
    outwards = _drag_hand_outwards(browser, viewer, 30)
    wait_for(lambda: hand.solves > solves and not hand.dragging, "the drag to reach the server and end")
    q_after = ed.motion.q[ed.k].copy()
    moved = np.degrees(np.abs(q_after - q_before)).max()
    assert moved > 1.0, f"keyframe 4's angles moved {moved:.2f}° at most"
    _, p_after = hand.arm.hand(q_after)
    assert (p_after - p) @ outwards > 0.005, "the hand went along the dragged arrow, more than 5 mm"
    assert np.abs(np.asarray(hand.gizmo.position) - p_after).max() < 1e-9, "the gizmo ends on the hand"
    j = int(np.argmax(np.abs(q_after - q_before)))
    label = f"{viewer.model.dof_names[j]} (°)"
    shown = wait_for(lambda: (lambda v: v if v is not None and abs(float(v) - np.degrees(q_after[j])) < 1e-3 else None)(
        browser.eval(f"(() => {{ const l = [...document.querySelectorAll('label')].find(x => x.innerText.trim() === "
                     f"'{label}'); const i = l && document.getElementById(l.htmlFor); return i ? i.value : null; }})()")),
        f"the page's {label} field to show the new angle")
    assert abs(float(shown) - np.degrees(q_after[j])) < 1e-3
    traj = ed.motion.sample(1e-3, ed.time_scale)
    peak = np.abs(viewer.model.inverse_dynamics(traj.q, traj.qd, traj.qdd)).max(axis=0)
    readout = ", ".join(f"{v:.3f}" for v in peak)
    wait_for(lambda: readout in browser.text(), "the page to show the dragged motion's torques")
    # far past the reach: refused on the page, the keyframe still inside the limits
    refusals = hand.refusals
    _drag_hand_outwards(browser, viewer, 400)
    wait_for(lambda: hand.refusals > refusals and not hand.dragging, "the refusal")
    wait_for(lambda: "refused: out of reach" in browser.text(), "the page to show the refusal")
    q_k = ed.motion.q[ed.k]
    assert np.all(q_k >= viewer.model.lower) and np.all(q_k <= viewer.model.upper), "in the limits"
