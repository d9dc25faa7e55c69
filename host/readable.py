"""Numbers as a person reads them: fixed decimals while that is readable, scientific notation
beyond (a finite 1e295 N·m is printed 1.85e+295, not as 296 digits). Any layer prints with it."""

from __future__ import annotations

import math

LARGEST_FIXED = 1e6        # from a million on, fixed decimals are a wall of digits


def fixed(x: float, decimals: int = 2) -> str:
    """`x` as f"{x:.{decimals}f}" prints it, or as f"{x:.{decimals}e}" (at least two decimals)
    when |x| >= LARGEST_FIXED."""
    x = float(x)
    if math.isfinite(x) and abs(x) >= LARGEST_FIXED:
        return f"{x:.{max(decimals, 2)}e}"
    return f"{x:.{decimals}f}"


def percent(ratio: float, decimals: int = 1) -> str:
    """`ratio` as f"{ratio:.{decimals}%}" prints it, huge ratios in scientific notation."""
    return f"{fixed(100 * float(ratio), decimals)}%"
