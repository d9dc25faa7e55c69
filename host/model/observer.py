"""The C core's generalized-momentum observer (firmware/core/include/sd_observer.h) on a model.

With p = M(q)q̇ and β = g(q) − C(q,q̇)ᵀq̇ (`Model.momentum`), the residual

    r = K_O [ p − p(0) − ∫ (τ_m − τ_f(q̇) − β + r) dt ]     obeys     ṙ = K_O (τ_ext − r)

so each joint's r is a first-order low-pass copy of the external torque at that joint, with no
acceleration measured (De Luca & Mattone 2005; Haddadin, De Luca, Albu-Schäffer, IEEE T-RO 2017).
The core discretizes the filter exactly, r_k = e^{−K_O Δt} r_{k−1} + (1 − e^{−K_O Δt}) τ̄_ext,k, with
the period's mean external torque from the momentum's change and the model's explanation of it
(trapezoidal). The motor torque given at a sample is the one that acted over the period ending
there (a servo's Present Current read with the position and velocity of the same packet).
"""

from __future__ import annotations

import numpy as np

from .. import _core, _core32


class MomentumObserver:
    """The core's observer for one model: `reset(q, qd)` then `step(q, qd, tau_m) -> r` each
    sample (or `run` over recorded arrays, in C).

    gain: K_O per dof (1/s), a scalar or (nv,); friction_coulomb (N m), friction_viscous (N m s/rad):
    the joint friction the model explains, F_c·tanh(q̇/friction_speed) + F_v·q̇ on the measured
    velocity, subtracted from the motor torque (the armature is already in M); lowpass: a one-pole
    low-pass on r (rad/s, scalar or per dof; None or 0: none), whose output `step`, `run` and
    `residual` give: the velocity quantum reaches r unfiltered, as K_O·M·δq̇."""

    def __init__(self, model, dt: float, gain, friction_coulomb=None, friction_viscous=None,
                 friction_speed: float = 0.0, lowpass=None, precision: str = "double"):
        n = model.nv
        self.model = model
        self.dt = float(dt)
        self.gain = np.broadcast_to(np.asarray(gain, dtype=float), (n,)).copy()
        friction = {name: np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()
                    for name, value in (("friction_coulomb", friction_coulomb),
                                        ("friction_viscous", friction_viscous),
                                        ("lowpass", lowpass)) if value is not None}
        observer_type = _core32.Observer if precision == "float" else _core.Observer
        self._c = observer_type(model._pick(precision), self.dt, self.gain,
                                friction_speed=float(friction_speed), **friction)

    def reset(self, q, qd) -> None:
        """Start (or restart after torque off) at the measured state: r = 0."""
        self._c.reset(q, qd)

    def step(self, q, qd, tau_m) -> np.ndarray:
        """One sample: the residual r (nv,) in N m."""
        return self._c.step(q, qd, tau_m)

    def run(self, q, qd, tau_m) -> np.ndarray:
        """The residual at every row of recorded (N, nq), (N, nv), (N, nv) arrays: reset at row 0
        (whose residual is 0), a step at each further row; row k's torque acted over the period
        that ends at row k."""
        return self._c.run(q, qd, tau_m)

    @property
    def residual(self) -> np.ndarray:
        return self._c.residual

    @property
    def tick(self) -> int:
        """Samples since reset (−1 before the first)."""
        return self._c.tick
