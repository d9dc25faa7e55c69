"""The description a model is built from: a body (`Body`) with its joint's dofs (`Dof`), the
coordinate names of a free root and a ball joint, rigid parts combined into one body
(`combine`), and the error for a description that cannot be built (`ModelError`). The tree
that compiles them is tree.Model."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ServodynError
from .shapes import Solid


class ModelError(ServodynError, ValueError):
    """A model description that cannot be built; the message names the body or key."""


@dataclass
class Dof:
    name: str
    axis: np.ndarray
    lower: float = -math.inf
    upper: float = math.inf
    armature: float = 0.0     # kg m², inertia turning with this dof alone: rotor inertia x gear ratio²
    motor: str = ""           # the part (parts.toml) that drives it and brings its armature, if named


def combine(parts: list[tuple[float, np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, com and inertia about the com of rigidly joined parts (mass, com, inertia about own com)."""
    mass = sum(m for m, _, _ in parts)
    if mass <= 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, I in parts:
        d = c - com
        inertia += I + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


@dataclass
class Body:
    name: str
    parent: int                                   # -1 for the fixed base
    pos: np.ndarray                               # joint origin in the parent's user frame (m)
    rot: np.ndarray                               # parent_R_body at q = 0, before post
    dofs: list[Dof] = field(default_factory=list)
    mass: float = 0.0                             # kg
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))           # user frame (m)
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # about the com
    post: np.ndarray = field(default_factory=lambda: np.eye(3))
    free: bool = False                            # floats free: 6 dofs (only body 0, on the base)
    ball: bool = False                            # a ball joint: 3 dofs, quaternion coordinates
    solids: list[Solid] = field(default_factory=list)   # its shape, user frame (drawing only)


FREE_DOFS = ("vx", "vy", "vz", "wx", "wy", "wz")   # velocity of the origin, then angular, body frame
FREE_COORDS = ("x", "y", "z", "qx", "qy", "qz", "qw")  # origin in the base frame, unit quaternion
BALL_DOFS = ("wx", "wy", "wz")                   # angular velocity in the body frame
BALL_COORDS = ("qx", "qy", "qz", "qw")           # unit quaternion of the body in its joint frame
