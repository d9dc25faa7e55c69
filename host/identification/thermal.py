"""A servo's thermal resistance and time constant from a heating run's winding temperature.

The winding model is the one the validator and the simulated servos use (hal.thermal): C·dT/dt =
I²·R·(1 + α(T − 25 °C)) − (T − T_amb)/R_th, τ_th = R_th·C. The fit is an output-error one: the
model is run over the log's own current (its mean I² every STEP_S) from a fitted starting
temperature, and R_th, τ_th and that start are chosen (scipy least_squares) so that it passes
through the readings. The readings are whole degrees, so the regressors must not be: a regression
of each step's rise on the read temperature (ΔT_{k+1} = a·ΔT_k + b·P_k) puts the 1 °C steps inside
its regressor and shortens τ_th (errors in variables).

Readings: a Dynamixel servo's temperature is read one tick in several (hal.dynamixel.backend) and
held in the log between reads. `read_rows` finds the rows read (the rows where any servo's value
changes lie on one grid: its spacing is their common divisor), so each reading is compared with the
model at the time it was taken, not up to a read interval later.

Errors: each reading is off the winding by up to half a degree (the rounding), and so may the
ambient be (its first reading). Those errors are not independent noise — at a steady temperature the
same rounding repeats — so beside the residuals' standard error the fit gives the worst case
`bound`: the largest change of each parameter that errors of at most half a degree on every
reading and on the ambient can make, at first order (the ℓ∞ gain of the least-squares solution).
The reported standard error is the larger of the two (the bound over √3: a uniform error of that
half-width)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy.optimize import least_squares

from ..hal.thermal import winding_rates, winding_temperature
from .estimate import REL_SIGMA_MAX, Parameter

STEP_S = 0.01           # s: the model's step (the current's mean square over each; the simulated servos' own)
QUANTUM_C = 1.0         # °C: a reading's resolution (Dynamixel Present Temperature, Damiao's coil byte)
MIN_RISE_C = 3.0        # °C: a winding that warms less determines nothing


@dataclass
class ThermalFit:
    resistance_k_w: Parameter
    time_constant_s: Parameter
    bound: tuple | None = None          # (K/W, s): the worst case of the whole-degree readings (None: not fitted)


def read_rows(temperature) -> np.ndarray:
    """The rows of a log's temperature columns (N, n) that are readings: every row when the values
    change on rows without a common spacing (read every tick), else the grid their changes lie on."""
    temperature = np.asarray(temperature, dtype=float)
    if temperature.ndim == 1:
        temperature = temperature[:, None]
    finite = np.isfinite(temperature).all(axis=1)
    changes = np.flatnonzero(np.any(np.diff(temperature, axis=0) != 0, axis=1) & finite[1:]) + 1
    if len(changes) < 3:
        return np.flatnonzero(finite)
    every = int(np.gcd.reduce(np.diff(changes)))
    if every <= 1:
        return np.flatnonzero(finite)
    rows = np.arange(changes[0] % every, len(temperature), every)
    return rows[finite[rows]]


def _not_determined(why: str) -> ThermalFit:
    return ThermalFit(Parameter(None, None, why), Parameter(None, None, why))


class _Winding:
    """The winding model over a log's current: the temperature at the reading times for given
    R_th, τ_th, starting temperature and ambient."""

    def __init__(self, t, current, resistance: float, at):
        self.edges = np.arange(t[0], t[-1], STEP_S)
        # the current is held from each row to the next: its square's integral, then its mean per step
        energy = np.concatenate([[0.0], np.cumsum(current[:-1] ** 2 * np.diff(t))])
        self.square = np.diff(np.interp(np.append(self.edges, self.edges[-1] + STEP_S), t, energy)) / STEP_S
        self.resistance = resistance
        self.at = at
        self.power = self.square * resistance

    def __call__(self, r_th: float, tau: float, start: float, ambient: float) -> np.ndarray:
        L = SimpleNamespace(resistance=np.array([self.resistance]), thermal_resistance=np.array([r_th]),
                            thermal_time_constant=np.array([tau]))
        from_ambient = winding_temperature(np.sqrt(self.square)[:, None], STEP_S, L, 1, ambient)[:, 0]
        a, _ = winding_rates(self.square, self.resistance, r_th, tau, ambient)
        decay = np.exp(np.concatenate([[0.0], np.cumsum(a * STEP_S)[:-1]]))
        return np.interp(self.at, self.edges, from_ambient + (start - ambient) * decay)


def fit_thermal(t, current, temperature, resistance: float, ambient: float | None = None, rows=None,
                ambient_exact: bool = False) -> ThermalFit:
    """R_th (K/W) and τ_th (s) of one servo from its current (A) and winding temperature (°C, nan
    where never read) over a run; `resistance` its winding's Ω at 25 °C; `ambient` the room's
    temperature (default: the first reading), a reading itself (to half a degree) unless
    `ambient_exact`; `rows` the rows that are readings (default: every finite one; `read_rows` finds
    them in a log)."""
    t, current, temperature = (np.asarray(x, dtype=float) for x in (t, current, temperature))
    rows = np.flatnonzero(np.isfinite(temperature)) if rows is None else np.asarray(rows, dtype=int)
    rows = rows[np.isfinite(temperature[rows])]
    if len(rows) < 2:
        return _not_determined("not determined: the log has no temperature readings")
    read = temperature[rows]
    ambient_read = not ambient_exact
    ambient = float(read[0]) if ambient is None else float(ambient)
    rise = float(read.max() - min(ambient, read.min()))
    if rise < MIN_RISE_C:
        return _not_determined(f"not determined: the winding warms by {rise:.1f} °C (needs {MIN_RISE_C:g} °C or "
                               "more: a heating run, servodyn excite --heat)")
    model = _Winding(t, current, resistance, t[rows])
    span = t[-1] - t[0]
    heat = float(np.percentile(model.power, 90))
    if heat <= 0:
        return _not_determined("not determined: the winding warms with no current through it")

    def residual(x):
        return model(math.exp(x[0]), math.exp(x[1]), x[2], ambient) - read

    # a few starting time constants: the cost has one valley, but a start far up its flat side
    # (τ much longer than the run) is slow to leave
    starts = [[math.log(max(rise, 1.0) / heat), math.log(span * f), read[0]] for f in (0.03, 0.15, 0.6)]
    best = min((least_squares(residual, x0, x_scale=[1.0, 1.0, QUANTUM_C]) for x0 in starts),
               key=lambda r: r.cost)
    r_th, tau = math.exp(best.x[0]), math.exp(best.x[1])
    if not (best.success and math.isfinite(r_th) and math.isfinite(tau) and tau < 100 * span):
        return _not_determined(f"not determined: no first-order heating in the log (the fit ends at R_th {r_th:.3g} "
                               f"K/W, τ_th {tau:.3g} s, over a run of {span:.3g} s)")
    # sensitivities in (R_th, τ_th, start), and to the ambient
    J = best.jac * np.array([r_th, tau, 1.0]) ** -1
    gain = np.linalg.pinv(J)                                            # (3, m): δp = gain · δreading
    dof = max(len(read) - 3, 1)
    cov = 2 * best.cost / dof * gain @ gain.T
    half = QUANTUM_C / 2
    bound = half * np.abs(gain).sum(axis=1)
    if ambient_read:
        step = 1e-3
        toward = (model(r_th, tau, best.x[2], ambient + step) - model(r_th, tau, best.x[2], ambient)) / step
        bound = bound + half * np.abs(gain @ toward)
    out = []
    for k, (value, unit) in enumerate(((r_th, "K/W"), (tau, "s"))):
        std = max(math.sqrt(max(cov[k, k], 0.0)), bound[k] / math.sqrt(3))
        if not (math.isfinite(std) and std <= REL_SIGMA_MAX * value):
            out.append(Parameter(None, None, f"not determined: {value:.4g} ± {std:.2g} {unit}, an error above "
                                             f"{REL_SIGMA_MAX:.0%} of the value (whole-degree readings over a "
                                             f"{rise:.0f} °C rise)"))
        else:
            out.append(Parameter(float(value), float(std)))
    return ThermalFit(out[0], out[1], (float(bound[0]), float(bound[1])))
