"""Inverse kinematics: joint angles that put the hand at a position (and, if given, an orientation).

    >>> from servodyn.model import load_model
    >>> from servodyn.model import ik
    >>> arm = load_model("human_arm")
    >>> r = ik.solve(arm, [0.3, -0.1, -0.2])                 # position only, cold
    >>> r.q, r.reach, r.swivel, r.method                      # q (nq,), fraction, rad, "srs"
    >>> r = ik.solve(arm, p, rotation=R, q_prev=r.q)          # nearest the previous pose
    >>> path = ik.solve_path(arm, positions, dt=0.01, max_speed=6.0)   # a hand path, (N, nq)

The hand is the origin of the end body (`end`, by default the body named like a right hand, else
the last one) and its orientation the rotation of that body's frame as the model file gives it
(`Model.user_poses`), in the base frame. Only the dofs on the path from the base to the hand move;
the others keep q_prev (the neutral pose without one).

Two solvers (`method`):

- **srs**, closed form (IKAN: Tolani, Goswami, Badler, Graphical Models 2000) for a spherical-
  revolute-spherical arm: the last seven dofs on the path are a shoulder of three axes through one
  point S, an elbow hinge, and a wrist of three axes through one point W, the hand's origin. The
  structure is read off the model's own axes and order (any axes, any offsets of the elbow), so
  human_arm and the replicas qualify. The elbow angle follows from |W − S| by the law of cosines;
  the swivel φ, the angle of the elbow about the shoulder–wrist line, is the free parameter; the
  shoulder and wrist angles are Euler angles about the model's axes (two branches each). Of the
  branches inside the limits, the one nearest q_prev is taken.
- **dls**, damped least squares with the limits as box bounds (scipy's bounded least squares on
  [J; λI] dx = [e; 0]), for any chain of hinges; a cold solve restarts from random poses.

`method="auto"` (the default) takes the closed form where the arm is S-R-S and falls back to DLS
otherwise, and when the closed form finds no swivel inside the limits.

The swivel φ is the angle about the shoulder→wrist line n of the elbow's bending direction
n × (elbow axis): 0 when it points as far down (−z of the base) as the line allows, positive
turning right-handed about n. Without `swivel`, a solve with q_prev keeps the previous elbow
direction (continuity along a drag or a path) and a cold solve starts from 0 (elbow down), each
moving to the nearest swivel inside the limits when that one is not.

Refusals are `IkError`s (a `ModelError`, one line): `OutOfReach` ("out of reach"), `NoSwivel`
("no swivel inside the limits"), and `IkError` for a chain the solvers cannot take.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np

from .rotations import axis_angle, rotation_angle, rotation_log, skew, turn
from .tree import Model, ModelError

TOL_LIMIT = 1e-10      # rad: a solution this far past a limit is clipped onto it (changes the hand < 1e-10 m)
TOL_REACH = 1e-12      # relative: the law of cosines accepts rounding this far past full reach
TOL_DLS = 1e-11        # m and rad: the DLS stops below this error
STRUCTURE_TOL = 1e-9   # m: axes meeting within this distance meet
GRID = 72              # swivels tried at once when the preferred one is outside the limits (5° apart)
ROTATION_LENGTH = 0.3  # m: an orientation error of 1 rad weighs as 0.3 m of position error in DLS


class IkError(ModelError):
    """Inverse kinematics refused a target; the message is one line and says why."""


class OutOfReach(IkError):
    """The target is farther from the shoulder than the arm reaches (or nearer than it folds)."""
    exit_code = 1       # a refusal, not bad input


class NoSwivel(IkError):
    """The target is within reach, but every arm pose reaching it has a joint outside its limits."""
    exit_code = 1       # a refusal, not bad input


@dataclass(frozen=True)
class IkResult:
    q: np.ndarray               # (nq,) the whole model's q, in limits
    position_error: float       # m, |hand - target|
    rotation_error: float       # rad, angle of R_hand R_targetᵀ (0 without a rotation target)
    reach: float                # |target - shoulder| / the farthest the arm reaches (1 = stretched)
    reach_m: float              # m, |target - shoulder| (the first dof's pivot without an S-R-S arm)
    swivel: float               # rad, the elbow's swivel (nan without an S-R-S arm)
    method: str                 # "srs" or "dls"
    iterations: int = 0         # DLS iterations (0 for the closed form)


@dataclass(frozen=True)
class PathResult:
    q: np.ndarray               # (N, nq)
    position_error: np.ndarray  # (N,) m
    rotation_error: np.ndarray  # (N,) rad
    swivel: np.ndarray          # (N,) rad
    slowed: np.ndarray          # (N,) bool: the speed bound held the arm back at this sample
    reach: np.ndarray           # (N,)


_EYE = np.eye(3)


# ------------------------------------------------------------------------------ the three-angle split
def _cross(a, b):
    """a x b over the last axis, broadcasting (numpy's cross costs ten times more on small arrays)."""
    a, b = np.asarray(a), np.asarray(b)
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _euler(G, w0, w1, w2, hint0):
    """Both branches of G = Rot(w0, a) Rot(w1, b) Rot(w2, c) for any axes with w1 across w0 and w2:
    angles (N, 2, 3) for G (N, 3, 3). In gimbal lock (a and c turn about one line) a = hint0."""
    K0, K1 = skew(w0), skew(w1)
    w12 = K1 @ w2
    c1 = w0 @ w2 - (w0 @ w1) * (w1 @ w2)
    s1 = w0 @ w12
    k = (w0 @ w1) * (w1 @ w2)
    Gw2 = G @ w2
    value = Gw2 @ w0
    alpha = math.atan2(s1, c1)
    # cos(b - alpha) = (value - k) / rho; its sine from |w0 x G w2|, exact near the lock too
    across = np.sum((Gw2 @ K0.T) ** 2, axis=-1) + 2 * value * k - (w0 @ w1) ** 2 - (w1 @ w2) ** 2
    spread = np.arctan2(np.sqrt(np.maximum(across, 0.0)), value - k)
    b = np.stack([alpha + spread, alpha - spread], axis=1)              # (N, 2)
    cb, sb = np.cos(b)[..., None], np.sin(b)[..., None]
    v = w2 * cb + w12 * sb + w1 * ((w1 @ w2) * (1 - cb))                # Rot(w1, b) w2, (N, 2, 3)
    # a: the turn about w0 taking v to G w2
    ap = v - (v @ w0)[..., None] * w0
    bp = (Gw2 - value[:, None] * w0)[:, None, :]
    a = np.arctan2(np.sum((ap @ K0.T) * bp, axis=-1), np.sum(ap * bp, axis=-1))
    a = np.where(np.sum(ap * ap, axis=-1) < 1e-18, hint0, a)
    # c: what Rot(w1, -b) Rot(w0, -a) G does to a vector x across w2
    x = _cross(w2, w0 if abs(w0 @ w2) < 0.9 else w1)
    x /= np.linalg.norm(x)
    y = turn(w1, -b, turn(w0, -a, (G @ x)[:, None, :]))
    c = np.arctan2(y @ (skew(w2) @ x), y @ x)
    return np.stack([a, b, c], axis=-1)


# ---------------------------------------------------------------------------------------- the chain
@dataclass
class _Srs:
    S: np.ndarray               # shoulder centre (zero pose of the S-R-S dofs, in their base frame)
    W: np.ndarray               # wrist centre = the hand's origin at zero
    min_reach: float
    max_reach: float
    elbow_lo: float
    elbow_hi: float


@dataclass
class Arm:
    """The kinematic chain from the base to the hand, as products of exponentials at q = 0:
    dof k turns about axis[k] through point[k] (base frame), and the hand's frame at zero is
    (end_R, end_p). Built once per model and end body (`Arm.of`)."""
    model: Model
    end: int
    q_index: np.ndarray         # (n,) where each chain dof sits in q
    axis: np.ndarray            # (n, 3)
    point: np.ndarray           # (n, 3)
    end_R: np.ndarray
    end_p: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    srs: _Srs | None = None
    why_not_srs: str = ""
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, model: Model, end: str | None = None) -> "Arm":
        """The chain to `end` (a body name; default: a right hand, else the last body), cached."""
        per_model = _ARMS.setdefault(model, {})
        key = end or ""
        if key not in per_model:
            per_model[key] = cls._build(model, end)
        return per_model[key]

    @classmethod
    def _build(cls, model: Model, end: str | None) -> "Arm":
        names = model.body_names
        if end is None:
            hands = [n for n in names if n in ("r_hand", "right_hand", "hand")] or \
                    [n for n in names if "hand" in n.lower()]
            end = hands[0] if hands else names[-1]
        if end not in names:
            raise IkError(f"no body '{end}' in model '{model.name}' (bodies: {', '.join(names)})")
        path, i = [], names.index(end)
        while i >= 0:
            path.append(i)
            i = model.bodies[i].parent
        path.reverse()
        slices = model._coordinate_slices()
        for i in path:
            b = model.bodies[i]
            if b.free or b.ball:
                raise IkError(f"body '{b.name}': inverse kinematics needs hinge dofs from the base to "
                              f"'{end}' (a free root or ball joint is on the way)")
        # a zero-pose pass through the core's frames (as Model.body_poses) collecting each dof's axis
        a = model._arrays
        dof_rot = np.asarray(a["dof_rot"], dtype=float).reshape(-1, 3, 3)
        first_dof = np.cumsum([0] + [len(b.dofs) if not b.free else 6 for b in model.bodies])
        R_world, p_world = {}, {}
        axes, points, q_index, lower, upper = [], [], [], [], []
        for i in path:
            b = model.bodies[i]
            Rp, pp = (R_world[b.parent], p_world[b.parent]) if b.parent >= 0 else (np.eye(3), np.zeros(3))
            R = Rp @ np.asarray(a["rot"][i], dtype=float).reshape(3, 3)
            p = pp + Rp @ np.asarray(a["pos"][i], dtype=float)
            for k, dof in enumerate(b.dofs):
                R = R @ dof_rot[first_dof[i] + k]
                axes.append(R[:, 2].copy())
                points.append(p.copy())
                q_index.append(slices[i].start + k)
                lower.append(dof.lower)
                upper.append(dof.upper)
            R_world[i], p_world[i] = R, p
        if not axes:
            raise IkError(f"no dof between the base and '{end}' in model '{model.name}'")
        arm = cls(model=model, end=names.index(end), q_index=np.array(q_index), axis=np.array(axes),
                  point=np.array(points), end_R=R_world[path[-1]] @ model.frame_rot[path[-1]].T,
                  end_p=p_world[path[-1]].copy(), lower=np.array(lower), upper=np.array(upper))
        arm.srs, arm.why_not_srs = arm._find_srs()
        return arm

    @property
    def n(self) -> int:
        return len(self.q_index)

    @property
    def dof_names(self) -> tuple[str, ...]:
        names = self.model.q_names
        return tuple(names[k] for k in self.q_index)

    # ---------------------------------------------------------------- forward kinematics
    def _exp(self, k, angle):
        """The rotation of dof k by angle: rotations.axis_angle with the dofs' cross matrices kept
        from the first call (the inner loop of the iterative solve)."""
        if "K" not in self._cache:
            K = np.array([skew(w) for w in self.axis])
            self._cache["K"], self._cache["KK"] = K, K @ K
        return _EYE + math.sin(angle) * self._cache["K"][k] + (1 - math.cos(angle)) * self._cache["KK"][k]

    def forward(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Hand rotation and origin at chain angles x (n,), and each dof's world axis and pivot."""
        R, p = _EYE, np.zeros(3)
        axes, pivots = np.empty((self.n, 3)), np.empty((self.n, 3))
        for k in range(self.n):
            w, r = self.axis[k], self.point[k]
            axes[k] = R @ w
            pivots[k] = R @ r + p
            E = self._exp(k, float(x[k]))
            p = p + R @ (r - E @ r)
            R = R @ E
        return R @ self.end_R, R @ self.end_p + p, axes, pivots

    def hand(self, q) -> tuple[np.ndarray, np.ndarray]:
        """The hand's rotation and origin at the model's q."""
        x = np.asarray(q, dtype=float)[self.q_index]
        R, p = _EYE, np.zeros(3)
        for k in range(self.n):
            r = self.point[k]
            E = self._exp(k, float(x[k]))
            p = p + R @ (r - E @ r)
            R = R @ E
        return R @ self.end_R, R @ self.end_p + p

    def _elbow_axis(self, x) -> np.ndarray:
        """The elbow's axis (the 4th of the last seven dofs) at chain angles x, in the base frame."""
        R = _EYE
        for k in range(self.n - 4):
            R = R @ self._exp(k, float(x[k]))
        return R @ self.axis[self.n - 4]

    # ---------------------------------------------------------------- S-R-S structure
    def _find_srs(self) -> tuple[_Srs | None, str]:
        if self.n < 7:
            return None, f"{self.n} dofs to the hand, an S-R-S arm has 7"
        w, r = self.axis[-7:], self.point[-7:]

        def meet(ks):
            A = sum(np.eye(3) - np.outer(w[k], w[k]) for k in ks)
            c = np.linalg.lstsq(A, sum((np.eye(3) - np.outer(w[k], w[k])) @ r[k] for k in ks), rcond=None)[0]
            gap = max(np.linalg.norm(_cross(w[k], c - r[k])) for k in ks)
            return c, gap

        S, gap_s = meet((0, 1, 2))
        W, gap_w = meet((4, 5, 6))
        if gap_s > STRUCTURE_TOL:
            return None, f"the first three of the last seven axes miss one point by {gap_s:.2g} m"
        if gap_w > STRUCTURE_TOL:
            return None, f"the last three axes miss one point by {gap_w:.2g} m"
        if np.linalg.norm(W - self.end_p) > STRUCTURE_TOL:
            return None, "the hand's origin is not where the wrist axes meet"
        for k0, k1, k2, what in ((0, 1, 2, "shoulder"), (4, 5, 6, "wrist")):
            if min(np.linalg.norm(_cross(w[k0], w[k1])), np.linalg.norm(_cross(w[k1], w[k2]))) < 0.1:
                return None, f"the {what}'s middle axis runs nearly along another"
        we, re = w[3], r[3]
        u = (W - re) - we * (we @ (W - re))
        v = (S - re) - we * (we @ (S - re))
        if min(np.linalg.norm(u), np.linalg.norm(v)) < 1e-6:
            return None, "the elbow axis passes through the shoulder or the wrist"
        # reach over the elbow's range: |W(θ) - S| at the ends and where it is longest or shortest
        lo, hi = self.lower[-4], self.upper[-4]
        theta = np.linspace(max(lo, -math.pi), min(hi, math.pi), 2001)
        d = np.linalg.norm(turn(we, theta, np.broadcast_to(W - re, (len(theta), 3))) + re - S, axis=1)
        return _Srs(S=S, W=W, min_reach=float(d.min()), max_reach=float(d.max()),
                    elbow_lo=lo, elbow_hi=hi), ""

    def max_reach(self) -> float:
        if self.srs is not None:
            return self.srs.max_reach
        return float(sum(np.linalg.norm(np.diff(np.vstack([self.point, self.end_p]), axis=0), axis=1)))

    def _shoulder(self) -> np.ndarray:
        return self.srs.S if self.srs is not None else self.point[0]

    # ---------------------------------------------------------------- closed form
    def _prefix(self, x) -> tuple[np.ndarray, np.ndarray]:
        """The pose (R, p) the dofs before the S-R-S seven give the chain's frame at angles x."""
        R, p = _EYE, np.zeros(3)
        for k in range(self.n - 7):
            w, r = self.axis[k], self.point[k]
            E = self._exp(k, float(x[k]))
            p = p + R @ (r - E @ r)
            R = R @ E
        return R, p

    def _candidates(self, pos, rot, phi, x_prev):
        """Every branch at each swivel: angles (N, C, 7) of the S-R-S dofs (C ≤ 8)."""
        s, w, r = self.srs, self.axis[-7:], self.point[-7:]
        n_vec, d = pos - s.S, np.linalg.norm(pos - s.S)
        n_hat = n_vec / d
        # elbow: the law of cosines (Paden-Kahan subproblem 3 about the elbow axis)
        we, re = w[3], r[3]
        u, v = s.W - re, s.S - re
        up, vp = u - we * (we @ u), v - we * (we @ v)
        # the angle between u' and v' whose opposite side is the target's distance across the axis,
        # by half-angle tangents (exact at full stretch, where an arccos loses half the digits)
        a, b = np.linalg.norm(up), np.linalg.norm(vp)
        delta = math.sqrt(max(d * d - (we @ (u - v)) ** 2, 0.0))
        opposite = math.sqrt(max((delta - (a - b)) * (delta + (a - b)), 0.0))
        adjacent = math.sqrt(max((a + b - delta) * (a + b + delta), 0.0))
        spread = 2 * math.atan2(opposite, adjacent)
        theta0 = math.atan2(we @ _cross(up, vp), up @ vp)
        elbows = {theta0 + spread, theta0 - spread}
        # the swivel's reference: down (-z) across the shoulder-wrist line, or back (-x) along it
        ref = np.array([0.0, 0.0, -1.0]) - n_hat * -n_hat[2]
        if np.linalg.norm(ref) < 1e-9:
            ref = np.array([-1.0, 0.0, 0.0]) - n_hat * -n_hat[0]
        ref /= np.linalg.norm(ref)
        # elbow angles outside the elbow's limits are no branch (unless both are: then the least bad)
        elbows = sorted(elbows)
        lo, hi = self.lower[-4], self.upper[-4]
        wrapped = [t + 2 * math.pi * round(((lo + hi) / 2 - t) / (2 * math.pi)) if math.isfinite(lo + hi) else t
                   for t in elbows]
        inside = [t for t, tw in zip(elbows, wrapped) if lo - TOL_LIMIT <= tw <= hi + TOL_LIMIT]
        elbows = inside or elbows
        phi = np.asarray(phi, dtype=float)
        N, ne = len(phi), len(elbows)
        Rs, E3s = np.empty((ne, N, 3, 3)), np.empty((ne, 3, 3))
        for e, t3 in enumerate(elbows):
            E3 = E3s[e] = axis_angle(we, t3)
            s0 = (E3 @ (s.W - re) + re) - s.S
            s0 /= np.linalg.norm(s0)
            # the smallest rotation taking s0 onto n, then the swivel about n
            axis = _cross(s0, n_hat)
            sin_a, cos_a = np.linalg.norm(axis), float(s0 @ n_hat)
            if sin_a < 1e-12:
                axis = _cross(s0, we if abs(s0 @ we) < 0.9 else w[0])
                sin_a = 0.0
            R_min = axis_angle(axis, math.atan2(sin_a, cos_a))
            bend = _cross(n_hat, R_min @ we)
            phi0 = math.atan2(_cross(ref, bend) @ n_hat, ref @ bend)
            Rs[e] = axis_angle(n_hat, phi - phi0) @ R_min
        Rs = Rs.reshape(ne * N, 3, 3)
        shoulder = _euler(Rs, w[0], w[1], w[2], x_prev[0])                  # (ne N, 2, 3)
        if rot is not None:
            E3n = np.repeat(E3s, N, axis=0)
            Rw = np.swapaxes(Rs @ E3n, 1, 2) @ (rot @ self.end_R.T)           # E3ᵀ Rsᵀ R end_Rᵀ
            wrist = _euler(Rw, w[4], w[5], w[6], x_prev[4])                 # (ne N, 2, 3)
        else:
            wrist = np.broadcast_to(x_prev[4:7], (ne * N, 1, 3))
        ns, nw = shoulder.shape[1], wrist.shape[1]
        c = np.empty((ne, N, ns, nw, 7))
        c[..., 0:3] = shoulder.reshape(ne, N, ns, 1, 3)
        c[..., 3] = np.array(elbows)[:, None, None, None]
        c[..., 4:7] = wrist.reshape(ne, N, 1, nw, 3)
        return c.transpose(1, 0, 2, 3, 4).reshape(N, ne * ns * nw, 7)

    def _fit(self, cand, x_prev):
        """Wrap each angle to the turn nearest its range (or x_prev); the largest limit excess."""
        lo, hi = self.lower[-7:], self.upper[-7:]
        mid = np.where(np.isfinite(lo) & np.isfinite(hi), (lo + hi) / 2, x_prev)
        cand = cand + 2 * math.pi * np.round((mid - cand) / (2 * math.pi))
        excess = np.maximum(np.maximum(lo - cand, cand - hi), 0.0).max(axis=-1)
        return cand, excess

    def _pick(self, pos, rot, phi, x_prev, x_ref):
        """The in-limit branch nearest x_ref at each swivel: (angles (N, 7), excess (N,))."""
        cand, excess = self._fit(self._candidates(pos, rot, phi, x_prev), x_prev)
        cost = np.sum((cand - x_ref) ** 2, axis=-1) + 1e6 * np.maximum(excess - TOL_LIMIT, 0.0)
        best = np.argmin(cost, axis=1)
        rows = np.arange(len(phi))
        return cand[rows, best], excess[rows, best]

    def swivel_of(self, x) -> float:
        """The swivel (rad) of the S-R-S arm at chain angles x."""
        R, p, axes, pivots = self.forward(x)
        Rp, pp = self._prefix(x)
        S = Rp @ self.srs.S + pp
        return self._swivel_at(Rp.T @ (p - S), Rp.T @ axes[-4])

    def _swivel_at(self, n_vec, elbow_axis) -> float:
        n_hat = n_vec / np.linalg.norm(n_vec)
        ref = np.array([0.0, 0.0, -1.0]) - n_hat * -n_hat[2]
        if np.linalg.norm(ref) < 1e-9:
            ref = np.array([-1.0, 0.0, 0.0]) - n_hat * -n_hat[0]
        ref /= np.linalg.norm(ref)
        bend = _cross(n_hat, elbow_axis)
        return math.atan2(_cross(ref, bend) @ n_hat, ref @ bend)

    def solve_srs(self, x_prev, pos, rot, swivel, cold):
        """Closed form; (x, swivel) or an IkError."""
        s = self.srs
        Rp, pp = self._prefix(x_prev)
        pos_l = Rp.T @ (pos - pp)
        rot_l = None if rot is None else Rp.T @ rot
        d = float(np.linalg.norm(pos_l - s.S))
        if d > s.max_reach * (1 + TOL_REACH) or d < s.min_reach * (1 - TOL_REACH):
            far = d > s.max_reach
            raise OutOfReach(f"out of reach: the target is {d:.3f} m from the shoulder, the arm reaches "
                             + (f"{s.max_reach:.3f} m" if far else
                                f"no nearer than {s.min_reach:.3f} m within the elbow's limits"))
        tail = x_prev[-7:]
        x_ref = tail if not cold else np.clip(np.zeros(7), self.lower[-7:], self.upper[-7:])
        if swivel is not None:
            phis = np.array([float(swivel)])
        else:
            if cold:
                preferred = 0.0
            else:
                # keep the elbow's previous bending direction, as seen across the new line
                preferred = self._swivel_at(pos_l - s.S, Rp.T @ self._elbow_axis(x_prev))
            phis = np.array([preferred])
        if cold and swivel is None:
            return self._search_swivel(pos_l, rot_l, float(phis[0]), tail, x_ref)
        x, excess = self._pick(pos_l, rot_l, phis, tail, x_ref)
        if excess[0] <= TOL_LIMIT:
            return x[0], float(phis[0])
        if swivel is not None:
            raise NoSwivel(f"no solution inside the limits at swivel {math.degrees(swivel):.1f}°")
        return self._search_swivel(pos_l, rot_l, float(phis[0]), tail, x_ref)

    def _search_swivel(self, pos, rot, preferred, x_prev, x_ref):
        """The in-limit swivel nearest `preferred`: a grid round the circle, then finer grids
        between the nearest in-limit swivel and the preferred one (or round the least excess)."""
        phis = preferred + np.linspace(0.0, 2 * math.pi, GRID, endpoint=False)
        x, excess = self._pick(pos, rot, phis, x_prev, x_ref)
        ok = excess <= TOL_LIMIT
        if ok[0]:
            return x[0], preferred
        if not ok.any():
            # none inside: look closer round the three least bad swivels
            for k in np.argsort(excess)[:3]:
                for width in (2 * math.pi / GRID, 2 * math.pi / GRID / 16):
                    fine = phis[k] + np.linspace(-width, width, 33)
                    xf, ef = self._pick(pos, rot, fine, x_prev, x_ref)
                    k_best = int(np.argmin(ef))
                    phis[k], excess[k], x[k] = fine[k_best], ef[k_best], xf[k_best]
                    if ef[k_best] <= TOL_LIMIT:
                        return xf[k_best], float(fine[k_best])
            raise NoSwivel("no swivel inside the limits: every elbow position about the shoulder-wrist line "
                           "puts a joint past its limit")
        signed = np.angle(np.exp(1j * (phis - preferred)))
        k = int(np.argmin(np.where(ok, np.abs(signed), np.inf)))
        # close in on the edge of the in-limit range from the preferred swivel's side, between the
        # in-limit grid swivel and its neighbour towards the preferred one (to 1/16 of a step, 0.3°)
        step = 2 * math.pi / GRID
        far = preferred + signed[k]
        fine = np.linspace(far - math.copysign(step, signed[k]), far, 17)
        xf, ef = self._pick(pos, rot, fine, x_prev, x_ref)
        inside = np.flatnonzero(ef <= TOL_LIMIT)
        if not len(inside):                                   # (the last is the grid's swivel: inside)
            return x[k], float(phis[k])
        return xf[inside[0]], float(fine[inside[0]])

    # ---------------------------------------------------------------- damped least squares
    def solve_dls(self, x0, pos, rot, lower=None, upper=None, iterations=100):
        """Bounded damped least squares from x0; (x, iterations, converged)."""
        from scipy.optimize import lsq_linear      # half a second to import: only the fallback needs it
        lower = self.lower if lower is None else lower
        upper = self.upper if upper is None else upper
        x = np.clip(x0, lower, upper)
        lam = 1e-2

        def error(x):
            R, p, axes, pivots = self.forward(x)
            e = pos - p
            if rot is not None:
                e = np.concatenate([e, ROTATION_LENGTH * rotation_log(rot @ R.T)])
            return e, p, axes, pivots

        e, p, axes, pivots = error(x)
        for it in range(1, iterations + 1):
            J = _cross(axes, p - pivots).T
            if rot is not None:
                J = np.vstack([J, ROTATION_LENGTH * axes.T])
            A = np.vstack([J, lam * np.eye(self.n)])
            b = np.concatenate([e, np.zeros(self.n)])
            lo, hi = lower - x, upper - x
            step = lsq_linear(A, b, bounds=(np.minimum(lo, -0.0), np.maximum(hi, 0.0)), method="bvls").x
            x_new = np.clip(x + step, lower, upper)
            e_new, p_new, axes_new, pivots_new = error(x_new)
            if np.linalg.norm(e_new) < np.linalg.norm(e):
                x, e, p, axes, pivots = x_new, e_new, p_new, axes_new, pivots_new
                lam = max(lam * 0.3, 1e-9)
            else:
                lam = min(lam * 10, 1e3)
                if lam >= 1e3:
                    break
            if np.linalg.norm(e) < TOL_DLS:
                return x, it, True
        return x, it, bool(np.linalg.norm(e) < TOL_DLS)


_ARMS: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()


# -------------------------------------------------------------------------------------- the API
def _target(position, rotation):
    try:
        pos = np.asarray(position, dtype=float)
    except (TypeError, ValueError):
        pos = np.array([math.nan])
    if pos.shape != (3,) or not np.all(np.isfinite(pos)):
        raise IkError(f"the target position must be three finite numbers (m), got {position!r}")
    if rotation is None:
        return pos, None
    try:
        rot = np.asarray(rotation, dtype=float)
    except (TypeError, ValueError):
        rot = np.array([math.nan])
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)) or \
            np.abs(rot @ rot.T - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) < 0:
        raise IkError("the target rotation must be a 3 x 3 rotation matrix")
    u, _, vt = np.linalg.svd(rot)
    return pos, u @ vt


def solve(model: Model, position, rotation=None, q_prev=None, swivel: float | None = None,
          end: str | None = None, method: str = "auto", restarts: int = 12, seed: int = 0) -> IkResult:
    """Joint angles that put the hand (the origin of body `end`) at `position` (m, base frame)
    and, if given, its frame at `rotation` (3 x 3, base ← hand), inside the joint limits.

    q_prev: the pose to stay near (branch, swivel, and the dofs that do not move); None is a cold
    solve. swivel: the elbow's swivel in rad (S-R-S arms; None: keep q_prev's or the nearest to 0
    inside the limits). method: "auto", "srs" (closed form only) or "dls" (least squares only).
    Raises OutOfReach, NoSwivel or IkError.
    """
    if method not in ("auto", "srs", "dls"):
        raise IkError(f"method must be 'auto', 'srs' or 'dls', got {method!r}")
    arm = Arm.of(model, end)
    pos, rot = _target(position, rotation)
    cold = q_prev is None
    q = model.neutral_q() if cold else np.array(q_prev, dtype=float)
    if q.shape != (model.nq,) or not np.all(np.isfinite(q)):
        raise IkError(f"q_prev must be {model.nq} finite numbers")
    x_prev = q[arm.q_index]
    if swivel is not None and not math.isfinite(float(swivel)):
        raise IkError(f"the swivel must be a finite angle, got {swivel!r}")
    if method == "srs" and arm.srs is None:
        raise IkError(f"model '{model.name}': no closed form: {arm.why_not_srs}")
    Rp, pp = arm._prefix(x_prev) if arm.srs is not None else (_EYE, np.zeros(3))
    reach_m = float(np.linalg.norm(pos - (Rp @ arm._shoulder() + pp)))
    refusal = None
    x, phi, how, iterations = None, math.nan, "srs", 0
    if arm.srs is not None and method != "dls":
        try:
            x_tail, phi = arm.solve_srs(x_prev, pos, rot, swivel, cold)
            x = x_prev.copy()
            x[-7:] = x_tail
        except IkError as err:
            # the closed form holds the dofs before the shoulder: least squares may still move them
            if method == "srs" or swivel is not None or (arm.n == 7 and isinstance(err, OutOfReach)):
                raise
            refusal = err
    if x is None:
        if arm.n == 7 and arm.srs is not None and reach_m > arm.max_reach() * (1 + TOL_REACH):
            raise OutOfReach(f"out of reach: the target is {reach_m:.3f} m from the shoulder, the arm "
                             f"reaches {arm.max_reach():.3f} m")
        how = "dls"
        rng = np.random.default_rng(seed)
        starts = [x_prev] + [rng.uniform(np.maximum(arm.lower, -math.pi), np.minimum(arm.upper, math.pi))
                             for _ in range(restarts if cold or refusal is not None else 0)]
        for start in starts:
            x, n_it, ok = arm.solve_dls(start, pos, rot)
            iterations += n_it
            if ok:
                break
        else:
            if refusal is not None:
                raise refusal
            if reach_m > arm.max_reach():
                raise OutOfReach(f"out of reach: the target is {reach_m:.3f} m from the shoulder, the arm "
                                 f"reaches {arm.max_reach():.3f} m")
            raise NoSwivel("no pose inside the limits reaches the target (least squares from "
                           f"{len(starts)} starts left {np.linalg.norm(arm.hand(_put(q, arm, x))[1] - pos) * 1e3:.1f} mm)")
        if arm.srs is not None:
            phi = arm.swivel_of(x)
    x = np.clip(x, arm.lower, arm.upper)
    q = _put(q, arm, x)
    R, p = arm.hand(q)
    return IkResult(q=q, position_error=float(np.linalg.norm(p - pos)),
                    rotation_error=0.0 if rot is None else float(rotation_angle(R @ rot.T)),
                    reach=reach_m / arm.max_reach(), reach_m=reach_m, swivel=float(phi), method=how,
                    iterations=iterations)


def _put(q, arm, x):
    q = np.array(q, dtype=float)
    q[arm.q_index] = x
    return q


def solve_path(model: Model, positions, rotations=None, q0=None, dt: float = 0.01,
               max_speed: float | np.ndarray | None = None, swivel: float | None = None,
               end: str | None = None, progress=None) -> PathResult:
    """A hand path: one solve per sample, each from the previous pose (so the swivel and the
    branches carry on), the first one cold unless q0 is given.

    positions (N, 3) m; rotations (N, 3, 3) or None; dt s between samples; max_speed rad/s (one
    number or one per dof of the model): a step that would turn a dof faster is replaced by the
    pose nearest the target within the step's bounds (the limits and ±max_speed·dt, by bounded
    least squares), and the sample is marked `slowed`. A sample out of reach or without a swivel
    in the limits raises, naming the sample. progress(i, N), if given, is called after each sample.
    """
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise IkError(f"positions must have shape (N, 3), got {positions.shape}")
    if rotations is not None:
        rotations = np.asarray(rotations, dtype=float)
        if rotations.shape != (len(positions), 3, 3):
            raise IkError(f"rotations must have shape ({len(positions)}, 3, 3), got {rotations.shape}")
    if not (dt > 0 and math.isfinite(dt)):
        raise IkError(f"dt must be a positive number of seconds, got {dt}")
    arm = Arm.of(model, end)
    step = None
    if max_speed is not None:
        speed = np.broadcast_to(np.asarray(max_speed, dtype=float), (model.nv,))
        if not np.all(speed > 0):
            raise IkError("max_speed must be positive (rad/s)")
        step = speed[arm.q_index] * dt
    N = len(positions)
    out = PathResult(q=np.empty((N, model.nq)), position_error=np.empty(N), rotation_error=np.empty(N),
                     swivel=np.empty(N), slowed=np.zeros(N, dtype=bool), reach=np.empty(N))
    q = q0
    for i in range(N):
        rot = None if rotations is None else rotations[i]
        try:
            r = solve(model, positions[i], rot, q_prev=q, swivel=swivel, end=end)
        except IkError as err:
            raise type(err)(f"sample {i + 1} of {N}: {err}") from None
        q_new = r.q
        if step is not None and q is not None:
            x_prev = np.asarray(q, dtype=float)[arm.q_index]
            x_new = q_new[arm.q_index]
            if np.any(np.abs(x_new - x_prev) > step * (1 + 1e-9)):
                lo = np.maximum(arm.lower, x_prev - step)
                hi = np.minimum(arm.upper, x_prev + step)
                x, _, _ = arm.solve_dls(np.clip(x_new, lo, hi), positions[i], rot, lo, hi, 30)
                q_new = _put(q, arm, x)
                R, p = arm.hand(q_new)
                r = IkResult(q=q_new, position_error=float(np.linalg.norm(p - positions[i])),
                             rotation_error=0.0 if rot is None else float(rotation_angle(R @ rot.T)),
                             reach=r.reach, reach_m=r.reach_m,
                             swivel=arm.swivel_of(x) if arm.srs is not None else math.nan, method="dls")
                out.slowed[i] = True
        out.q[i], out.position_error[i], out.rotation_error[i] = r.q, r.position_error, r.rotation_error
        out.swivel[i], out.reach[i] = r.swivel, r.reach
        q = r.q
        if progress is not None:
            progress(i + 1, N)
    return out


__all__ = ["Arm", "IkError", "IkResult", "NoSwivel", "OutOfReach", "PathResult", "solve", "solve_path"]
