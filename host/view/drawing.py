"""The 3-D arm in viser's scene: `ArmDrawing` (the arm's solids, one scene frame per body, posed
by the model's forward kinematics, a torque-coloured ball at each joint) and `SourceOverlay` (the
captured arm a retargeted motion came from, as line segments)."""

from __future__ import annotations

import time

import numpy as np

from ..model.rotations import matrix_to_quat
from ..model.shapes import solid_mesh
from .timeline import share_rgb

SOLID_RGB = (178, 184, 196)
GHOST_RGB = (90, 160, 255)
GHOST_OPACITY = 0.35
SOURCE_RGB = (255, 140, 40)  # the captured arm of --source


class ArmDrawing:
    """The arm's solids in the scene under `root`, one scene frame per body, posed at q."""

    def __init__(self, server, model, root: str, rgb, opacity: float | None = None, markers: float = 0.0):
        """markers: the radius (m) of a ball at each joint coloured by its torque (0: none)."""
        self.model = model
        self.frames = []
        self.markers = {}
        scene = server.scene
        for body in model.bodies:
            frame = scene.add_frame(f"{root}/{body.name}", show_axes=False)
            self.frames.append(frame)
            for k, solid in enumerate(body.solids):
                vertices, faces = solid_mesh(solid)
                scene.add_mesh_simple(f"{root}/{body.name}/solid{k}", vertices.astype(np.float32), faces,
                                      color=rgb, opacity=opacity, cast_shadow=False, receive_shadow=False)
            if markers and body.dofs and self._joint_of(body) is body:
                self.markers[body.name] = scene.add_icosphere(f"{root}/{body.name}/torque", radius=markers,
                                                              color=share_rgb(0.0), opacity=0.6)
        # which velocity dofs each body's joint drives
        self.dof_slices, k = [], 0
        for body in model.bodies:
            n = 6 if body.free else 3 if body.ball else len(body.dofs)
            self.dof_slices.append(slice(k, k + n))
            k += n

    def _joint_of(self, body):
        """The first body of a chain that turns about one point (a replica's servos in series at
        the shoulder): one joint, one marker."""
        while body.parent >= 0 and np.linalg.norm(body.pos) < 1e-9 and self.model.bodies[body.parent].dofs:
            body = self.model.bodies[body.parent]
        return body

    def pose(self, q, yield_each: bool = False) -> None:
        """Pose every body at q. yield_each: let other threads run between two bodies (the live
        view's thread must not hold the interpreter for long: the control loop waits on it)."""
        R, p = self.model.user_poses(q)
        for frame, Ri, pi in zip(self.frames, R, p):
            x, y, z, w = matrix_to_quat(Ri)
            frame.wxyz = (w, x, y, z)
            frame.position = tuple(pi)
            if yield_each:
                time.sleep(0)

    def color_joints(self, share) -> None:
        """Each joint's ball in the colour of its most loaded dof's share of its limit."""
        worst = {}
        for body, sl in zip(self.model.bodies, self.dof_slices):
            if sl.stop > sl.start:
                name = self._joint_of(body).name
                worst[name] = max(worst.get(name, 0.0), float(np.max(share[sl])))
        for name, marker in self.markers.items():
            marker.color = share_rgb(worst.get(name, 0.0))

    def show(self, visible: bool) -> None:
        for frame in self.frames:
            frame.visible = visible


class SourceOverlay:
    """The captured arm a retargeted motion came from (`--source CLIP.bvh`): shoulder, elbow, wrist
    and hand as line segments, posed at the player's time (hidden during the lead-in)."""

    def __init__(self, server, t: np.ndarray, points: np.ndarray, time_scale: float):
        self.t, self.points = t * time_scale, points
        self.handle = server.scene.add_line_segments("/source", self._segments(0), SOURCE_RGB, thickness=0.012)

    def _segments(self, k: int) -> np.ndarray:
        p = self.points[k].astype(np.float32)
        return np.stack([p[:-1], p[1:]], axis=1)

    def pose(self, t: float) -> None:
        k = int(np.clip(np.searchsorted(self.t, t), 1, len(self.t) - 1))
        k -= int(t - self.t[k - 1] < self.t[k] - t)          # the nearest frame
        self.handle.visible = bool(t >= self.t[0] - 1e-9)
        self.handle.points = self._segments(k)
