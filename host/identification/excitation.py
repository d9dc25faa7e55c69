"""An exciting trajectory: Swevers' finite Fourier series per joint (Swevers et al., IEEE TRA 13(5)
1997), its coefficients chosen for a well conditioned observation matrix.

    q_j(t) = q_j0 + Σ_{l=1..N} a_jl/(l ω) sin(l ω t) − b_jl/(l ω) cos(l ω t),   ω = 2π f

It is periodic, so whole periods are played. Σ_l a_jl = 0 and Σ_l l·b_jl = 0 put q̇ and q̈ at zero at
t = 0 and at every period's end: the motion starts and ends at rest. The last harmonic's a and b
are what those two sums leave, the others free. Inside `limits` with a margin: each joint's
excursion from q_j0 (the middle of its range) is scaled to the range shrunk by the margin, and down
further when its peak speed would pass `speed_fraction` of the joint's velocity limit — in the
objective itself, so the optimiser sees only motions that fit.

Bounded by what it is for: at most MAX_PLAYED_DURATION (a swing samples its motion whole), and at
most `max_harmonics(duration)` harmonics: the highest, N times the base frequency, at or below
identify's low-pass cut-off (signals.FILTER_HZ: above it the filter takes the harmonic out of the q
and torque the least squares see) and below half the SAMPLES of a period the condition number is
evaluated at (above, a harmonic aliases on that grid and the design cannot see it). The optimiser's
cost grows with the harmonics (a gradient is 2(N - 1) evaluations per joint); `progress` is told
each iteration."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from ..control.timing import MAX_PLAYED_DURATION
from ..errors import ServodynError
from .estimate import _base_columns, _gram_condition
from .signals import FILTER_HZ

HARMONICS = 5
PERIOD_S = 10.0           # s: the period aimed at (f ≈ 0.1 Hz; notes/identification.md)
SAMPLES = 120             # per period, where the condition number is evaluated
PEAK_SAMPLES = 4000       # per period, where the peaks are found (the highest harmonic's period in 800)
MARGIN = 0.1              # of each joint's range kept clear at both ends
SPEED_FRACTION = 0.6      # of each joint's velocity limit


class ExcitationError(ServodynError, ValueError):
    """A duration or a number of harmonics no excitation is designed for; the message is one line."""


def base_frequency(duration: float) -> float:
    """Hz: the duration as whole periods of about PERIOD_S."""
    return max(1, int(round(duration / PERIOD_S))) / duration


def max_harmonics(duration: float) -> tuple[int, str]:
    """The most harmonics an excitation of `duration` s has use for, and why no more."""
    base_hz = base_frequency(duration)
    by_filter = int(math.floor(FILTER_HZ / base_hz * (1 + 1e-9)))
    by_grid = SAMPLES // 2 - 1
    if by_filter <= by_grid:
        return by_filter, (f"above {by_filter} times its {base_hz:.3g} Hz base frequency a harmonic is past "
                           f"identify's {FILTER_HZ:g} Hz low-pass, which takes it out of what the least squares fit")
    return by_grid, (f"the design evaluates the condition number at {SAMPLES} samples a period, which tells no more "
                     f"than {by_grid} harmonics apart")


def check_design(duration: float, harmonics: int) -> None:
    """ExcitationError unless an excitation of `duration` s with `harmonics` can be designed."""
    shortest = 2 / FILTER_HZ        # s: its two harmonics inside identify's low-pass
    if not (math.isfinite(duration) and shortest <= duration <= MAX_PLAYED_DURATION):
        raise ExcitationError(f"an excitation lasts from {shortest:g} s (2 harmonics, the least, within identify's "
                              f"{FILTER_HZ:g} Hz low-pass) to {MAX_PLAYED_DURATION:g} s (the longest a swing plays), "
                              f"not {duration:g} s")
    most, why = max_harmonics(duration)
    if not 2 <= harmonics <= most:
        raise ExcitationError(f"an excitation of {duration:g} s has from 2 harmonics (the last closes the rest at "
                              f"both ends) to {most}: {why}; not {harmonics}")


@dataclass
class FourierExcitation:
    """The series of every dof (a joint not excited has zero coefficients and stays at q0)."""
    base_hz: float
    q0: np.ndarray        # (n,)
    a: np.ndarray         # (n, N)
    b: np.ndarray         # (n, N)
    duration: float       # s, whole periods

    def evaluate(self, t):
        """q, qd, qdd at times t (a leading axis of len(t))."""
        t = np.asarray(t, dtype=float)
        scalar = t.ndim == 0
        t = np.atleast_1d(t)
        w = 2 * math.pi * self.base_hz * np.arange(1, self.a.shape[1] + 1)     # (N,)
        s, c = np.sin(np.outer(t, w)), np.cos(np.outer(t, w))                  # (m, N)
        q = self.q0 + s @ (self.a / w).T - c @ (self.b / w).T
        qd = c @ self.a.T + s @ self.b.T
        qdd = -s @ (self.a * w).T + c @ (self.b * w).T
        return (q[0], qd[0], qdd[0]) if scalar else (q, qd, qdd)

    def scaled(self, factor: float) -> "FourierExcitation":
        """The same shape with every excursion times `factor`."""
        return FourierExcitation(self.base_hz, self.q0, self.a * factor, self.b * factor, self.duration)


def _coefficients(x: np.ndarray, k: int, N: int) -> tuple[np.ndarray, np.ndarray]:
    """a, b (k, N) from the free ones, the last harmonic closing Σ a = 0 and Σ l b = 0."""
    free = x.reshape(k, 2, N - 1)
    a = np.concatenate([free[:, 0], -free[:, 0].sum(axis=1, keepdims=True)], axis=1)
    l = np.arange(1, N)
    b = np.concatenate([free[:, 1], -(free[:, 1] @ l)[:, None] / N], axis=1)
    return a, b


def _fitted(series: FourierExcitation, excited, half, speed) -> FourierExcitation:
    """Each excited joint's excursion scaled to fill its half range, then to keep its speed."""
    t = np.linspace(0, 1 / series.base_hz, PEAK_SAMPLES, endpoint=False)
    q, qd, _ = series.evaluate(t)
    dev = np.max(np.abs(q - series.q0), axis=0)
    fast = np.max(np.abs(qd), axis=0)
    factor = np.ones(len(series.q0))
    with np.errstate(divide="ignore", invalid="ignore"):
        # 0.1 % short of the bounds: a peak between two of the samples overshoots by less
        factor[excited] = np.minimum(half[excited] / dev[excited], speed[excited] / fast[excited]) * 0.999
    factor = np.where(np.isfinite(factor), factor, 0.0)
    return FourierExcitation(series.base_hz, series.q0, series.a * factor[:, None], series.b * factor[:, None],
                             series.duration)


def design_excitation(model, lower, upper, velocity_limit, duration: float, excited=None,
                      harmonics: int = HARMONICS, margin: float = MARGIN, speed_fraction: float = SPEED_FRACTION,
                      payload_body: str | None = None, iterations: int = 40, seed: int = 0,
                      progress=None) -> tuple[FourierExcitation, float]:
    """The excitation of `duration` s (rounded to whole periods near PERIOD_S) over the `excited`
    dofs (indices; default all), and the condition number it reaches: of the column-scaled
    observation matrix of the payload body's base parameters and each excited joint's armature,
    viscous and Coulomb friction over one period. `progress(i, iterations, condition)` after each
    of the optimiser's iterations."""
    check_design(duration, harmonics)
    n = model.nv
    lower, upper, velocity_limit = (np.asarray(x, dtype=float) for x in (lower, upper, velocity_limit))
    excited = np.arange(n) if excited is None else np.asarray(excited, dtype=int)
    base_hz = base_frequency(duration)
    periods = int(round(duration * base_hz))
    middle = (lower + upper) / 2
    half = (upper - lower) / 2 * (1 - 2 * margin)
    q0 = np.where((lower + (upper - lower) * margin <= 0) & (0 <= upper - (upper - lower) * margin), 0.0, middle)
    q0[excited] = middle[excited]
    half = np.minimum(half, np.minimum(q0 - lower, upper - q0) - (upper - lower) * margin)
    speed = velocity_limit * speed_fraction
    k, N = len(excited), harmonics
    b_index = model.body_names.index(payload_body or model.body_names[-1])
    rng = np.random.default_rng(seed)
    base, _, _ = _base_columns(model, np.arange(10 * b_index, 10 * b_index + 10), rng)
    cols = 10 * b_index + base
    t = np.linspace(0, 1 / base_hz, SAMPLES, endpoint=False)
    eye = np.eye(n)[:, excited]

    def build(x):
        a, b = np.zeros((n, N)), np.zeros((n, N))
        a[excited], b[excited] = _coefficients(x, k, N)
        return _fitted(FourierExcitation(base_hz, q0, a, b, periods / base_hz), excited, half, speed)

    def condition(x):
        series = build(x)
        q, qd, qdd = series.evaluate(t)
        Y = model.regressor(q, qd, qdd)[:, :, cols]
        W = np.concatenate([Y, qdd[:, :, None] * eye, qd[:, :, None] * eye, np.sign(qd)[:, :, None] * eye],
                           axis=2).reshape(-1, len(cols) + 3 * k)
        norms = np.linalg.norm(W, axis=0)
        if np.any(norms < 1e-12):
            return 1e12
        return _gram_condition(W / norms)

    x0 = rng.normal(size=k * 2 * (N - 1))
    done = [0]

    def told(x):
        done[0] += 1
        progress(done[0], iterations, condition(x))
    best = minimize(lambda x: math.log(condition(x)), x0, method="L-BFGS-B", callback=told if progress else None,
                    options={"maxiter": iterations, "maxfun": iterations * (len(x0) + 1)})
    x = best.x if best.fun < math.log(condition(x0)) else x0
    return build(x), condition(x)
