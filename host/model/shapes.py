"""Triangle meshes of the paper's solid primitives, for drawing a model (the browser view) and for
the URDF export's visual geometry. A mesh is in the solid's own frame (`local_mesh`) or placed in
its body's user frame (`solid_mesh`); the dimensions mean what they mean for the inertia
(tree.Solid)."""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np


BOX_FROM_ELLIPSOID = math.sqrt(12.0 / 5.0)   # a box of sides s and an ellipsoid of semi-axes
#                                              s·sqrt(5/12) have the same inertia for one mass


@dataclass(frozen=True)
class Solid:
    """One of the paper's primitives as the body carries it, for drawing: `kind` and `dims` as in a
    model file (cylinder (radius, length) and frustum (r0, r1, length) run from the solid's origin
    along its +z; sphere (radius,) and ellipsoid (a, b, c) are centred on it), placed at `pos` with
    rotation `rot` in the body's user frame."""
    kind: str
    dims: tuple[float, ...]
    pos: np.ndarray
    rot: np.ndarray
    mass: float = 0.0
    draw: str = ""            # "box": an ellipsoid that stands for a box of the same inertia (a servo)



def box_sides(solid: Solid) -> np.ndarray:
    """The sides of the box an ellipsoid drawn as a box stands for (a servo's housing)."""
    return np.asarray(solid.dims, dtype=float) * BOX_FROM_ELLIPSOID


def _revolved(radii: np.ndarray, z: np.ndarray, segments: int, closed_ends: bool):
    """A surface of revolution about z through rings (radius, height); caps where a ring has r > 0."""
    angles = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    vertices = [np.column_stack([r * ring, np.full(segments, h)]) for r, h in zip(radii, z)]
    faces = []
    for i in range(len(radii) - 1):
        a, b = i * segments, (i + 1) * segments
        for j in range(segments):
            k = (j + 1) % segments
            faces += [(a + j, a + k, b + k), (a + j, b + k, b + j)]
    V = np.concatenate(vertices)
    if closed_ends:
        bottom, top = len(V), len(V) + 1
        V = np.vstack([V, [0.0, 0.0, z[0]], [0.0, 0.0, z[-1]]])
        last = (len(radii) - 1) * segments
        for j in range(segments):
            k = (j + 1) % segments
            faces += [(bottom, k, j), (top, last + j, last + k)]
    return V, np.array(faces, dtype=np.int32)


def local_mesh(solid: Solid, segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3), faces (m, 3)) of the solid in its own frame, outward-facing."""
    kind, dims = solid.kind, solid.dims
    if kind == "ellipsoid" and solid.draw == "box":
        h = box_sides(solid) / 2
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) * h
        faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
                 (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
        return corners, np.array(faces, dtype=np.int32)
    if kind in ("cylinder", "frustum"):
        r0, r1, length = (dims[0], dims[0], dims[1]) if kind == "cylinder" else dims
        return _revolved(np.array([r0, r1]), np.array([0.0, length]), segments, closed_ends=True)
    if kind in ("sphere", "ellipsoid"):
        axes = np.array([dims[0]] * 3 if kind == "sphere" else dims, dtype=float)
        polar = np.linspace(0.0, math.pi, segments // 2 + 1)[1:-1]
        V, F = _revolved(np.sin(polar), -np.cos(polar), segments, closed_ends=False)
        south, north = len(V), len(V) + 1
        V = np.vstack([V, [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
        last = (len(polar) - 1) * segments
        caps = []
        for j in range(segments):
            k = (j + 1) % segments
            caps += [(south, k, j), (north, last + j, last + k)]
        return V * axes, np.vstack([F, np.array(caps, dtype=np.int32)])
    raise ValueError(f"unknown solid '{kind}'")


def solid_mesh(solid: Solid, segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """The solid's mesh in its body's user frame."""
    V, F = local_mesh(solid, segments)
    return np.asarray(solid.pos, dtype=float) + V @ np.asarray(solid.rot, dtype=float).T, F
