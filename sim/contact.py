"""Contact on the simulated arm: pushes on its bodies and obstacles its solids hit, as the external
wrenches the plant hands the C core every small step (sim/plant.py's `wrenches`), with the ground
truth kept for scoring a detector (`Contacts.status`, `Contacts.log`).

    contacts = Contacts(model, obstacles=[Plane((0, 0, 1), -0.45)])
    contacts.schedule(Push("r_hand", (0, 0, -10), start=1.2), origin=plant_time_at_swing_start)
    f_ext = contacts(t, q, qd)         # (nbody, 6) or None: nothing touches the arm at t

The data (Push, Plane, Sphere) are hal/contact_spec.py's. A wrench is what model.step takes: per
body, (torque about the body's origin, force), both in the body's user frame.

* A push is its force, world frame, at the body's centre of mass (model.bodies[i].com), from its
  start for its duration; it does not follow the body's motion.
* An obstacle is a frictionless spring–damper along its normal, F = K·δ + C·δ̇ (never pulling:
  clamped at 0), δ the depth of a body's deepest sample point inside it, δ̇ its rate; one contact per
  body and obstacle, so a body sunk flat into a plane feels K, not K times its points. The damping
  C = K·DAMPING_TIME: a damping ratio of 0.1 on 1 kg at 40 N/mm, restitution about 0.7.
* The sample points are on the surface of each body's solids (host/model/shapes.py, the replica's
  servo housings, tubes and brackets): a box's corners, edge middles and face centres; rings of
  RING_POINTS points at most SPACING apart along a cylinder or frustum, with its end centres; a
  sphere's or ellipsoid's poles and equator. A body without solids is sampled at its origin and its
  centre of mass.

The points are checked every step only near an obstacle: after a check that finds every point at
least d from every obstacle, none can touch one before the arm has moved d, bounded each step by
Σ|q̇_k|·reach_k (reach_k: the farthest any point beyond dof k can be from its axis, from the link
lengths), so the next check waits for that (`reach`); the kinematics are the model's user frames in
plain floats (`Kinematics`: a small chain costs more in numpy calls than in arithmetic).

The wrench is held over a step (as the drives' currents are). A held spring–damper is stable
while its damping outlasts half a step and C·dt stays under twice the effective mass at the point;
`substeps(dt)` cuts the plant's step so that holds down to LIGHTEST kg (the replica's hand without
its servos' armature is about 0.09 kg, contact/plan.md §3): one piece up to K ≈ 100 N/mm at 1 ms.

Ground truth, per evaluation in contact (`log`: time, body, source, force xyz (N, world), point xyz
(m, world), depth (m)), and its summary (`status`): the onset (first time a force over
ONSET_FORCE or a depth over 0), its body, the peak force and when, the force now.
"""

from __future__ import annotations

import math

import numpy as np

from servodyn.errors import InputError
from servodyn.hal.contact_spec import Plane, Push, Sphere, check_contacts
from servodyn.model.shapes import box_sides

DAMPING_TIME = 1e-3     # s: an obstacle's damping C = K·DAMPING_TIME (N s/m)
LIGHTEST = 0.05         # kg: the lightest effective mass a contact point is integrated stably for
ONSET_FORCE = 0.5       # N: a contact starts when its force exceeds this, or a point is inside
SPACING = 0.03          # m between rings of sample points along a tube
RING_POINTS = 6         # sample points round a ring
MAX_LOG = 200_000       # rows of ground truth kept (200 s of contact at 1 kHz)
MARGIN = 2e-3           # m: a check comes before the arm can have moved within this of an obstacle
LOG_COLUMNS = ("t", "body", "source", "fx", "fy", "fz", "px", "py", "pz", "depth")


def _ring(radius: float, z: float) -> np.ndarray:
    angles = np.arange(RING_POINTS) * (2 * math.pi / RING_POINTS)
    return np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.full(RING_POINTS, z)])


def solid_points(solid) -> np.ndarray:
    """Sample points on a solid's surface, in its body's user frame (module docstring)."""
    kind, dims = solid.kind, solid.dims
    if kind == "ellipsoid" and solid.draw == "box":
        half = box_sides(solid) / 2
        grid = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if x or y or z])
        local = grid * half
    elif kind in ("cylinder", "frustum"):
        r0, r1, length = (dims[0], dims[0], dims[1]) if kind == "cylinder" else dims
        rings = max(2, math.ceil(length / SPACING) + 1)
        local = np.vstack([_ring(r0 + (r1 - r0) * s, length * s) for s in np.linspace(0.0, 1.0, rings)]
                          + [[[0.0, 0.0, 0.0], [0.0, 0.0, length]]])
    elif kind in ("sphere", "ellipsoid"):
        axes = np.array([dims[0]] * 3 if kind == "sphere" else dims, dtype=float)
        local = np.vstack([_ring(1.0, 0.0), [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]]) * axes
    else:
        raise ValueError(f"unknown solid '{kind}'")
    return np.asarray(solid.pos, dtype=float) + local @ np.asarray(solid.rot, dtype=float).T


def body_points(body) -> np.ndarray:
    """A body's sample points in its user frame."""
    if not body.solids:
        return np.array([np.zeros(3), np.asarray(body.com, dtype=float)])
    return np.vstack([solid_points(s) for s in body.solids])


def _mat(a, b):
    """a·b of 3×3 nested tuples, written out (10 times faster than a comprehension)."""
    (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = a
    (b0, b1, b2), (b3, b4, b5), (b6, b7, b8) = b
    return ((a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8),
            (a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8),
            (a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8))


def _vec(a, x):
    (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = a
    x0, x1, x2 = x
    return (a0 * x0 + a1 * x1 + a2 * x2, a3 * x0 + a4 * x1 + a5 * x2, a6 * x0 + a7 * x1 + a8 * x2)


def _tvec(a, x):
    """aᵀ·x."""
    (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = a
    x0, x1, x2 = x
    return (a0 * x0 + a3 * x1 + a6 * x2, a1 * x0 + a4 * x1 + a7 * x2, a2 * x0 + a5 * x1 + a8 * x2)


def _fold(r, a, b, s, v):
    """r + s·a + v·b of 3×3 nested tuples."""
    (r0, r1, r2), (r3, r4, r5), (r6, r7, r8) = r
    (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = a
    (b0, b1, b2), (b3, b4, b5), (b6, b7, b8) = b
    return ((r0 + s * a0 + v * b0, r1 + s * a1 + v * b1, r2 + s * a2 + v * b2),
            (r3 + s * a3 + v * b3, r4 + s * a4 + v * b4, r5 + s * a5 + v * b5),
            (r6 + s * a6 + v * b6, r7 + s * a7 + v * b7, r8 + s * a8 + v * b8))


def _turn(axis, angle):
    """Rotation by `angle` about the unit `axis` (Rodrigues)."""
    x, y, z = axis
    s, c = math.sin(angle), math.cos(angle)
    t = 1.0 - c
    return ((c + t * x * x, t * x * y - s * z, t * x * z + s * y),
            (t * x * y + s * z, c + t * y * y, t * y * z - s * x),
            (t * x * z - s * y, t * y * z + s * x, c + t * z * z))


class Kinematics:
    """The bodies' user frames in the world and their velocities at (q, q̇), for a model of hinge
    joints: parent_R_body(q) = rot · Rot(axis_1, q_1) · ... · post (host/model/tree.py)."""

    def __init__(self, model):
        bodies = model.bodies
        self.parent = [b.parent for b in bodies]
        rows = lambda m: tuple(map(tuple, np.asarray(m, dtype=float).tolist()))      # noqa: E731
        self.rot = [rows(b.rot) for b in bodies]
        self.post = [None if np.array_equal(b.post, np.eye(3)) else rows(b.post) for b in bodies]
        self.pos = [tuple(np.asarray(b.pos, dtype=float).tolist()) for b in bodies]
        self.dofs, self.axes = [], []
        for body in bodies:
            self.dofs.append(list(range(len(self.axes), len(self.axes) + len(body.dofs))))
            self.axes += [tuple((np.asarray(d.axis, dtype=float) / np.linalg.norm(d.axis)).tolist()) for d in body.dofs]
        # a body's first turn folded into its fixed rotation: rot·Rot(a, q) = rot + sin q·rot[a]× + (1 − cos q)·rot[a]×²
        self.first = []
        for i, dofs in enumerate(self.dofs):
            if not dofs:
                self.first.append(None)
                continue
            x, y, z = self.axes[dofs[0]]
            cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
            rot = np.asarray(bodies[i].rot, dtype=float)
            self.first.append((rows(rot @ cross), rows(rot @ cross @ cross), tuple((rot @ self.axes[dofs[0]]).tolist())))

    def __call__(self, q, qd=None, last: int | None = None):
        """(R (nbody, 3, 3) world ← user frame, origins (nbody, 3), angular velocities (nbody, 3),
        origins' velocities (nbody, 3)), all in the world frame; up to body `last` only when given,
        and without the velocities (zeros) when qd is None."""
        return tuple(np.array(x) for x in self.chain(q, qd, last))

    def chain(self, q, qd=None, last: int | None = None) -> tuple[list, list, list, list]:
        """What __call__ gives, as lists of tuples (rows of R)."""
        q = np.asarray(q, dtype=float).tolist()
        qd = [0.0] * len(q) if qd is None else np.asarray(qd, dtype=float).tolist()
        R, p, w, v = [], [], [], []
        for i, parent in enumerate(self.parent[:None if last is None else last + 1]):
            if parent >= 0:
                Rp, pp, wp, vp = R[parent], p[parent], w[parent], v[parent]
                off = _vec(Rp, self.pos[i])
                p.append((pp[0] + off[0], pp[1] + off[1], pp[2] + off[2]))
                v.append((vp[0] + wp[1] * off[2] - wp[2] * off[1], vp[1] + wp[2] * off[0] - wp[0] * off[2],
                          vp[2] + wp[0] * off[1] - wp[1] * off[0]))
                wi = wp
            else:
                Rp = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
                p.append(self.pos[i])
                v.append((0.0, 0.0, 0.0))
                wi = (0.0, 0.0, 0.0)
            dofs = self.dofs[i]
            if dofs:
                A, B, axis = self.first[i]
                k, rate = dofs[0], qd[dofs[0]]
                sine, versine = math.sin(q[k]), 1.0 - math.cos(q[k])
                if rate:
                    a = _vec(Rp, axis)
                    wi = (wi[0] + a[0] * rate, wi[1] + a[1] * rate, wi[2] + a[2] * rate)
                Ri = _mat(Rp, _fold(self.rot[i], A, B, sine, versine))
            else:
                Ri = _mat(Rp, self.rot[i])
            for k in dofs[1:]:
                a, rate = _vec(Ri, self.axes[k]), qd[k]
                wi = (wi[0] + a[0] * rate, wi[1] + a[1] * rate, wi[2] + a[2] * rate)
                Ri = _mat(Ri, _turn(self.axes[k], q[k]))
            R.append(Ri if self.post[i] is None else _mat(Ri, self.post[i]))
            w.append(wi)
        return R, p, w, v


def reach(model, points: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Per dof, the farthest any sample point of a body beyond it can be from its joint's origin
    (on its axis), in any pose: the link lengths on the way and the point's own distance added up."""
    bodies = model.bodies
    own = np.array([np.linalg.norm(points[owner == i], axis=1).max(initial=0.0) for i in range(len(bodies))])
    out = []
    for i, body in enumerate(bodies):
        farthest = 0.0
        for j in range(len(bodies)):        # j beyond i: walk up from j to i adding the offsets
            length, b = own[j], j
            while b > i:
                length += float(np.linalg.norm(bodies[b].pos))
                b = bodies[b].parent
            if b == i:
                farthest = max(farthest, length)
        out += [farthest] * len(body.dofs)
    return np.array(out)


class Contacts:
    """The pushes and obstacles on one model's bodies; called as the plant's `wrenches`."""

    def __init__(self, model, obstacles=(), pushes=()):
        if model.nq != model.nv:
            raise InputError(f"'{model.name}': contact is simulated on hinge joints only (no free root or ball joint)")
        self.model = model
        self.names = model.body_names
        self.obstacles = list(obstacles)
        for obstacle in self.obstacles:
            if not isinstance(obstacle, (Plane, Sphere)):
                raise InputError(f"an obstacle is a Plane or a Sphere, not {obstacle!r}")
        self.pushes: list[tuple[Push, float, float]] = []       # (push, start, end) on the plant's clock
        self.com = [tuple(np.asarray(b.com, dtype=float).tolist()) for b in model.bodies]
        points = [body_points(b) for b in model.bodies]
        self.points = np.vstack(points)                         # every body's, in its user frame
        self.owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(points)])
        self.starts = np.cumsum([0] + [len(p) for p in points])          # body i's points: starts[i]:starts[i+1]
        self.kinematics = Kinematics(model)
        self.reach = reach(model, self.points, self.owner)
        self._clear = 0.0            # m the arm may still move before the obstacles need a check
        self._last = None            # (time, speed bound) at the last call
        self.log: list[tuple] = []
        self.onset: dict | None = None
        self.peak = {"force_n": 0.0, "time": None, "body": None}
        self.now: dict[str, float] = {}                         # body -> force (N) at the last evaluation
        for push in pushes:
            self.schedule(push)

    # --- set up ---------------------------------------------------------------------------------

    def schedule(self, push: Push, origin: float = 0.0) -> None:
        """`push` from `origin` + push.start on the plant's clock (s)."""
        check_contacts(self.model, [push], [], simulated=True)
        start = float(origin) + push.start
        self.pushes.append((push, start, start + push.duration))

    def substeps(self, dt: float) -> int:
        """Pieces to cut a plant step of `dt` into while in contact (module docstring)."""
        stiffest = max((o.stiffness for o in self.obstacles), default=0.0)
        return max(1, math.ceil(stiffest * DAMPING_TIME * dt / (2 * LIGHTEST) - 1e-9))

    # --- every step -----------------------------------------------------------------------------

    def __call__(self, t: float, q, qd) -> np.ndarray | None:
        """The wrenches on the bodies at time t and state (q, qd), or None when nothing touches the
        arm; what is applied goes into the ground truth."""
        active = [(k, p) for k, (p, start, end) in enumerate(self.pushes) if start - 1e-9 <= t < end - 1e-9]
        check = bool(self.obstacles) and self._moved(t, qd)
        if not active and not check:
            if self.now:
                self.now = {}
            return None
        pushed = [self.names.index(push.body) for _, push in active]
        R, origin, w, v = self.kinematics.chain(q, qd, None) if check else \
            self.kinematics.chain(q, None, max(pushed))
        rows = []          # (body, source, force, point, depth): the force and point in the world frame
        for (k, push), body in zip(active, pushed):
            centre, at = _vec(R[body], self.com[body]), origin[body]
            rows.append((body, f"push {k}", push.force, (at[0] + centre[0], at[1] + centre[1], at[2] + centre[2]),
                         0.0))
        if check:
            rows += self._obstacles(*(np.array(x) for x in (R, origin, w, v)))
        if not rows:
            if self.now:
                self.now = {}
            return None
        f_ext = np.zeros((len(self.names), 6))
        for body, _, force, point, _ in rows:
            at = origin[body]
            fx, fy, fz = _tvec(R[body], force)
            x, y, z = _tvec(R[body], (point[0] - at[0], point[1] - at[1], point[2] - at[2]))
            f_ext[body] += (y * fz - z * fy, z * fx - x * fz, x * fy - y * fx, fx, fy, fz)
        self._record(t, rows)
        return f_ext

    def _moved(self, t: float, qd) -> bool:
        """Whether the obstacles want a check now: the arm may have moved within MARGIN of one since
        the last check (its points' speed bounded by Σ|q̇_k|·reach_k, the larger of now and then)."""
        speed = float(np.abs(qd) @ self.reach)
        if self._last is not None:
            self._clear -= max(speed, self._last[1]) * max(t - self._last[0], 0.0)
        self._last = (t, speed)
        return self._clear <= MARGIN

    def _obstacles(self, R, origin, w, v) -> list:
        """Each body's deepest point inside each obstacle, as (body, source, force, point, depth)
        rows; and how far the arm may move before the next check."""
        offset = np.einsum("pij,pj->pi", R[self.owner], self.points)
        world = origin[self.owner] + offset
        rows, nearest = [], math.inf
        for index, obstacle in enumerate(self.obstacles):
            depth, normal = self._depth(obstacle, world)
            deepest = float(depth.max())
            nearest = min(nearest, -deepest)
            if deepest <= 0:
                continue
            for body in np.flatnonzero(np.maximum.reduceat(depth, self.starts[:-1]) > 0).tolist():
                first = int(self.starts[body])
                p = first + int(np.argmax(depth[first:self.starts[body + 1]]))
                spin, r = w[body].tolist(), offset[p].tolist()
                moving = v[body] + [spin[1] * r[2] - spin[2] * r[1], spin[2] * r[0] - spin[0] * r[2],
                                    spin[0] * r[1] - spin[1] * r[0]]
                rate = -float(normal[p] @ moving)
                magnitude = max(0.0, obstacle.stiffness * (depth[p] + DAMPING_TIME * rate))
                rows.append((body, f"obstacle {index}", tuple((magnitude * normal[p]).tolist()),
                             tuple(world[p].tolist()), float(depth[p])))
        self._clear = nearest
        return rows

    @staticmethod
    def _depth(obstacle, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each point's depth inside the obstacle (negative: outside) and the outward normal there."""
        if isinstance(obstacle, Plane):
            normal = np.asarray(obstacle.normal)
            return obstacle.offset - world @ normal, np.broadcast_to(normal, world.shape)
        away = world - np.asarray(obstacle.centre)
        distance = np.linalg.norm(away, axis=1)
        normal = away / np.maximum(distance, 1e-12)[:, None]
        return obstacle.radius - distance, normal

    def _record(self, t: float, rows: list) -> None:
        vectors: dict[str, list] = {}
        touching = None
        for body, source, force, point, depth in rows:
            name = self.names[body]
            total = vectors.setdefault(name, [0.0, 0.0, 0.0])
            total[0], total[1], total[2] = total[0] + force[0], total[1] + force[1], total[2] + force[2]
            if len(self.log) < MAX_LOG:
                self.log.append((t, name, source, *force, *point, depth))
            if depth > 0 and touching is None:
                touching = name
        per_body = {name: math.sqrt(x * x + y * y + z * z) for name, (x, y, z) in vectors.items()}
        self.now = per_body
        strongest = max(per_body, key=per_body.get)
        if self.onset is None and (per_body[strongest] > ONSET_FORCE or touching is not None):
            body = strongest if per_body[strongest] > ONSET_FORCE else touching
            self.onset = {"time": t, "body": body}
        if per_body[strongest] > self.peak["force_n"]:
            self.peak = {"force_n": per_body[strongest], "time": t, "body": strongest}

    # --- what happened --------------------------------------------------------------------------

    def status(self) -> dict:
        """The ground truth so far, JSON-able: onset_time (plant s, None before any contact),
        body (at the onset), peak_force_n, peak_time, peak_body, force_n (the largest on a body at
        the last step: at a stop, the force at the stop), forces_n (each body's then), pushes
        (body, start, end on the plant's clock), obstacles (how many)."""
        onset = self.onset or {}
        return {"onset_time": onset.get("time"), "body": onset.get("body"),
                "peak_force_n": self.peak["force_n"], "peak_time": self.peak["time"], "peak_body": self.peak["body"],
                "force_n": max(self.now.values(), default=0.0), "forces_n": dict(self.now),
                "pushes": [{"body": p.body, "force": list(p.force), "start": s, "end": e} for p, s, e in self.pushes],
                "obstacles": len(self.obstacles), "log_rows": len(self.log)}

    def table(self) -> dict:
        """The ground truth row by row: {"columns": LOG_COLUMNS, "rows": [...]}."""
        return {"columns": list(LOG_COLUMNS), "rows": [list(row) for row in self.log]}
