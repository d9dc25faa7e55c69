"""A servo's thermal resistance and time constant from a heating run's winding temperature.

The winding model is the one the validator and the simulated servos use (hal.thermal): C·dT/dt = P − (T − T_amb)/R_th with
P = I²·R·(1 + α(T − 25 °C)). Held over a step Δt it is, exactly, ΔT_{k+1} = a·ΔT_k + b·P_k with
ΔT = T − T_amb, a = e^(−Δt/τ_th), b = R_th·(1 − a); so a and b by least squares, then
τ_th = −Δt / ln a and R_th = b / (1 − a). Dynamixel reports the temperature in 1 °C steps: the run
must heat the winding by several degrees and last several τ_th for the numbers to be determined."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..hal.thermal import COPPER_ALPHA
from .estimate import Parameter, _judged

STEP_S = 1.0            # s: the regression's step (the temperature is read at a low rate)
MIN_RISE_C = 3.0        # °C: a run that heats the winding less determines nothing


@dataclass
class ThermalFit:
    resistance_k_w: Parameter
    time_constant_s: Parameter


def fit_thermal(t, current, temperature, resistance: float, ambient: float | None = None) -> ThermalFit:
    """R_th (K/W) and τ_th (s) of one servo from its current (A) and winding temperature (°C) over a
    run; `resistance` its winding's Ω at 25 °C; ambient the temperature at the start by default."""
    t, current, temperature = (np.asarray(x, dtype=float) for x in (t, current, temperature))
    # the temperature is read at a low rate (nan between readings): steps between the readings
    read = np.isfinite(temperature)
    if read.sum() < 2:
        why = "not determined: the log has no temperature readings"
        return ThermalFit(Parameter(None, None, why), Parameter(None, None, why))
    ambient = float(temperature[read][0]) if ambient is None else float(ambient)
    rise = float(np.max(temperature[read]) - ambient)
    if rise < MIN_RISE_C or t[-1] - t[0] < 10 * STEP_S:
        why = f"not determined: the winding warms by {rise:.1f} °C (needs {MIN_RISE_C:g} °C or more over a long run)"
        return ThermalFit(Parameter(None, None, why), Parameter(None, None, why))
    # per step of STEP_S: the mean heat over the step, the temperature (between readings, linear)
    # at its start and end
    held = np.interp(t, t[read], temperature[read])
    edges = np.arange(t[0], t[-1] + 1e-9, STEP_S)
    at = np.unique(np.searchsorted(t, edges))
    at = at[at < len(t)]
    T = held[at] - ambient
    heat = current**2 * resistance * (1 + COPPER_ALPHA * (held - 25.0))
    power = np.add.reduceat(heat, at)[:-1] / np.diff(at)
    A = np.column_stack([T[:-1], power])
    y = T[1:]
    (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ np.array([a, b])
    cov = float(res @ res) / max(len(y) - 2, 1) * np.linalg.pinv(A.T @ A)
    if not (0 < a < 1 and b > 0):
        why = f"not determined: the fit gives a = {a:.4g}, b = {b:.3g} (no first-order heating in the log)"
        return ThermalFit(Parameter(None, None, why), Parameter(None, None, why))
    tau = -STEP_S / math.log(a)
    r_th = b / (1 - a)
    # first-order errors: dτ/da = Δt / (a ln² a); dR/da = b / (1 − a)², dR/db = 1 / (1 − a)
    j_tau = np.array([STEP_S / (a * math.log(a) ** 2), 0.0])
    j_r = np.array([b / (1 - a) ** 2, 1 / (1 - a)])
    return ThermalFit(_judged(r_th, math.sqrt(j_r @ cov @ j_r), "K/W"),
                      _judged(tau, math.sqrt(j_tau @ cov @ j_tau), "s"))
