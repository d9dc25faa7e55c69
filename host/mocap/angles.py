"""Batched rotation arithmetic for captured motion: the smallest rotation between two directions,
signed angles about an axis, and the split of a rotation into three angles about given axes
(Davenport angles: Euler and Cardan angles are the cases where the axes are coordinate axes).
Rotations about an axis and the angle of a rotation are servodyn.model.rotations'.

Every function takes a leading frame axis; angles in radians."""

from __future__ import annotations

import numpy as np

from ..model.rotations import axis_angle, unit


def smallest_rotation(a, b) -> np.ndarray:
    """The rotation by the smallest angle that turns direction a onto direction b."""
    a, b = unit(a), unit(b)
    axis = np.cross(a, b)
    sin_t, cos_t = np.linalg.norm(axis), float(a @ b)
    if sin_t < 1e-12:
        if cos_t > 0:
            return np.eye(3)
        other = np.eye(3)[int(np.argmin(np.abs(a)))]      # half a turn about any perpendicular
        return axis_angle(np.cross(a, other), np.pi)
    return axis_angle(axis, np.arctan2(sin_t, cos_t))


def angle_about(axis, v, r) -> np.ndarray:
    """(F,) signed angle about `axis` that turns the (F, 3) vectors v towards r (their parts
    perpendicular to the axis)."""
    n = unit(axis)
    return np.arctan2(np.einsum("fi,i->f", np.cross(v, r), n), (v * r).sum(-1) - (v @ n) * (r @ n))


def split3(R: np.ndarray, n1, n2, n3) -> tuple[np.ndarray, np.ndarray]:
    """The two sets of angles (F, 3) with R = Rot(n1, a) Rot(n2, b) Rot(n3, c), for axes with
    n1 ⊥ n2 and n2 ⊥ n3 (R is (F, 3, 3)). b comes from n1·R·n3 = (n1·n3) cos b + n1·(n2×n3) sin b;
    the second set has the other b of the same value, and both give R exactly. At the lock
    (n3 turned onto ±n1) a and c are one angle: c is set to 0."""
    n1, n2, n3 = unit(n1), unit(n2), unit(n3)
    lam, mu = float(n1 @ np.cross(n2, n3)), float(n1 @ n3)
    value = np.einsum("i,fij,j->f", n1, R, n3)
    # value = mu cos b + lam sin b = rho cos(b - phi)
    rho, phi = np.hypot(mu, lam), np.arctan2(lam, mu)
    delta = np.arccos(np.clip(value / rho, -1.0, 1.0))
    sets = []
    for b in (phi + delta, phi - delta):
        b = (b + np.pi) % (2 * np.pi) - np.pi
        v = np.einsum("fij,j->fi", axis_angle(n2, b), n3)            # Rot(n2, b) n3
        r = np.einsum("fij,j->fi", R, n3)                        # = Rot(n1, a) v
        a = angle_about(n1, v, r)
        locked = np.linalg.norm(np.cross(v, n1), axis=-1) < 1e-9
        a = np.where(locked, 0.0, a)
        # c: Rot(n3, c) Rᵀ n1' = Rot(n2, -b) Rot(n1, -a) n1'... solved on the remainder
        rest = np.einsum("fji,fjk->fik", axis_angle(n1, a) @ axis_angle(n2, b), R)   # = Rot(n3, c)
        p = np.broadcast_to(np.cross(n3, np.eye(3)[int(np.argmin(np.abs(n3)))]), (len(R), 3))
        c = angle_about(n3, p, np.einsum("fij,fj->fi", rest, p))
        sets.append(np.stack([a, b, c], axis=-1))
    return sets[0], sets[1]
