"""Contact detection on the momentum observer: detection, isolation and the contact force.

The residual r of the C core's observer (`servodyn.model.MomentumObserver`) is each joint's
external torque through k/(s+k) and a low-pass. A contact is declared when some |r_j| stays above its threshold

    θ_j(t) = θ_static,j + d_j(t)

for `debounce` samples in a row, once the observer is armed. θ_static comes from clean motions
(`thresholds_from_clean`, margin × the largest |r_j| seen); d_j(t) is what the model's
uncertainty allows at the present state (`Uncertainty`): the velocity resolution, which enters r
as K_O·M(q)·δq̇ before the low-pass (times the low-pass's peak response to it); the torque
resolution; and, through the observer's own low-pass, the inverse-dynamics error the
identification's standard errors allow, |Y(q, q̇, q̈)|·σ_π plus the friction's, and the Coulomb step
the model smooths near a velocity reversal (where the true friction is anywhere in ±F_c).

Isolation: the force of a contact on link k reaches only the joints between the base and k, so
the last joint with a residual over its threshold names the link (its child body). Proximal joints
cross first (longer lever arms), so the link and the force are refined every sample for `settle`
seconds after the detection (2/K_O + 2/low-pass, 40 ms by default: r then holds 91 % of a step). The force is the
least-squares F with J(q)ᵀF = r over the joints up to that link, J the Jacobian of the link's centre
of mass (world frame), from the core's inverse dynamics with unit forces there.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from ..model import MomentumObserver
from .controller import FRICTION_SPEED

# 1/s and rad/s: the residual's bandwidth K_O and the low-pass after it, two equal poles (r then
# reaches 1 − (1 + x)e⁻ˣ of a step at x = 100 t: 26 % at 10 ms, 59 % at 20 ms, 91 % at 40 ms). The velocity quantum
# enters r unfiltered as K_O·M·δq̇ (0.31 N m per Dynamixel velocity unit at the replica's shoulder at
# K_O 50), the external torque through K_O/(s + K_O) already: the low-pass averages the quantum's
# noise over ~10 ticks. On the replica with Dynamixel quantization (tools/bench/contact.py, 20 pushes
# per force) the clean-swing thresholds fell from 0.77 to 0.28 N m at the shoulder against K_O 50
# alone, the 10 N P95 delay from 11.8 to 10.7 ms, and 3 N was detected within 50 ms in 100 % of the
# pushes instead of 90 %; K_O/low-pass of 100/60, 150/100 and 200/70 did no better.
DEFAULT_GAIN = 100.0
DEFAULT_LOWPASS = 100.0
# thresholds_from_clean: θ = margin × the largest |r| of the clean runs. 1.2 over 10 swings gave
# 0-1 false alarms in 100 further swings in the prototype (the residual's peaks over a swing vary
# by ~10 % from run to run with the sensors' noise); larger costs sensitivity one for one.
DEFAULT_MARGIN = 1.2
# N m: the static threshold of an observer given none — no calibration yet. Calibrated on clean
# forehands the replica's are 0.07-0.28 N m (Dynamixel sensors, masses 10 % off, the defaults above);
# an uncalibrated arm also carries what no clean run of the model shows (a racket, friction): 1 N m,
# a 2-4 N push at the hand, the Dynamixel servos' torque resolution times 150-200.
DEFAULT_THRESHOLD_NM = 1.0
# samples in a row over the threshold: one isolated sample over it is the velocity quantum's (it
# passes r unfiltered); two cost one period (1 ms at 1 kHz)
DEFAULT_DEBOUNCE = 2
# the uncertainty's coverage: standard errors × 3
COVERAGE = 3.0
# s: how often the velocity resolution's term K_O·|M(q)|·δq̇/2 is recomputed
MASS_MATRIX_EVERY_S = 0.01
# singular values of J below this fraction of the largest are dropped from the force's solution
RCOND = 1e-2


@dataclass(frozen=True)
class Uncertainty:
    """What the model and the sensors leave unknown, per dof (scalars broadcast): the dynamic term
    of the thresholds. Zero (the default) leaves the static thresholds alone."""
    velocity_resolution: np.ndarray | float = 0.0    # rad/s at the joint per unit (Dynamixel 0.229 rpm)
    torque_resolution: np.ndarray | float = 0.0      # N m at the joint per unit of current read
    parameter_std: np.ndarray | None = None          # (10·nbody) standard errors, Model.regressor's columns
    coulomb_std: np.ndarray | float = 0.0            # N m
    viscous_std: np.ndarray | float = 0.0            # N m s/rad
    armature_std: np.ndarray | float = 0.0           # kg m²
    coverage: float = COVERAGE


@dataclass(frozen=True)
class Detection:
    """A contact: when, the first joint over its threshold, the link it is on and the force there
    (world frame, at the link's centre of mass). `settled` once the isolation window has passed."""
    t_s: float
    joint: str
    link: str
    force_n: tuple[float, float, float]
    force_estimate_n: float
    residual: tuple[float, ...]
    settled: bool = False

    def as_dict(self) -> dict:
        return {"detected_t_s": self.t_s, "joint": self.joint, "link": self.link,
                "force_n": list(self.force_n), "force_estimate_n": self.force_estimate_n}


def _per_dof(value, n: int, name: str, allow_zero: bool = True, allow_inf: bool = False) -> np.ndarray:
    try:
        out = np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number or {n} numbers, one per dof") from None
    finite = ~np.isnan(out) if allow_inf else np.isfinite(out)
    if not np.all(finite) or np.any(out < 0) or (not allow_zero and np.any(out == 0)):
        raise InputError(f"{name} must be {'' if allow_inf else 'finite and '}{'>= 0' if allow_zero else '> 0'}, "
                         f"got {out.tolist()}")
    return out


def thresholds_from_clean(residual_runs: list[np.ndarray], margin: float = DEFAULT_MARGIN) -> np.ndarray:
    """Per-joint static thresholds from the residuals (N, nv) of clean runs: margin × the largest
    |r_j| over every run (the runs' samples before the observer was armed left out by the caller)."""
    if not (isinstance(margin, (int, float)) and np.isfinite(margin) and margin >= 1.0):
        raise InputError(f"margin must be a number >= 1, got {margin!r}")
    runs = [np.asarray(r, dtype=float) for r in residual_runs]
    if not runs or any(r.ndim != 2 or len(r) == 0 for r in runs) or len({r.shape[1] for r in runs}) != 1:
        raise InputError("thresholds_from_clean needs at least one run, each a non-empty (samples, dofs) array "
                         "with the same number of dofs")
    peak = np.max([np.abs(r).max(axis=0) for r in runs], axis=0)
    if not np.all(np.isfinite(peak)):
        raise InputError("a clean run's residual is not finite")
    return margin * peak


def _pulse_peak(gain: np.ndarray, lowpass: np.ndarray) -> np.ndarray:
    """The peak of the low-pass's response to r's response to a velocity error's step, K_O·M·δ·e^(−K_O t),
    over K_O·M·δ: (K/w)^(K/(w − K)), 1/e for equal poles, 1 without the low-pass."""
    k, w = gain, lowpass
    with np.errstate(divide="ignore", invalid="ignore"):
        general = (k / w) ** (k / (w - k))
    return np.where(w <= 0, 1.0, np.where(np.abs(w - k) < 1e-9 * k, np.exp(-1.0), general))


class ContactObserver:
    """The momentum observer with a detection rule, isolation and the contact force.

    model: the identified servodyn Model; period: the sample period (s); gain: K_O (1/s, scalar or
    per dof); thresholds: static per-dof thresholds (N m; None: DEFAULT_THRESHOLD_NM); friction:
    (coulomb N m, viscous N m s/rad) per dof, the configuration's friction_coulomb_nm and
    friction_viscous_nm_s; uncertainty: the dynamic term (Uncertainty); lowpass: the low-pass on r
    (rad/s, scalar or per dof; 0: none); arm_time: seconds after reset before a detection counts,
    and settle: seconds the isolation is refined after a detection (None: 2/K_O + 2/lowpass, the
    slowest joint's, 40 ms by default: r then holds 91 % of a step)."""

    def __init__(self, model, period: float, gain=DEFAULT_GAIN, thresholds=None, friction=None,
                 uncertainty: Uncertainty | None = None, debounce: int = DEFAULT_DEBOUNCE,
                 arm_time: float | None = None, settle: float | None = None,
                 friction_speed: float = FRICTION_SPEED, lowpass=DEFAULT_LOWPASS, precision: str = "double"):
        n = model.nv
        if not (isinstance(period, (int, float)) and np.isfinite(period) and period > 0):
            raise InputError(f"period must be a positive number of seconds, got {period!r}")
        self.model, self.period = model, float(period)
        self.gain = _per_dof(gain, n, "gain", allow_zero=False)
        # an infinite threshold leaves its joint unwatched (a calibration run watches none)
        self.thresholds = _per_dof(DEFAULT_THRESHOLD_NM if thresholds is None else thresholds, n, "thresholds",
                                   allow_inf=True)
        coulomb, viscous = (None, None) if friction is None else friction
        self.coulomb = _per_dof(0.0 if coulomb is None else coulomb, n, "friction coulomb")
        self.viscous = _per_dof(0.0 if viscous is None else viscous, n, "friction viscous")
        self.friction_speed = float(friction_speed)
        self.uncertainty = Uncertainty() if uncertainty is None else uncertainty
        self.debounce = int(debounce)
        if self.debounce < 1:
            raise InputError(f"debounce must be at least 1 sample, got {debounce!r}")
        self.lowpass = _per_dof(0.0 if lowpass is None else lowpass, n, "lowpass")
        lag = np.where(self.lowpass > 0, 2.0 / np.maximum(self.lowpass, 1e-300), 0.0)
        rise = float(np.max(2.0 / self.gain + lag))
        self.arm_time = rise if arm_time is None else float(arm_time)
        self.settle = rise if settle is None else float(settle)
        try:
            self._observer = MomentumObserver(model, self.period, self.gain, self.coulomb, self.viscous,
                                              self.friction_speed, self.lowpass, precision)
        except ValueError as err:
            raise InputError(str(err)) from None
        self._decay = np.exp(-self.gain * self.period)
        self._sensor_share = _pulse_peak(self.gain, self.lowpass)
        self._prepare_uncertainty()
        self._dof_body = np.array([i for i, b in enumerate(model.bodies)
                                   for _ in range(6 if b.free else len(b.dofs))], dtype=int)
        self._path = self._paths()
        self.dof_names = model.dof_names
        self.detection: Detection | None = None
        self.threshold = self.thresholds.copy()    # θ(t) of the last sample
        self._started = False

    # ------------------------------------------------------------------ set-up
    def _prepare_uncertainty(self) -> None:
        u, n = self.uncertainty, self.model.nv
        self._vel_res = _per_dof(u.velocity_resolution, n, "velocity_resolution")
        self._tau_res = _per_dof(u.torque_resolution, n, "torque_resolution")
        k = float(u.coverage)
        self._sigma = {name: k * _per_dof(getattr(u, name), n, name)
                       for name in ("coulomb_std", "viscous_std", "armature_std")}
        self._param_std = None
        if u.parameter_std is not None:
            std = np.asarray(u.parameter_std, dtype=float)
            if std.shape != (10 * self.model.nbody,) or not np.all(np.isfinite(std)) or np.any(std < 0):
                raise InputError(f"parameter_std must be {10 * self.model.nbody} finite numbers >= 0 "
                                 "(Model.regressor's columns)")
            self._param_std = k * std
        # what _dynamic has to compute, decided once
        self._tau_half = self._tau_res / 2 if self._tau_res.any() else 0.0
        self._vel_half = self._vel_res / 2 if self._vel_res.any() else None
        self._vel_gain = self._sensor_share * self.gain
        self._vel_every = max(1, int(round(MASS_MATRIX_EVERY_S / self.period)))
        self._coulomb_band = bool(self.coulomb.any())
        self._model_terms = self._coulomb_band or self._param_std is not None or \
            any(v.any() for v in self._sigma.values())

    def _paths(self) -> list[np.ndarray]:
        """For each body, the dofs between the base and it (its own included)."""
        paths = []
        for i, body in enumerate(self.model.bodies):
            mask = np.zeros(self.model.nv, dtype=bool)
            j = i
            while j >= 0:
                mask[self._dof_body == j] = True
                j = self.model.bodies[j].parent
            paths.append(mask)
        return paths

    # ------------------------------------------------------------------ the samples
    def reset(self, q, qd) -> None:
        """Start at the measured state (after torque on, or a re-enable): r = 0, not armed, no
        detection."""
        self._observer.reset(q, qd)
        self._qd_prev = np.asarray(qd, dtype=float).copy()
        self._qdd = np.zeros(self.model.nv)
        self._model_error = np.zeros(self.model.nv)
        self._over = np.zeros(self.model.nv, dtype=int)
        self._vel_term, self._samples = None, 0
        self._t0 = None
        self.detection = None
        self.threshold = self.thresholds.copy()
        self._started = True

    def update(self, t: float, q, qd, tau_motor) -> np.ndarray:
        """One sample at time t (s): the measured state and the motor torque at the joints that
        acted over the period ending now (current × torque constant). Returns the residual (nv,);
        `detection` holds the contact once one is found."""
        if not self._started:
            self.reset(q, qd)
            self._t0 = t
            return self._observer.residual
        r = self._observer.step(q, qd, tau_motor)
        if self._t0 is None:
            self._t0 = t - self.period
        qd = np.asarray(qd, dtype=float)
        self.threshold = self.thresholds + self._dynamic(q, qd)
        over = np.abs(r) > self.threshold
        self._over = (self._over + 1) * over
        if self.detection is None:
            if t - self._t0 >= self.arm_time and over.any() and (self._over >= self.debounce).any():
                joint = int(np.flatnonzero(self._over >= self.debounce)[0])
                link, force = self.estimate(q, r, over)
                self.detection = Detection(t_s=float(t), joint=self.dof_names[joint], link=link,
                                           force_n=tuple(float(f) for f in force),
                                           force_estimate_n=float(np.linalg.norm(force)),
                                           residual=tuple(float(x) for x in r))
        elif not self.detection.settled:
            link, force = self.estimate(q, r, over)
            self.detection = replace(self.detection, link=link, force_n=tuple(float(f) for f in force),
                                     force_estimate_n=float(np.linalg.norm(force)),
                                     residual=tuple(float(x) for x in r),
                                     settled=t - self.detection.t_s >= self.settle - 1e-9)
        return r

    @property
    def residual(self) -> np.ndarray:
        return self._observer.residual

    # ------------------------------------------------------------------ thresholds
    def _dynamic(self, q, qd: np.ndarray) -> np.ndarray | float:
        """d(t): the sensors' part now, and the model's through the observer's low-pass (only the
        terms the uncertainty has: the static thresholds alone cost nothing here)."""
        out = self._tau_half
        if self._vel_half is not None:
            # M(q) moves little in 10 ms (a tenth of a radian at the swing's fastest): refreshed
            # that often, it costs a few µs a sample instead of a mass matrix each
            if self._vel_term is None or self._samples % self._vel_every == 0:
                self._vel_term = self._vel_gain * (np.abs(self.model.mass_matrix(q)) @ self._vel_half)
            self._samples += 1
            out = out + self._vel_term
        if not self._model_terms:
            return out
        qdd = (qd - self._qd_prev) / self.period
        self._qd_prev = qd.copy()
        self._qdd = self._decay * self._qdd + (1 - self._decay) * qdd
        error = (self._sigma["coulomb_std"] + self._sigma["viscous_std"] * np.abs(qd)
                 + self._sigma["armature_std"] * np.abs(self._qdd))
        if self._coulomb_band:
            # the smoothed Coulomb step: within a few quanta of zero speed the true friction is
            # anywhere in ±F_c
            error = error + self.coulomb * (1 - np.abs(np.tanh(qd / self.friction_speed)))
        if self._param_std is not None:
            error = error + np.abs(self.model.regressor(q, qd, self._qdd)) @ self._param_std
        self._model_error = self._decay * self._model_error + (1 - self._decay) * error
        return out + self._model_error

    # ------------------------------------------------------------------ isolation and force
    def estimate(self, q, r=None, significant=None, link: str | None = None) -> tuple[str, np.ndarray]:
        """(link, force): the body of the last joint whose residual is significant (over its
        threshold; every joint's by default), or the given link, and the world-frame force at its
        centre of mass that best explains r over the joints up to it (least squares, J's small
        singular values cut)."""
        r = self.residual if r is None else np.asarray(r, dtype=float)
        if link is not None:
            if link not in self.model.body_names:
                raise InputError(f"link '{link}' is not a body of the model ({', '.join(self.model.body_names)})")
            body = self.model.body_names.index(link)
        else:
            if significant is None:
                significant = np.abs(r) > self.threshold
            hits = np.flatnonzero(significant)
            dof = int(hits[-1]) if len(hits) else int(np.argmax(np.abs(r) / np.maximum(self.threshold, 1e-12)))
            body = int(self._dof_body[dof])
        path = self._path[body]
        jt = self.com_jacobian_t(q, body)[path]
        force, *_ = np.linalg.lstsq(jt, r[path], rcond=RCOND)
        return self.model.body_names[body], force

    def com_jacobian_t(self, q, body: int) -> np.ndarray:
        """Jᵀ (nv, 3) of the body's centre of mass, world frame: the joint torques a unit world force
        there produces, from the core's inverse dynamics (an external wrench enters it as −Jᵀf)."""
        model, n = self.model, self.model.nv
        R, _ = model.user_poses(q)
        com = np.asarray(model.bodies[body].com, dtype=float)
        f_ext = np.zeros((4, model.nbody, 6))
        for axis in range(3):
            force = R[body].T[:, axis]               # the world axis in the body's frame
            f_ext[axis, body, 3:] = force
            f_ext[axis, body, :3] = np.cross(com, force)
        tau = model.inverse_dynamics(np.tile(np.asarray(q, dtype=float), (4, 1)), np.zeros((4, n)),
                                     np.zeros((4, n)), f_ext=f_ext)
        return -(tau[:3] - tau[3]).T
