"""The servos' winding model: a first-order thermal circuit whose copper resistance rises with
temperature, C_th·dT/dt = I²·R·(1 + α(T − 25 °C)) − (T − T_amb)/R_th."""

from __future__ import annotations

import numpy as np

COPPER_ALPHA = 0.00393      # 1/°C: copper's resistance rises with temperature
AMBIENT = 25.0              # °C
CHUNK = 4096                # samples of the thermal recurrence evaluated at once


def winding_temperature(current: np.ndarray, dt: float, L, repeat: int, ambient: float) -> np.ndarray:
    """The winding temperature over the last of `repeat` plays, from ambient at the start of the
    first. Within a sample the current is held, so C·dT/dt = a·T + b is linear in T and each step
    is exact: T ← e^(a·dt/C)·T + (b/a)·(e^(a·dt/C) − 1). Unmodelled servos (R_th = 0) stay at ambient."""
    modelled = L.thermal_resistance > 0
    r_th = np.where(modelled, L.thermal_resistance, 1.0)
    capacity = np.where(modelled, L.thermal_time_constant, 1.0) / r_th
    heat = current**2 * L.resistance                      # W at 25 °C
    a = (heat * COPPER_ALPHA - 1 / r_th) / capacity       # 1/s
    b = (heat * (1 - 25.0 * COPPER_ALPHA) + ambient / r_th) / capacity
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
