"""Rotation arithmetic, once for the package: roll-pitch-yaw, axis-angle (Rodrigues) and its inverse,
the angle of a rotation, quaternions, and frames aligned to an axis.

Angles come from atan2 rather than an arccos of the trace, so that they are exact near 0 and near a
half turn alike. The axis-angle forms take one angle or an array of them (a leading batch axis)."""

from __future__ import annotations

import math

import numpy as np


def rpy_to_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, then y, then z) to a rotation matrix Rz(y) Ry(p) Rx(r)."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def unit(v) -> np.ndarray:
    """v / |v|, scaled first so that no square overflows or underflows (an axis of 1e300 or
    1e-200 is a direction like any other)."""
    a = np.asarray(v, dtype=float)
    a = a / np.max(np.abs(a))
    return a / np.linalg.norm(a)


_EYE = np.eye(3)


def skew(v) -> np.ndarray:
    """The cross-product matrix of v: skew(v) @ x = v x x."""
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]], dtype=float)


def axis_angle(axis, angle) -> np.ndarray:
    """Rotation by `angle` about the direction `axis` (Rodrigues): (3, 3) for one angle, (..., 3, 3)
    for an array of angles (...)."""
    K = skew(unit(axis))
    a = np.asarray(angle, dtype=float)[..., None, None]
    return _EYE + np.sin(a) * K + (1 - np.cos(a)) * (K @ K)


def turn(axis, angle, v) -> np.ndarray:
    """The vectors v (..., 3) turned by angles (...) about the unit vector `axis` (Rodrigues on a
    vector, without building the matrix)."""
    w = np.asarray(axis, dtype=float)
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return v * c + (v @ skew(w).T) * s + w * ((v @ w)[..., None] * (1 - c))


def _vee(R) -> np.ndarray:
    """Twice the axial vector of the skew part of R (..., 3, 3): 2 sin(angle) axis."""
    return np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)


def rotation_angle(R) -> np.ndarray:
    """The angle (rad, 0..π) of a rotation matrix (3, 3), or of each of (..., 3, 3). From atan2 of the
    skew part's size and the trace: exact near 0 and near π, where an arccos of the trace is not."""
    R = np.asarray(R, dtype=float)
    return np.arctan2(np.linalg.norm(_vee(R), axis=-1) / 2, (np.trace(R, axis1=-2, axis2=-1) - 1) / 2)


def rotation_log(R) -> np.ndarray:
    """Axis times angle of a rotation matrix (3, 3): the inverse of axis_angle."""
    R = np.asarray(R, dtype=float)
    angle = float(rotation_angle(R))
    v = _vee(R)
    if angle < 1e-6:
        return v / 2
    if angle > math.pi - 1e-6:
        # near half a turn: the axis from the symmetric part
        axis = np.sqrt(np.clip((np.diag(R) + 1) / 2, 0, None))
        k = int(np.argmax(axis))
        axis[np.arange(3) != k] = (R[k] + R[:, k])[np.arange(3) != k] / (4 * axis[k])
        return axis / np.linalg.norm(axis) * angle * (1 if v @ axis >= 0 else -1)
    return v * angle / (2 * math.sin(angle))


def rot_z(angle) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def frame_with_z(axis) -> np.ndarray:
    """The smallest rotation M with M e_z = axis: a frame whose z axis is `axis`.

    It is the identity when the axis already is z, which keeps the core on its fast path.
    """
    a = unit(axis)
    z = np.array([0.0, 0.0, 1.0])
    cos_t = float(a @ z)
    if cos_t > 1 - 1e-15:
        return np.eye(3)
    if cos_t < -1 + 1e-15:
        return np.diag([1.0, -1.0, -1.0])  # half a turn about x
    v = np.cross(z, a)
    return axis_angle(v, np.arctan2(np.linalg.norm(v), cos_t))


def orthonormalize(R) -> np.ndarray:
    """The nearest rotation to R (polar decomposition), to clean rounding from parsed files."""
    u, _, vt = np.linalg.svd(np.asarray(R, dtype=float))
    M = u @ vt
    if np.linalg.det(M) < 0:
        u[:, -1] *= -1
        M = u @ vt
    return M


def quat_to_matrix(quat) -> np.ndarray:
    """world_R_body of a quaternion (x, y, z, w), normalized on the way."""
    x, y, z, w = (float(v) for v in quat)
    s = 2.0 / (x * x + y * y + z * z + w * w)
    return np.array([
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ])


def matrix_to_quat(R) -> np.ndarray:
    """The unit quaternion (x, y, z, w), w >= 0, of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    trace = np.trace(R)
    if trace > 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        quat = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        quat = np.zeros(4)
        quat[i] = s / 4
        quat[j] = (R[j, i] + R[i, j]) / s
        quat[k] = (R[k, i] + R[i, k]) / s
        quat[3] = (R[k, j] - R[j, k]) / s
    quat /= np.linalg.norm(quat)
    return quat if quat[3] >= 0 else -quat
