"""Random valid models for differential tests and benchmarks: trees and chains of 1-3-dof joints
with arbitrary axes and placements and full (off-diagonal) inertias."""

from __future__ import annotations

import numpy as np

from .rotations import axis_angle
from .tree import Body, Dof, Model


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return axis_angle(rng.normal(size=3), rng.uniform(-np.pi, np.pi))


def random_inertia(rng: np.random.Generator, mass: float) -> np.ndarray:
    """A physical inertia about the com: principal moments from a random box, randomly rotated."""
    sides = rng.uniform(0.05, 0.4, size=3)
    principal = mass / 12.0 * np.array([sides[1]**2 + sides[2]**2, sides[0]**2 + sides[2]**2,
                                        sides[0]**2 + sides[1]**2])
    R = random_rotation(rng)
    return R @ np.diag(principal) @ R.T


def random_model(rng: np.random.Generator, ndof: int, chain: bool = False, name: str = "random",
                 max_joint_dof: int = 3) -> Model:
    """A model with exactly ndof dofs; each body's joint has 1..max_joint_dof dofs."""
    bodies: list[Body] = []
    remaining = ndof
    while remaining > 0:
        nd = int(min(remaining, rng.integers(1, max_joint_dof + 1)))
        remaining -= nd
        i = len(bodies)
        parent = i - 1 if chain else int(rng.integers(-1, i))
        mass = float(rng.uniform(0.5, 5.0))
        dofs = [Dof(f"j{i}_{k}", rng.normal(size=3), -4.0, 4.0) for k in range(nd)]
        bodies.append(Body(name=f"b{i}", parent=parent, pos=rng.uniform(-0.4, 0.4, size=3),
                           rot=random_rotation(rng), dofs=dofs, mass=mass,
                           com=rng.uniform(-0.2, 0.2, size=3), inertia=random_inertia(rng, mass)))
    return Model(bodies, name=name, gravity=(0.0, 0.0, -9.81))


def serial_chain(ndof: int, joint_dof: int = 1) -> Model:
    """A regular serial chain of 0.3 m cylinders-like links, for benchmarks."""
    rng = np.random.default_rng(ndof)
    bodies = []
    for i in range(0, ndof, joint_dof):
        nd = min(joint_dof, ndof - i)
        axes = [np.eye(3)[(i + k) % 3] for k in range(nd)]
        bodies.append(Body(name=f"link{len(bodies)}", parent=len(bodies) - 1,
                           pos=np.array([0.0, 0.0, 0.3 if bodies else 0.0]), rot=np.eye(3),
                           dofs=[Dof(f"q{i + k}", axes[k], -4.0, 4.0) for k in range(nd)], mass=1.0,
                           com=np.array([0.0, 0.0, 0.15]), inertia=random_inertia(rng, 1.0)))
    return Model(bodies, name=f"chain{ndof}")
