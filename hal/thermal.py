"""The servos' winding model: a first-order thermal circuit whose copper resistance rises with
temperature, C_th·dT/dt = I²·R·(1 + α(T − 25 °C)) − (T − T_amb)/R_th, τ_th = R_th·C_th.

One implementation for whoever needs it: the validator runs it over a whole motion at once
(`winding_temperature`), the simulated servos step it as they run (`winding_step`). Within a step
the current is held, so C·dT/dt = a·T + b is linear in T and each step is exact:
T ← e^(a·dt)·T + (b/a)·(e^(a·dt) − 1), a and b per unit of C from `winding_rates`.
"""

from __future__ import annotations

import math

import numpy as np

COPPER_ALPHA = 0.00393      # 1/°C: copper's resistance rises with temperature
AMBIENT = 25.0              # °C
CHUNK = 4096                # samples of the thermal recurrence evaluated at once


def winding_rates(current_squared, resistance, thermal_resistance, thermal_time_constant, ambient):
    """(a, b) of dT/dt = a·T + b for a held current (floats or arrays alike; R_th, τ_th > 0)."""
    capacity = thermal_time_constant / thermal_resistance
    heat = current_squared * resistance                   # W at 25 °C
    a = (heat * COPPER_ALPHA - 1 / thermal_resistance) / capacity       # 1/s
    b = (heat * (1 - 25.0 * COPPER_ALPHA) + ambient / thermal_resistance) / capacity
    return a, b


def winding_step(temperature: float, current_squared: float, dt: float, resistance: float,
                 thermal_resistance: float, thermal_time_constant: float, ambient: float = AMBIENT) -> float:
    """The winding's temperature (°C) `dt` seconds on, with I² held (one servo; R_th = 0: not
    modelled, it stays where it is)."""
    if thermal_resistance <= 0 or thermal_time_constant <= 0:
        return temperature
    a, b = winding_rates(current_squared, resistance, thermal_resistance, thermal_time_constant, ambient)
    if a == 0.0:
        return temperature + b * dt
    grow = math.expm1(a * dt)
    return temperature + grow * (temperature + b / a)


def winding_temperature(current: np.ndarray, dt: float, L, repeat: int, ambient: float) -> np.ndarray:
    """The winding temperature over the last of `repeat` plays, from ambient at the start of the
    first, for currents (N, n) held dt each; L gives per servo `resistance`, `thermal_resistance`,
    `thermal_time_constant` (arrays of n). Unmodelled servos (R_th = 0) stay at ambient."""
    modelled = L.thermal_resistance > 0
    r_th = np.where(modelled, L.thermal_resistance, 1.0)
    a, b = winding_rates(current**2, L.resistance, r_th, np.where(modelled, L.thermal_time_constant, 1.0), ambient)
    log_decay = a * dt
    gain = np.where(np.abs(a) > 1e-15, np.expm1(log_decay) / np.where(a == 0, 1, a), dt) * b
    temperature = np.full(current.shape[1], float(ambient))
    out = np.empty_like(current)
    for _ in range(max(1, repeat)):
        # T_k = D_k·(T_0 + Σ_{j<k} gain_j / D_{j+1}), D_k = Π_{i<k} decay_i, in chunks short
        # enough that D stays far from overflow
        for start in range(0, len(current), CHUNK):
            cs = np.cumsum(log_decay[start:start + CHUNK], axis=0)
            before = np.vstack([np.zeros((1, cs.shape[1])), cs[:-1]])
            summed = np.cumsum(gain[start:start + CHUNK] * np.exp(-cs), axis=0)
            carried = np.vstack([np.zeros((1, cs.shape[1])), summed[:-1]])
            out[start:start + CHUNK] = np.exp(before) * (temperature + carried)
            temperature = np.exp(cs[-1]) * (temperature + summed[-1])
    return np.where(modelled, out, ambient)
