"""The rotation arithmetic of servodyn.model.rotations, the package's one copy, against SciPy's
Rotation as the independent reference: exact angles near 0 and near a half turn, where an arccos
of the trace loses half the digits."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from servodyn.model.rotations import axis_angle, rotation_angle, rotation_log, skew, turn

# near 0 and near π the reference angle itself is good to a few ulps of π
EXACT = 4e-15


def _axes(rng, n):
    a = rng.normal(size=(n, 3))
    return a / np.linalg.norm(a, axis=1, keepdims=True)


@pytest.mark.parametrize("angles", [
    np.array([1e-12, 3e-9, 1e-7, 1e-4, 0.0]),                         # near 0
    np.pi - np.array([1e-12, 3e-9, 1e-7, 1e-4, 0.0]),                 # near a half turn
    np.linspace(0.01, np.pi - 0.01, 9),                               # in between
], ids=["near-0", "near-pi", "between"])
def test_rotation_angle_is_exact_where_arccos_is_not(angles):
    rng = np.random.default_rng(3)
    axes = _axes(rng, len(angles))
    R = Rotation.from_rotvec(axes * angles[:, None])
    matrices = R.as_matrix()
    expected = R.magnitude()
    got = rotation_angle(matrices)
    assert got.shape == angles.shape, "one angle per matrix"
    assert np.max(np.abs(got - expected)) <= EXACT, f"worst {np.max(np.abs(got - expected)):.1e} rad"
    for M, e in zip(matrices, expected):
        assert abs(float(rotation_angle(M)) - e) <= EXACT, "a single matrix gives the same angle"
    if angles[0] == 1e-12:
        # the arccos of the trace: 1 - 1e-24/2 rounds to 1, the angle to 0 (or ~1e-8 off)
        naive = np.arccos(np.clip((np.trace(matrices, axis1=1, axis2=2) - 1) / 2, -1, 1))
        assert abs(naive[0] - angles[0]) > 1e-13, "the form this module replaces is not exact here"


def test_axis_angle_and_log_are_scipys_rotvec():
    """Rodrigues (one angle and a batch), its inverse, the vector form and the cross matrix agree
    with SciPy to 1e-15 per entry on random axes and angles over a whole turn, half turns included."""
    rng = np.random.default_rng(4)
    axes = _axes(rng, 40)
    angles = np.concatenate([rng.uniform(-np.pi, np.pi, 36), [np.pi, -np.pi, 1e-10, 0.0]])
    for axis, angle in zip(axes, angles):
        expected = Rotation.from_rotvec(axis * angle).as_matrix()
        assert np.max(np.abs(axis_angle(axis * 7.0, angle) - expected)) <= 1e-15, "any length of axis"
        log = rotation_log(expected)
        back = Rotation.from_rotvec(log).as_matrix()
        assert np.max(np.abs(back - expected)) <= 1e-14, f"log inverts axis_angle at {angle:.3g} rad"
        v = rng.normal(size=3)
        assert np.max(np.abs(skew(axis) @ v - np.cross(axis, v))) <= 1e-15, "skew(a) v = a x v"
    batch = axis_angle(axes[0], angles)
    assert batch.shape == (40, 3, 3), "a batch of angles gives a batch of matrices"
    expected = Rotation.from_rotvec(axes[0] * angles[:, None]).as_matrix()
    assert np.max(np.abs(batch - expected)) <= 1e-15, "batch equals SciPy"
    vectors = rng.normal(size=(40, 3))
    turned = turn(axes[0], angles, vectors)
    assert np.max(np.abs(turned - np.einsum("fij,fj->fi", expected, vectors))) <= 1e-14, \
        "turn(v) = axis_angle @ v"
