"""The servodyn model: a tree of rigid bodies joined by 0-3-dof rotational joints (paper §2).

A model is described body by body in *user frames* — the frames a model file or a URDF speaks
of: each body frame at q = 0 sits at `pos` with orientation `rot` in its parent's frame, and
the joint turns it about `axes` given in that frame, applied in sequence:

    parent_R_body(q) = rot · Rot(axis_1, q_1) · Rot(axis_2, q_2) · Rot(axis_3, q_3) · post

(`post` is a fixed rotation a URDF can leave between the last joint and its link; identity
otherwise). The C core wants each dof to turn about the z axis of its own frame (paper Fig. 3),
so `Model` compiles the description into that form once, keeping for every body the fixed
rotation `frame_rot` (user frame ← core body frame) to translate wrenches at the API.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .. import _core, _core32
from .bodies import BALL_COORDS, BALL_DOFS, FREE_COORDS, FREE_DOFS, Body, ModelError
from .bodies import Dof, combine  # noqa: F401  (importable from here too: the model files and tests take them from tree)
from .rotations import frame_with_z, matrix_to_quat, quat_to_matrix, rot_z
from .shapes import Solid  # noqa: F401  (importable from here too)
from .urdf_write import write_urdf
from .variants import Variants

INTEGRATORS = {"rk4": _core.RK4, "euler": _core.EULER}
DEFAULT_GRAVITY = (0.0, 0.0, -9.81)


def _sym6(I: np.ndarray) -> list[float]:
    return [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]


class Model(Variants):
    """A validated model and the C core that computes its dynamics (double and float builds)."""

    def __init__(self, bodies: list[Body], name: str = "model", gravity=DEFAULT_GRAVITY,
                 description: str = "", source: str = ""):
        self.name = name
        self.description = description
        self.source = source
        self.bodies = list(bodies)
        self._check_names()
        self._compile(np.asarray(gravity, dtype=float))

    # ------------------------------------------------------------------ description
    def _check_names(self):
        seen_bodies, seen_dofs = set(), set()
        for i, body in enumerate(self.bodies):
            if body.name in seen_bodies:
                raise ModelError(f"body '{body.name}': the name is used twice")
            seen_bodies.add(body.name)
            if not -1 <= body.parent < i:
                raise ModelError(f"body '{body.name}': its parent must come before it")
            if len(body.dofs) > 3:
                raise ModelError(f"body '{body.name}': a joint has at most 3 dofs, got {len(body.dofs)}")
            if body.free and (i != 0 or body.parent != -1 or body.dofs):
                raise ModelError(f"body '{body.name}': only body 0, on the base and without dofs, can float free")
            if body.ball and (len(body.dofs) != 3 or body.free or not np.allclose(body.post, np.eye(3))):
                raise ModelError(f"body '{body.name}': a ball joint replaces exactly 3 dofs, with no post rotation")
            if i > 0 and body.parent == -1 and self.bodies[0].free:
                raise ModelError(f"body '{body.name}': with a free root every other body hangs from a body")
            for key in ("pos", "rot", "com", "inertia", "post"):
                if not np.all(np.isfinite(np.asarray(getattr(body, key), dtype=float))):
                    raise ModelError(f"body '{body.name}': a NaN or infinite number in '{key}'")
            for dof in body.dofs:
                if dof.name in seen_dofs:
                    raise ModelError(f"dof '{dof.name}': the name is used twice")
                seen_dofs.add(dof.name)
                if not np.all(np.isfinite(dof.axis)) or np.max(np.abs(dof.axis)) < 1e-9:
                    raise ModelError(f"dof '{dof.name}': the axis must be a finite non-zero vector")
                if not dof.lower <= dof.upper:
                    raise ModelError(f"dof '{dof.name}': lower limit above upper limit")
                if not (math.isfinite(dof.armature) and dof.armature >= 0):
                    raise ModelError(f"dof '{dof.name}': the armature must be a finite number >= 0 kg m², "
                                     f"got {dof.armature}")

    def _compile(self, gravity: np.ndarray):
        """Turn the user-frame description into the core's z-axis dof frames and build the core."""
        nb = len(self.bodies)
        frame_rot = []                 # user_R_core for each body
        pos, rot, dof_rot, com, inertia, dofnum = [], [], [], [], [], []
        for body in self.bodies:
            if body.free:
                # its pose is in q; its frame is the user frame; 6 dofs with no fixed rotations
                frame_rot.append(np.eye(3))
                rot.append(np.eye(3))
                pos.append(np.zeros(3))
                dof_rot.extend([np.eye(3)] * 6)
                com.append(np.asarray(body.com, dtype=float))
                inertia.append(_sym6(np.asarray(body.inertia, dtype=float)))
                dofnum.append(6)
                continue
            parent_F = frame_rot[body.parent] if body.parent >= 0 else np.eye(3)
            if body.ball:
                # the quaternion turns the user frame itself: parent_R_body = rot R(quat)
                frame_rot.append(np.eye(3))
                rot.append(parent_F.T @ body.rot)
                pos.append(parent_F.T @ np.asarray(body.pos, dtype=float))
                dof_rot.extend([np.eye(3)] * 3)
                com.append(np.asarray(body.com, dtype=float))
                inertia.append(_sym6(np.asarray(body.inertia, dtype=float)))
                dofnum.append(3)
                continue
            # M_k sends z to axis_k, so Rot(a, q) = M Rz(q) M' and the chain becomes
            # rot M1 Rz(q1) (M1' M2) Rz(q2) (M2' M3) Rz(q3) (M3' post)
            frames = [frame_with_z(d.axis) for d in body.dofs]
            if frames:
                first = body.rot @ frames[0]
                F = body.post.T @ frames[-1]
            else:
                first = body.rot @ body.post
                F = np.eye(3)
            rot.append(parent_F.T @ first)
            if frames:
                dof_rot.extend([np.eye(3)] + [frames[k - 1].T @ frames[k] for k in range(1, len(frames))])
            frame_rot.append(F)
            pos.append(parent_F.T @ np.asarray(body.pos, dtype=float))
            com.append(F.T @ np.asarray(body.com, dtype=float))
            inertia.append(_sym6(F.T @ np.asarray(body.inertia, dtype=float) @ F))
            dofnum.append(len(body.dofs))
        self.frame_rot = np.array(frame_rot)
        args = dict(parent=[b.parent for b in self.bodies], dofnum=dofnum, pos=pos, rot=rot,
                    dof_rot=dof_rot if dof_rot else np.zeros((0, 9)),
                    mass=[b.mass for b in self.bodies], com=com, inertia=inertia, gravity=gravity,
                    free_root=bool(self.bodies and self.bodies[0].free),
                    ball=[int(b.ball) for b in self.bodies],
                    armature=[0.0] * (6 if self.bodies[0].free else 0)
                    + [d.armature for b in self.bodies for d in b.dofs])
        try:
            self.core = _core.Core(**args)
            self.core32 = _core32.Core(**args)
        except ValueError as err:
            message = str(err)
            if message.startswith("body ") and ":" in message:
                index, reason = message[5:].split(":", 1)
                if index.strip().lstrip("-").isdigit() and int(index) >= 0:
                    message = f"body '{self.bodies[int(index)].name}':{reason}"
            raise ModelError(message) from None
        self._arrays = args
        self.nbody = nb

    # ------------------------------------------------------------------ properties
    @property
    def free_root(self) -> bool:
        """Body 0 floats free (the paper's FREE node): q starts with its origin and quaternion."""
        return bool(self.bodies[0].free)

    @property
    def dof_names(self) -> tuple[str, ...]:
        """Names of the velocity dofs, in the order of qd, qdd and tau."""
        names = []
        for body in self.bodies:
            if body.free:
                names += [f"{body.name}_{c}" for c in FREE_DOFS]
            elif body.ball:
                names += [f"{body.name}_{c}" for c in BALL_DOFS]
            else:
                names += [d.name for d in body.dofs]
        return tuple(names)

    @property
    def q_names(self) -> tuple[str, ...]:
        """Names of the coordinates of q: the dof names, but 7 for a free root and 4 per ball."""
        names = []
        for body in self.bodies:
            if body.free:
                names += [f"{body.name}_{c}" for c in FREE_COORDS]
            elif body.ball:
                names += [f"{body.name}_{c}" for c in BALL_COORDS]
            else:
                names += [d.name for d in body.dofs]
        return tuple(names)

    @property
    def body_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bodies)

    @property
    def nq(self) -> int:
        """Length of q (with a free root one more than nv: its quaternion has 4 numbers)."""
        return self.core.nq

    @property
    def nv(self) -> int:
        """Length of qd, qdd and tau."""
        return self.core.ndof

    def neutral_q(self) -> np.ndarray:
        """q with every hinge at 0, every ball joint at its joint frame and a free root at its
        described pose."""
        q = np.zeros(self.nq)
        k = 0
        for body in self.bodies:
            if body.free:
                q[:3] = body.pos
                q[3:7] = matrix_to_quat(body.rot)
                k = 7
            elif body.ball:
                q[k + 3] = 1.0
                k += 4
            else:
                k += len(body.dofs)
        return q

    def _coordinate_slices(self) -> list[slice]:
        slices, k = [], 0
        for body in self.bodies:
            n = 7 if body.free else 4 if body.ball else len(body.dofs)
            slices.append(slice(k, k + n))
            k += n
        return slices

    def user_poses(self, q) -> tuple[np.ndarray, np.ndarray]:
        """World rotations and origins of the bodies' user frames (those of the model file)."""
        R, p = self.body_poses(q)
        return np.einsum("bij,bkj->bik", R, self.frame_rot), p

    @property
    def gravity(self) -> np.ndarray:
        return np.array(self.core.gravity)

    def _limits(self, which: str) -> np.ndarray:
        values = []
        for body in self.bodies:
            if body.free or body.ball:
                values += [math.inf if which == "upper" else -math.inf] * (6 if body.free else 3)
            else:
                values += [getattr(d, which) for d in body.dofs]
        return np.array(values)

    @property
    def lower(self) -> np.ndarray:
        """Lower joint limits per velocity dof (-inf for a free root's and a ball joint's)."""
        return self._limits("lower")

    @property
    def upper(self) -> np.ndarray:
        return self._limits("upper")

    @property
    def armature(self) -> np.ndarray:
        """Armature per velocity dof (kg m²): the inertia that turns with the dof alone (a geared
        motor's rotor inertia x gear ratio²), added to the diagonal of M(q); 0 for a free root."""
        return np.array(self._arrays["armature"], dtype=float)

    @property
    def total_mass(self) -> float:
        return float(sum(b.mass for b in self.bodies))

    def __repr__(self) -> str:
        return f"<servodyn.Model '{self.name}': {self.nbody} bodies, {self.nv} dofs{', free root' if self.free_root else ''}>"

    # ------------------------------------------------------------------ dynamics
    def _core_fext(self, f_ext):
        """External wrenches (nbody x 6: torque about the body origin, force; user body frames)
        into the core's body frames. A leading batch axis is allowed."""
        if f_ext is None:
            return None
        f = np.asarray(f_ext, dtype=float)
        if f.shape[-2:] != (self.nbody, 6) or f.ndim > 3:
            raise ValueError(f"f_ext must have shape ({self.nbody}, 6) or (N, {self.nbody}, 6), got {f.shape}")
        torque = np.einsum("bji,...bj->...bi", self.frame_rot, f[..., :3])
        force = np.einsum("bji,...bj->...bi", self.frame_rot, f[..., 3:])
        return np.concatenate([torque, force], axis=-1)

    def _pick(self, precision: str):
        if precision == "double":
            return self.core
        if precision == "float":
            return self.core32
        raise ValueError("precision must be 'double' or 'float'")

    # the C binding checks shapes and finiteness itself: no Python-side copies on the way in
    def inverse_dynamics(self, q, qd, qdd, f_ext=None, precision="double") -> np.ndarray:
        """Joint torques (N·m) that produce qdd at (q, qd) under gravity and f_ext.

        f_ext: wrenches acting on each body, (nbody, 6) as (torque about the body origin, force)
        in the body's frame; the paper's end-effector load (f_{n+1}, n_{n+1}) is minus that on
        the last body. Arrays may carry a leading batch axis, computed in C in one call.
        """
        return self._pick(precision).rnea(q, qd, qdd, None if f_ext is None else self._core_fext(f_ext))

    def forward_dynamics(self, q, qd, tau, f_ext=None, precision="double") -> np.ndarray:
        """Joint accelerations (rad/s²) under torques tau, gravity and f_ext (as inverse_dynamics)."""
        return self._pick(precision).forward(q, qd, tau, None if f_ext is None else self._core_fext(f_ext))

    def step(self, q, qd, tau, dt, integrator="rk4", nsteps=1, f_ext=None, precision="double"):
        """Advance (q, qd) by nsteps fixed steps of dt seconds with tau held; returns (q, qd)."""
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {sorted(INTEGRATORS)}, got '{integrator}'")
        return self._pick(precision).step(q, qd, tau, float(dt), INTEGRATORS[integrator], int(nsteps),
                                          None if f_ext is None else self._core_fext(f_ext))

    def regressor(self, q, qd, qdd) -> np.ndarray:
        """The joint-torque regressor Y (nv, 10·nbody): inverse_dynamics = Y @ inertial_parameters()
        plus armature·qdd, without f_ext. A leading batch axis gives (N, nv, 10·nbody), computed in
        C in one call. Columns per body in Pinocchio's order (m, m·c, I about the body origin:
        xx, xy, yy, xz, yz, zz), in the core's body frame (frame_rot turns it to the user's)."""
        return self.core.regressor(q, qd, qdd)

    def inertial_parameters(self) -> np.ndarray:
        """The bodies' parameters (10·nbody) in the order of regressor()'s columns."""
        a = self._arrays
        out = []
        for mass, com, (xx, yy, zz, xy, xz, yz) in zip(a["mass"], a["com"], a["inertia"]):
            c = np.asarray(com, dtype=float)
            I = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]) + mass * (c @ c * np.eye(3) - np.outer(c, c))
            out.append([mass, *(mass * c), I[0, 0], I[0, 1], I[1, 1], I[0, 2], I[1, 2], I[2, 2]])
        return np.array(out, dtype=float).ravel()

    def momentum(self, q, qd, precision="double") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p, g, Cᵀq̇): the generalized momentum M(q)·q̇ (armature included), the gravity torques
        g(q) and C(q, q̇)ᵀ·q̇ with Ṁ = C + Cᵀ, in one O(n) recursion of the core (sd_momentum); the
        momentum observer's β = g − Cᵀq̇. A leading batch axis is computed in C in one call."""
        return self._pick(precision).momentum(q, qd)

    def mass_matrix(self, q) -> np.ndarray:
        """The joint-space inertia matrix M(q), column by column from inverse dynamics (the
        armatures on its diagonal)."""
        q = np.asarray(q, dtype=float)
        n = self.nv
        # minus the torques at zero acceleration, which a root force would otherwise add
        columns = self._weightless.rnea(np.tile(q, (n + 1, 1)), np.zeros((n + 1, n)),
                                        np.vstack([np.eye(n), np.zeros(n)]))
        return (columns[:n] - columns[n]).T

    @functools.cached_property
    def _weightless(self):
        """The core of this model without gravity, for M(q): its columns are then the inertial
        torques alone, as exact as the RNEA (with gravity, M e_i + g(q) - g(q) rounds away the low
        bits of small columns). Built on first use; the model's own cores are never changed."""
        return _core.Core(**{**self._arrays, "gravity": np.zeros(3)})

    # ------------------------------------------------------------------ kinematics and energy
    def body_poses(self, q) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (nbody, 3, 3) and origins (nbody, 3) of the core body frames at q."""
        q = np.asarray(q, dtype=float)
        a = self._arrays
        R_world = np.zeros((self.nbody, 3, 3))
        p_world = np.zeros((self.nbody, 3))
        dof_rot = np.asarray(a["dof_rot"], dtype=float).reshape(-1, 3, 3)
        k = 0      # index into q
        j = 0      # index into the dofs (dof_rot)
        for i, body in enumerate(self.bodies):
            if body.free:
                R_world[0], p_world[0] = quat_to_matrix(q[3:7]), q[:3]
                k, j = 7, 6
                continue
            R = np.asarray(a["rot"][i], dtype=float).reshape(3, 3)
            if body.ball:
                R = R @ quat_to_matrix(q[k:k + 4])
                k += 4
                j += 3
            else:
                for _ in body.dofs:
                    R = R @ dof_rot[j] @ rot_z(q[k])
                    k += 1
                    j += 1
            p = np.asarray(a["pos"][i], dtype=float)
            if body.parent >= 0:
                p_world[i] = p_world[body.parent] + R_world[body.parent] @ p
                R_world[i] = R_world[body.parent] @ R
            else:
                p_world[i], R_world[i] = p, R
        return R_world, p_world

    def com_positions(self, q) -> np.ndarray:
        """World positions (nbody, 3) of every body's centre of mass."""
        R, p = self.body_poses(q)
        com = np.asarray(self._arrays["com"], dtype=float)
        return p + np.einsum("bij,bj->bi", R, com)

    def energy(self, q, qd) -> tuple[float, float]:
        """(kinetic, potential) energy in joules; potential is zero at the base origin."""
        qd = np.asarray(qd, dtype=float)
        kinetic = 0.5 * float(qd @ self.mass_matrix(q) @ qd)
        masses = np.array([b.mass for b in self.bodies])
        potential = -float(np.sum(masses * (self.com_positions(q) @ self.gravity)))
        return kinetic, potential

    # ------------------------------------------------------------------ export
    def to_urdf(self, path) -> None:
        """Write the model as URDF (one revolute joint per dof, massless links between the dofs
        of one joint), loadable by Pinocchio, MuJoCo and RViz."""
        write_urdf(self, path)
