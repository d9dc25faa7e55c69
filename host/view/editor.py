"""Shaping a keyframe motion on the page: `MotionEditor` puts the keyframes in the page's controls
(the angle of each dof, the keyframe's time); every edit re-samples the motion, recomputes its
torques in one batched RNEA and asks the validator again, and the arm, the plots and the verdict
follow. The hand's gizmo (gizmo.py) edits the same keyframe by inverse kinematics."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..control.motion import Motion, check_limits, save_motion
from ..control.timing import SMALL_TIME_STEP
from ..control.trajectory import TrajectoryError
from ..validation import describe, violations
from .gizmo import HandGizmo
from .timeline import motion_timeline

if TYPE_CHECKING:
    from .app import Viewer


class MotionEditor:
    """The keyframes of a motion in the page's controls; every edit re-samples the motion,
    recomputes its torques in one batched RNEA and asks the validator again."""

    def __init__(self, viewer: Viewer, motion: Motion, time_scale: float, save_to: Path):
        self.viewer, self.motion, self.time_scale, self.save_to = viewer, motion, time_scale, Path(save_to)
        self.model = viewer.model
        self.result = None
        self.edits = 0
        gui = viewer.server.gui
        names = self.model.dof_names
        with gui.add_folder("Shape the motion", order=10):
            self.verdict = gui.add_markdown("")
            self.key = gui.add_slider("Keyframe", min=1, max=len(motion.t), step=1, initial_value=1)
            self.key_time = gui.add_number("Keyframe time (s)", float(motion.t[0]), step=0.01)
            self.angles = []
            for j, name in enumerate(names):
                lo, hi = self.model.lower[j], self.model.upper[j]
                lo = math.degrees(lo) if math.isfinite(lo) else -180.0
                hi = math.degrees(hi) if math.isfinite(hi) else 180.0
                self.angles.append(gui.add_number(f"{name} (°)", round(math.degrees(motion.q[0, j]), 3),
                                                  min=round(lo, 3), max=round(hi, 3), step=0.1))
            self.save_button = gui.add_button("Save keyframes")
            self.saved = gui.add_markdown(f"saves to `{self.save_to}`")
        self.hand = HandGizmo(self) if HandGizmo.fits(self.model) else None
        self._loading = False
        self.key.on_update(lambda _: self._load_keyframe())
        self.key_time.on_update(lambda _: self._changed())
        for handle in self.angles:
            handle.on_update(lambda _: self._changed())
        self.save_button.on_click(lambda _: self.save())
        self._load_keyframe()
        self.update()

    @property
    def k(self) -> int:
        return int(self.key.value) - 1

    def _load_keyframe(self) -> None:
        with self.viewer.lock:
            self._loading = True
            try:
                self.key_time.value = float(self.motion.t[self.k])
                for j, handle in enumerate(self.angles):
                    handle.value = round(math.degrees(self.motion.q[self.k, j]), 3)
            finally:
                self._loading = False
            self._show_keyframe()

    def _show_keyframe(self) -> None:
        v = self.viewer
        if v.timeline is not None:
            v.seek((self.motion.t[self.k] - self.motion.t[0]) * self.time_scale)
        if getattr(self, "hand", None) is not None:
            self.hand.follow_keyframe()

    def _changed(self) -> None:
        # viser runs these handlers in a thread pool: one edit at a time, whole, under the
        # viewer's lock (the hand's worker and the player take it too)
        with self.viewer.lock:
            if self._loading:
                return
            t = self.motion.t.copy()
            q = self.motion.q.copy()
            t[self.k] = float(self.key_time.value)
            q[self.k] = np.radians([float(h.value) for h in self.angles])
            self.set_keyframe(self.k, t[self.k], q[self.k])

    def show_angles(self) -> None:
        """The number fields to keyframe k's angles (without counting it as an edit)."""
        self._loading = True
        try:
            for j, handle in enumerate(self.angles):
                handle.value = round(math.degrees(self.motion.q[self.k, j]), 3)
        finally:
            self._loading = False

    def refuse(self, reason: str) -> None:
        """A refusal on the page, where the editor's refusals go: the verdict line."""
        self.verdict.content = f"**refused**: {reason}"

    def set_keyframe(self, k: int, t_k: float, q_k) -> bool:
        """Replace keyframe k; False (and the reason on the page) if the motion it makes is refused."""
        t = self.motion.t.copy()
        q = self.motion.q.copy()
        t[k], q[k] = t_k, q_k
        try:
            if np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
                raise TrajectoryError(f"keyframe {k + 1}: its time must lie between its neighbours' "
                                      f"({t[k - 1] if k else -math.inf:g} s and "
                                      f"{t[k + 1] if k + 1 < len(t) else math.inf:g} s)")
            motion = replace(self.motion, t=t, q=q)
        except (TrajectoryError, ValueError) as err:
            self.refuse(str(err))
            return False
        self.motion = motion
        self.edits += 1
        self.update()
        return True

    def update(self) -> None:
        """Sample, RNEA (one batched call), validate; redraw."""
        v = self.viewer
        try:
            timeline, result, limits = motion_timeline(self.model, v.config, self.motion, self.time_scale)
        except (TrajectoryError, ValueError, FloatingPointError) as err:
            self.verdict.content = f"**refused**: {err}"
            return
        self.result = result
        peak = np.abs(timeline.tau).max(axis=0)
        worst = int(np.argmax(peak))
        text = (f"edits: {self.edits}; peak torque {peak[worst]:.3f} N·m "
                f"({self.model.dof_names[worst]}); torques: "
                + ", ".join(f"{p:.3f}" for p in peak) + " N·m")
        if result is None:
            try:
                check_limits(self.motion.sample(SMALL_TIME_STEP, self.time_scale), self.model, self.motion.name)
                verdict = "within the joint limits (no configuration: no servo limits to validate against)"
            except TrajectoryError as err:
                verdict = f"**FAIL**: {err}"
        elif result.passed:
            verdict = "**PASS**: every joint within every servo limit"
        else:
            found = violations(result, self.model.dof_names)
            verdict = f"**FAIL** ({len(found)}): {describe(found[0], v.config, limits, 1, 1.0)}"
        self.verdict.content = f"{verdict}  \n{text}"
        v.show_timeline(timeline, f"{self.motion.name}, time scale {self.time_scale:g}")
        self._show_keyframe()

    def save(self) -> Path:
        self.save_to.parent.mkdir(parents=True, exist_ok=True)
        save_motion(self.motion, self.save_to)
        self.saved.content = f"saved `{self.save_to}` ({len(self.motion.t)} keyframes)"
        return self.save_to
