"""The hand of the selected keyframe as a transform gizmo (`HandGizmo`): a drag is inverse
kinematics from the keyframe's pose, the keyframe set to the result through the editor. viser's
drag events are queued in order on its event loop and handled by one worker thread; the keyframe
is changed under the viewer's lock, as typed edits are."""

from __future__ import annotations

import collections
import math
import threading
import time
from typing import TYPE_CHECKING

import numpy as np

from ..model import ik
from ..model.rotations import matrix_to_quat, quat_to_matrix

if TYPE_CHECKING:
    from .editor import MotionEditor

GIZMO_SCALE = 0.3          # of the arm's length: the hand's transform gizmo


class HandGizmo:
    """The hand of the selected keyframe as a transform gizmo: a drag event is one inverse
    kinematics solve from the keyframe's pose (its branch and elbow swivel carried on), the
    keyframe set to the result (the arm, torques and verdict follow, as for a typed angle), and the
    angle fields shown. Events that arrive while one is being handled are coalesced: the latest
    target is handled next, none is queued behind a slow one. A swivel slider turns the elbow about
    the shoulder-wrist line with the hand held; the reach and each refusal ("out of reach", "no
    swivel inside the limits") are shown on the page. The hand's orientation is followed when
    "Turn the hand too" is ticked; otherwise the wrist keeps its angles."""

    @staticmethod
    def fits(model) -> bool:
        try:
            ik.Arm.of(model)
        except ik.IkError:
            return False
        return model.nq == model.nv

    def __init__(self, editor: MotionEditor):
        self.editor = editor
        self.model = editor.model
        self.arm = ik.Arm.of(self.model)
        self.events = 0              # drag events received
        self.solves = 0              # inverse kinematics solves done (coalesced events are skipped)
        self.refusals = 0
        self.arm_s = []              # s per handled event from its arrival to the arm redrawn (IK, pose)
        self.handler_s = []          # s per handled event in all: IK, arm, keyframe, torques, verdict
        # viser runs a plain callback in a thread pool, where a drag's "start", "update"s and "end"
        # can be handled out of order (an "end" before its "start" left the gizmo deaf to the
        # keyframes); the events are queued in order on viser's loop and handled by one worker
        self._events: collections.deque = collections.deque()
        self._wake = threading.Condition()
        self._placing = False
        self.dragging = False
        server, gui = editor.viewer.server, editor.viewer.server.gui
        _, p = self.model.user_poses(self.model.neutral_q())
        size = GIZMO_SCALE * max(0.2, float(np.linalg.norm(p - p[0], axis=1).max()))
        self.gizmo = server.scene.add_transform_controls("/hand_target", scale=size, depth_test=False,
                                                         line_width=3.0)
        with gui.add_folder("Drag the hand", order=11):
            self.reach = gui.add_markdown("")
            self.turn = gui.add_checkbox("Turn the hand too", False)
            self.swivel = gui.add_slider("Elbow swivel (°)", min=-180.0, max=180.0, step=0.5, initial_value=0.0,
                                         disabled=self.arm.srs is None)
        self.gizmo.on_update(self._receive)
        worker = threading.Thread(target=self._work, name="servodyn-view-hand", daemon=True)
        worker.start()
        editor.viewer._threads.append(worker)
        self.swivel.on_update(lambda _: None if self._placing else self.solve_to(*self._hand(), swivel=True))

    def _hand(self):
        """The gizmo's pose: (position, rotation)."""
        w, x, y, z = self.gizmo.wxyz
        return np.asarray(self.gizmo.position, dtype=float), quat_to_matrix([x, y, z, w])

    def follow_keyframe(self) -> None:
        """Put the gizmo (and the swivel slider) on the selected keyframe's hand."""
        q = self.editor.motion.q[self.editor.k]
        R, p = self.arm.hand(q)
        x, y, z, w = matrix_to_quat(R)
        self._placing = True
        try:
            if not self.dragging:             # never pull the gizmo from under the pointer
                self.gizmo.position = tuple(p)
                self.gizmo.wxyz = (w, x, y, z)
            if self.arm.srs is not None:
                self.swivel.value = round(math.degrees(self.arm.swivel_of(q[self.arm.q_index])), 1)
        finally:
            self._placing = False
        self._show_reach(float(np.linalg.norm(p - self.arm.srs.S if self.arm.srs else p - self.arm.point[0])))

    def _show_reach(self, distance: float, note: str = "") -> None:
        far = self.arm.max_reach()
        self.reach.content = f"reach {distance / far:.2f} ({distance:.3f} m of {far:.3f} m){note}"

    async def _receive(self, event) -> None:
        """On viser's event loop, in the order the page sent them: the event and the gizmo's pose
        at that moment, queued for the worker (nothing awaited, nothing slow here)."""
        self.events += 1
        with self._wake:
            self._events.append((event.phase, self._hand()))
            self._wake.notify()

    def _work(self) -> None:
        """The worker: the queued events in order; of a run of updates only the latest is solved
        (a slow solve never falls behind the pointer)."""
        stop = self.editor.viewer._stop
        while not stop.is_set():
            with self._wake:
                if not self._events:
                    self._wake.wait(timeout=0.25)
                    continue
                phase, pose = self._events.popleft()
                while phase == "update" and self._events and self._events[0][0] == "update":
                    phase, pose = self._events.popleft()
            self._handle(phase, pose)

    def _on_drag(self, event) -> None:
        """One drag event handled at once, with the gizmo's present pose."""
        self.events += 1
        self._handle(event.phase, self._hand())

    def _handle(self, phase: str, pose) -> None:
        if phase == "start":
            self.dragging = True
        elif phase == "end":
            with self.editor.viewer.lock:
                self.dragging = False
                self.follow_keyframe()        # a refused target snaps back to the hand
        else:
            self.solve_to(*pose)

    def solve_to(self, position, rotation, swivel: bool = False) -> bool:
        """Keyframe k's hand to `position` (and `rotation` with "Turn the hand too"); False and the
        refusal on the page if inverse kinematics or the editor refuses it."""
        start = time.perf_counter()
        ed = self.editor
        k = ed.k
        q_prev = ed.motion.q[k]
        phi = math.radians(float(self.swivel.value)) if swivel and self.arm.srs is not None else None
        try:
            with ed.viewer.lock:
                result = ik.solve(self.model, position, rotation if self.turn.value else None, q_prev=q_prev,
                                  swivel=phi)
        except ik.IkError as err:
            self.refusals += 1
            ed.refuse(str(err))
            self._show_reach(float(np.linalg.norm(np.asarray(position) - (self.arm.srs.S if self.arm.srs else
                                                                          self.arm.point[0]))), " — refused")
            return False
        self.solves += 1
        with ed.viewer.lock:
            ed.viewer.arm.pose(result.q)      # the arm first: the verdict below takes longer
            self.arm_s.append(time.perf_counter() - start)
            # the keyframe, its torques and verdict; the swivel slider and the reach follow the
            # keyframe there (follow_keyframe)
            ok = ed.set_keyframe(k, float(ed.motion.t[k]), result.q)
            if ok:
                ed.show_angles()
        self.handler_s.append(time.perf_counter() - start)
        return ok
