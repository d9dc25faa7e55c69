"""From a log's samples to what the least squares take: q̇ and q̈ from q by filtered
differentiation, the torque through the same filter, both decimated.

The filter is a Butterworth low-pass of order FILTER_ORDER at FILTER_HZ run forwards and backwards
(scipy.signal.sosfiltfilt): zero phase, so no lag between q̈ and the torque; its gain is |H|², -6 dB
at the cut-off. The torque goes through the same filter, so what the filter does to the motion it
does to the torque too; so does sign(q̇), the Coulomb friction's column. At 1 kHz and 4096 counts per turn, the quantisation left in q̈ after a
10 Hz low-pass is about 0.1 rad/s² rms (notes/identification.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

from ..control.timing import MIN_CONTROL_PERIOD
from ..errors import ServodynError

FILTER_HZ = 10.0          # Hz: the low-pass's cut-off
FILTER_ORDER = 4
DECIMATED_HZ = 50.0       # Hz: the rate the least squares see (5 samples per period of the cut-off)
EDGE_S = 0.25             # s dropped at each end, where the filter runs into the log's ends


class SignalError(ServodynError, ValueError):
    """Samples that cannot be filtered: too short, or not evenly spaced."""


@dataclass
class Prepared:
    """One log's samples after filtering and decimation (m samples, n dofs)."""
    t: np.ndarray         # (m,) s
    q: np.ndarray         # (m, n) rad
    qd: np.ndarray        # (m, n) rad/s
    qdd: np.ndarray       # (m, n) rad/s²
    tau: np.ndarray       # (m, n) N m, measured (current x torque constant x gear)
    sign: np.ndarray      # (m, n) sign(q̇) through the same filter: the Coulomb friction's column
    rate_hz: float        # the log's own sampling rate


def prepare(t, q, tau, cutoff_hz: float = FILTER_HZ, decimated_hz: float = DECIMATED_HZ,
            origin: str = "log") -> Prepared:
    """Filter q and tau alike (zero phase), differentiate q twice, drop the ends, decimate."""
    t, q, tau = (np.asarray(x, dtype=float) for x in (t, q, tau))
    dt = np.diff(t)
    if len(t) < 20:
        raise SignalError(f"{origin}: {len(t)} samples, too few to filter")
    step = float(np.median(dt))
    if not step >= MIN_CONTROL_PERIOD:
        raise SignalError(f"{origin}: a time step of {step:.3g} s, shorter than any control period "
                          f"({MIN_CONTROL_PERIOD * 1e3:g} ms): its t column is not a servo log's")
    if np.max(np.abs(dt - step)) > 0.5 * step:
        raise SignalError(f"{origin}: samples not evenly spaced (steps from {dt.min() * 1e3:.3g} to "
                          f"{dt.max() * 1e3:.3g} ms)")
    rate = 1.0 / step
    if not 0 < cutoff_hz < 0.5 * rate:
        raise SignalError(f"{origin}: a {cutoff_hz:g} Hz cut-off needs more than {2 * cutoff_hz:g} samples per "
                          f"second, the log has {rate:.4g}")
    if cutoff_hz * (t[-1] - t[0]) < 1.0:
        # the filter's state has nothing to settle on (a cut-off of 1e-300 Hz made its design singular)
        raise SignalError(f"{origin}: a {cutoff_hz:g} Hz cut-off is a period longer than the log's "
                          f"{t[-1] - t[0]:.3g} s: give a cut-off of {1 / (t[-1] - t[0]):.3g} Hz or more")
    sos = butter(FILTER_ORDER, cutoff_hz, fs=rate, output="sos")
    qf = sosfiltfilt(sos, q, axis=0)
    tauf = sosfiltfilt(sos, tau, axis=0)
    qd = np.gradient(qf, step, axis=0)
    qdd = np.gradient(qd, step, axis=0)
    # Coulomb friction steps where q̇ changes sign, and the filter smooths that step in the torque:
    # its column goes through the filter too, or the torque's smoothed step biases the fit
    sign = sosfiltfilt(sos, np.sign(qd), axis=0)
    every = max(1, int(round(rate / decimated_hz)))
    edge = int(round(EDGE_S * rate))
    keep = slice(edge, len(t) - edge, every)
    if len(t) - 2 * edge < 2 * every:
        raise SignalError(f"{origin}: {t[-1] - t[0]:.3g} s, too short to identify from (needs well over "
                          f"{2 * EDGE_S:g} s)")
    return Prepared(t=t[keep], q=qf[keep], qd=qd[keep], qdd=qdd[keep], tau=tauf[keep], sign=sign[keep],
                    rate_hz=rate)
