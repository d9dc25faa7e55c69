"""The kinematic chain inverse kinematics works on: the dofs from the base to the hand as products of
exponentials at q = 0, built once per model and end body, with its forward kinematics; the
refusals (`IkError`, `OutOfReach`, `NoSwivel`) and the S-R-S structure's numbers (`_Srs`).
The solvers are mixed in by `ik.Arm` (ik_srs.ClosedForm, ik_dls.LeastSquares)."""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np

from .rotations import skew
from .tree import Model, ModelError


class IkError(ModelError):
    """Inverse kinematics refused a target; the message is one line and says why."""


class OutOfReach(IkError):
    """The target is farther from the shoulder than the arm reaches (or nearer than it folds)."""
    exit_code = 1       # a refusal, not bad input


class NoSwivel(IkError):
    """The target is within reach, but every arm pose reaching it has a joint outside its limits."""
    exit_code = 1       # a refusal, not bad input


_EYE = np.eye(3)


def _cross(a, b):
    """a x b over the last axis, broadcasting (numpy's cross costs ten times more on small arrays)."""
    a, b = np.asarray(a), np.asarray(b)
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


@dataclass
class _Srs:
    S: np.ndarray               # shoulder centre (zero pose of the S-R-S dofs, in their base frame)
    W: np.ndarray               # wrist centre = the hand's origin at zero
    min_reach: float
    max_reach: float
    elbow_lo: float
    elbow_hi: float


@dataclass
class Chain:
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
    def of(cls, model: Model, end: str | None = None) -> "Chain":
        """The chain to `end` (a body name; default: a right hand, else the last body), cached."""
        per_model = _ARMS.setdefault(model, {})
        key = end or ""
        if key not in per_model:
            per_model[key] = cls._build(model, end)
        return per_model[key]

    @classmethod
    def _build(cls, model: Model, end: str | None) -> "Chain":
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

    def max_reach(self) -> float:
        if self.srs is not None:
            return self.srs.max_reach
        return float(sum(np.linalg.norm(np.diff(np.vstack([self.point, self.end_p]), axis=0), axis=1)))

    def _shoulder(self) -> np.ndarray:
        return self.srs.S if self.srs is not None else self.point[0]

    # ---------------------------------------------------------------- before the S-R-S seven
    def _prefix(self, x) -> tuple[np.ndarray, np.ndarray]:
        """The pose (R, p) the dofs before the S-R-S seven give the chain's frame at angles x."""
        R, p = _EYE, np.zeros(3)
        for k in range(self.n - 7):
            w, r = self.axis[k], self.point[k]
            E = self._exp(k, float(x[k]))
            p = p + R @ (r - E @ r)
            R = R @ E
        return R, p


_ARMS: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()
