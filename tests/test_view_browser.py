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
from servodyn.tools.view import open_view

CANVAS_RIGHT = 780       # px: the GUI panel covers the page right of about here


@pytest.fixture(scope="module")
def page():
    viewer = open_view("replica", port=0, say=lambda *a, **k: None)
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
    viewer = open_view("replica_can", port=0, say=lambda *a, **k: None)
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

