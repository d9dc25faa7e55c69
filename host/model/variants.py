"""The models derived from a model, each a new one (a Model never changes once built): with ball
joints, a subtree, locked joints, a payload, scaled masses, a free root, another gravity or other
armatures, and a pose carried from one model's coordinates to another's. Mixed into tree.Model."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .bodies import ModelError, combine
from .rotations import axis_angle, matrix_to_quat

if TYPE_CHECKING:
    from .tree import Model


class Variants:
    """The `with_*` methods of tree.Model (and `subtree`, `q_from`)."""

    def with_ball_joints(self) -> "Model":
        """The same bodies with every 3-dof joint as a ball joint (quaternion coordinates): the
        same physics without gimbal lock, for simulation."""
        bodies = [replace(b, ball=True) if len(b.dofs) == 3 and not b.free else b for b in self.bodies]
        return type(self)(bodies, name=self.name, gravity=self.gravity, description=self.description,
                          source=self.source)

    def q_from(self, other: "Model", q_other) -> np.ndarray:
        """This model's q for the pose other (the same bodies, hinges or ball joints) has at q_other."""
        q_other = np.asarray(q_other, dtype=float)
        mine, theirs = self._coordinate_slices(), other._coordinate_slices()
        q = np.zeros(self.nq)
        for body, sm, so, other_body in zip(self.bodies, mine, theirs, other.bodies):
            value = q_other[so]
            if body.ball and not other_body.ball:
                R = np.eye(3)
                for dof, angle in zip(other_body.dofs, value):
                    R = R @ axis_angle(dof.axis, angle)
                value = matrix_to_quat(R)
            elif other_body.ball and not body.ball:
                raise ModelError(f"body '{body.name}': cannot turn a ball joint back into angles")
            q[sm] = value
        return q

    def subtree(self, root: str, q=None) -> "Model":
        """The bodies from `root` down, with `root` welded to the base where it is at q (the
        neutral pose by default) — e.g. the upper body of human15 held at the thorax."""
        if root not in self.body_names:
            raise ModelError(f"no body '{root}' in model '{self.name}'")
        q = self.neutral_q() if q is None else np.asarray(q, dtype=float)
        R, p = self.user_poses(q)
        start = self.body_names.index(root)
        keep = [start]
        for i in range(start + 1, self.nbody):
            if self.bodies[i].parent in keep:
                keep.append(i)
        index = {old: new for new, old in enumerate(keep)}
        top = self.bodies[start]
        bodies = [replace(top, parent=-1, pos=p[start].copy(), rot=R[start].copy(), dofs=[],
                          post=np.eye(3), free=False)]
        bodies += [replace(self.bodies[i], parent=index[self.bodies[i].parent]) for i in keep[1:]]
        return type(self)(bodies, name=f"{self.name}:{root}", gravity=self.gravity,
                          description=f"the bodies of {self.name} from {root} down, {root} held still",
                          source=self.source)

    def with_locked(self, bodies: list[str], angles: dict[str, float] | None = None) -> "Model":
        """The same model with the joints of the named bodies welded at the given angles (0 by
        default): their dofs leave q."""
        angles = angles or {}
        out = []
        for body in self.bodies:
            if body.name in bodies and body.dofs:
                R = body.rot
                for dof in body.dofs:
                    R = R @ axis_angle(dof.axis, angles.get(dof.name, 0.0))
                body = replace(body, rot=R @ body.post, dofs=[], post=np.eye(3))
            out.append(body)
        missing = set(bodies) - set(self.body_names)
        if missing:
            raise ModelError(f"no body '{sorted(missing)[0]}' in model '{self.name}'")
        return type(self)(out, name=self.name, gravity=self.gravity, description=self.description,
                          source=self.source)

    def with_payload(self, mass: float, body: str | None = None, com=None) -> "Model":
        """The same model carrying a point mass rigidly on a body (the last one, the hand, by
        default) at `com` in that body's user frame (its centre of mass by default)."""
        name = self.body_names[-1] if body is None else body
        if name not in self.body_names:
            raise ModelError(f"no body '{name}' in model '{self.name}' ({', '.join(self.body_names)})")
        if not (math.isfinite(mass) and mass >= 0):
            raise ModelError(f"payload mass must be a finite number >= 0 kg, got {mass}")
        k = self.body_names.index(name)
        host = self.bodies[k]
        at = host.com if com is None else np.asarray(com, dtype=float)
        if at.shape != (3,) or not np.all(np.isfinite(at)):
            raise ModelError(f"payload position must be three finite numbers (m), got {com}")
        total, centre, inertia = combine([(host.mass, host.com, host.inertia), (mass, at, np.zeros((3, 3)))])
        bodies = list(self.bodies)
        bodies[k] = replace(host, mass=total, com=centre, inertia=inertia)
        return type(self)(bodies, name=self.name, gravity=self.gravity, description=self.description,
                          source=self.source)

    def with_mass_scale(self, scale: float) -> "Model":
        """The same model with every body's mass and inertia times `scale` (centres of mass kept)."""
        if not (math.isfinite(scale) and scale > 0):
            raise ModelError(f"mass scale must be a finite number > 0, got {scale}")
        bodies = [replace(b, mass=b.mass * scale, inertia=b.inertia * scale) for b in self.bodies]
        return type(self)(bodies, name=self.name, gravity=self.gravity, description=self.description,
                          source=self.source)

    def with_free_root(self) -> "Model":
        """The same model with body 0 floating free instead of fixed to the base."""
        first = self.bodies[0]
        if first.parent != -1 or first.dofs:
            raise ModelError(f"body '{first.name}': a free root must hang from the base without dofs")
        bodies = [replace(first, free=True)] + self.bodies[1:]
        return type(self)(bodies, name=self.name, gravity=self.gravity, description=self.description,
                          source=self.source)

    def with_gravity(self, g) -> "Model":
        """The same model under gravity g (m/s², world frame). A Model never changes once built, so
        that threads stepping it (a simulator's real-time thread) and threads asking it for M(q)
        share it safely."""
        g = np.asarray(g, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ModelError(f"gravity must be 3 finite numbers (m/s²), got {g.tolist()}")
        return type(self)(self.bodies, name=self.name, gravity=g, description=self.description,
                          source=self.source)

    def with_armature(self, armature: dict[str, float]) -> "Model":
        """The same model with the armature (kg m²) of the named dofs set to the given values."""
        unknown = sorted(set(armature) - {d.name for b in self.bodies for d in b.dofs})
        if unknown:
            raise ModelError(f"no dof '{unknown[0]}' in model '{self.name}'")
        bodies = [replace(b, dofs=[replace(d, armature=float(armature.get(d.name, d.armature)))
                                   for d in b.dofs]) for b in self.bodies]
        return type(self)(bodies, name=self.name, gravity=self.gravity, description=self.description,
                          source=self.source)
