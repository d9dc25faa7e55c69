"""The slowest uniform timing a motion needs: the smallest time scale at which every check passes."""

from __future__ import annotations

import math

from ..control.trajectory import MotionPath
from .checks import check
from .limits import Limits

FIT_GRID = (0.25, 64.0, 1.25)     # geometric scan of time scales: first, last, ratio
FIT_TOLERANCE = 1e-3              # relative width the bisection stops at


def fit_time_scale(model, limits: Limits, path: MotionPath, margin: float, repeat: int, ambient: float):
    """The smallest uniform time scale at which every check passes, and how it was found.

    Played s times slower, the speeds fall as 1/s and the inertial and velocity-product torques as
    1/s² (τ(s) = M·q̈/s² + C·q̇²/s² + g), so the speed, envelope, current and command checks pass from
    some s on; position and bus do not depend on s; heat grows with s when gravity is held longer.
    A geometric scan (×1.25 from 0.25 to 64) finds the first passing scale, a bisection between it
    and the scale before narrows it to 0.1 %, each candidate checked densely like any run."""
    def passes(scale):
        return check(model, limits, path.at_scale(scale, limits.period), margin, repeat, ambient).passed
    return smallest_passing_scale(passes)


def smallest_passing_scale(passes, first: float = FIT_GRID[0], last: float = FIT_GRID[1],
                           tolerance: float = FIT_TOLERANCE):
    """The smallest time scale from `first` to `last` for which `passes(scale)` is true, found by a
    geometric scan (xFIT_GRID[2]) and a bisection to `tolerance` between the first passing scale
    and the one before; (None, why) when none does. Also sizing's (validation.sizing), whose
    `passes` is "some set of catalogue servos passes"."""
    ratio = FIT_GRID[2]
    below, scale = None, first
    while scale <= last * (1 + 1e-12):
        if passes(scale):
            break
        below, scale = scale, scale * ratio
    else:
        return None, f"no time scale from {first:g} to {last:g} passes"
    if below is None:
        return scale, f"already passes at the scan's first scale, {first:g}"
    above = scale
    while above - below > tolerance * above:
        middle = math.sqrt(below * above)
        if passes(middle):
            above = middle
        else:
            below = middle
    return above, f"scan x{ratio:g} then bisection to {tolerance:.1%}: fails at {below:.4f}, passes at {above:.4f}"
