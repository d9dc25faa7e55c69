"""Shared test helpers: the same model in servodyn and in Pinocchio, the independent oracle."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))


class PinocchioTwin:
    """A servodyn model exported to URDF and loaded by Pinocchio's own parser, with the map
    between the two joint orders (Pinocchio numbers joints depth-first, servodyn by body)."""

    def __init__(self, model, tmp_path: Path):
        import pinocchio as pin
        self.pin = pin
        path = tmp_path / f"{model.name}.urdf"
        model.to_urdf(path)
        self.model = pin.buildModelFromUrdf(str(path))
        self.model.gravity.linear = np.asarray(model.gravity)
        self.data = self.model.createData()
        assert self.model.nq == model.nq, "every exported joint must be one revolute dof"
        self.index = np.array([self.model.joints[self.model.getJointId(n)].idx_q for n in model.dof_names])
        # the Pinocchio joint that carries each servodyn body (its last dof)
        self.body_joint = [self.model.getJointId(b.dofs[-1].name) if b.dofs else None for b in model.bodies]

    def to_pin(self, x):
        out = np.zeros(len(self.index))
        out[self.index] = x
        return out

    def _call(self, algorithm, q, qd, x, f_ext):
        """Pinocchio's algorithm on servodyn-ordered arrays; wrenches go to each body's last joint."""
        args = [self.model, self.data, self.to_pin(q), self.to_pin(qd), self.to_pin(x)]
        if f_ext is not None:
            fext = [self.pin.Force.Zero() for _ in range(self.model.njoints)]
            for body, jid in enumerate(self.body_joint):
                assert jid is not None or not np.any(f_ext[body]), "welded bodies take no wrench here"
                if jid is not None:
                    fext[jid] = self.pin.Force(f_ext[body, 3:], f_ext[body, :3])
            args.append(fext)
        return algorithm(*args)[self.index]

    def rnea(self, q, qd, qdd, f_ext=None):
        return self._call(self.pin.rnea, q, qd, qdd, f_ext)

    def aba(self, q, qd, tau, f_ext=None):
        return self._call(self.pin.aba, q, qd, tau, f_ext)


@pytest.fixture
def twin(tmp_path):
    return lambda model: PinocchioTwin(model, tmp_path)


def rel_err(a, b) -> float:
    """max |a - b| relative to max |b| (floored at 1e-12 so exact zeros compare absolutely)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-12))


def random_state(rng, model, scale_qd=2.0, scale_qdd=5.0):
    n = model.nq
    lo = np.maximum(model.lower, -3.0)
    hi = np.minimum(model.upper, 3.0)
    return rng.uniform(lo, hi), rng.normal(size=n) * scale_qd, rng.normal(size=n) * scale_qdd
