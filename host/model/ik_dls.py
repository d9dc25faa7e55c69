"""Damped least squares for any chain of hinges: the limits as box bounds (scipy's bounded least
squares on [J; λI] dx = [e; 0]). Mixed into `ik.Arm`."""

from __future__ import annotations

import numpy as np

from .ik_chain import _cross
from .rotations import rotation_log

TOL_DLS = 1e-11        # m and rad: the DLS stops below this error
ROTATION_LENGTH = 0.3  # m: an orientation error of 1 rad weighs as 0.3 m of position error in DLS


class LeastSquares:
    """The iterative solve of `ik.Arm` (on a `ik_chain.Chain`)."""

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
