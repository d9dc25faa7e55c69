"""A heating run: the motion whose log gives each servo's thermal resistance and time constant.

The arm holds a pose where gravity loads the heated joints (a steady current, so a steady heat
I²·R), then moves to a pose where it hangs with little load and rests there while the windings
cool. Both halves are first-order curves of the winding model (hal.thermal): the hold's rise sets
R_th·P, the time both curves take sets τ_th, so a run of a few τ_th in each half determines both
(identification.thermal).

The poses come from random candidates inside the joints' limits less a margin of their range:
the hold pose is the one whose predicted steady rise, I²·R·R_th with I the gravity torque over the
torque per ampere, comes nearest to `share` of each heated winding's headroom (its temperature
limit less the ambient), summed over the heated joints; the rest pose is the one with the least
heat in all of them. The move between them is a minimum-jerk quintic, its peak speed under
`speed_fraction` of each joint's velocity limit. Whether it is safe is the validator's to say
(servodyn excite --heat checks the whole run and pulls the hold pose towards the rest pose until
every winding stays within `share` of its headroom).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..control.timing import MAX_PLAYED_DURATION
from .excitation import MARGIN, SPEED_FRACTION

CANDIDATES = 4000         # random poses the hold and the rest pose are chosen from
HEAT_SHARE = 0.5          # of each winding's headroom (limit − ambient) the run may use, predicted
HEAT_TAUS = 3.0           # each half of the default run lasts this many of the slowest τ_th, up to
                          # MAX_PLAYED_DURATION in all (a swing samples its motion whole)
MIN_MOVE_S = 1.0          # s: the shortest move between the poses
MIN_JERK_PEAK = 1.875     # a minimum-jerk move's peak speed over its mean speed


@dataclass
class HeatingRun:
    """Hold `hold` for hold_s, move to `rest` in move_s (minimum jerk), rest there for rest_s."""
    hold: np.ndarray      # (n,) rad
    rest: np.ndarray      # (n,) rad
    hold_s: float
    move_s: float
    rest_s: float

    @property
    def duration(self) -> float:
        return self.hold_s + self.move_s + self.rest_s

    @property
    def knots(self) -> np.ndarray:
        """The times between which q is a quintic (constant in the holds): a trajectory CSV of
        these rows, read with its quintic Hermite interpolation, is exactly this run."""
        return np.array([0.0, self.hold_s, self.hold_s + self.move_s, self.duration])

    def evaluate(self, t):
        """q, qd, qdd at times t (a leading axis of len(t))."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        s = np.clip((t - self.hold_s) / self.move_s, 0.0, 1.0)[:, None]
        moving = ((t > self.hold_s) & (t < self.hold_s + self.move_s))[:, None]
        step = self.rest - self.hold
        q = self.hold + step * (10 * s**3 - 15 * s**4 + 6 * s**5)
        qd = np.where(moving, step * (30 * s**2 - 60 * s**3 + 30 * s**4) / self.move_s, 0.0)
        qdd = np.where(moving, step * (60 * s - 180 * s**2 + 120 * s**3) / self.move_s**2, 0.0)
        return q, qd, qdd

    def pulled(self, factor: float) -> "HeatingRun":
        """The same run with the hold pose `factor` of the way from the rest pose to it."""
        hold = self.rest + factor * (self.hold - self.rest)
        return HeatingRun(hold, self.rest, self.hold_s, self.move_s, self.rest_s)


def steady_rise(model, q, per_amp, resistance, thermal_resistance) -> np.ndarray:
    """Each winding's steady rise (K, copper at 25 °C) holding poses q (m, n) against gravity."""
    zero = np.zeros_like(q)
    current = model.inverse_dynamics(q, zero, zero) / per_amp
    return current**2 * resistance * thermal_resistance


def design_heating(model, lower, upper, velocity_limit, per_amp, resistance, thermal_resistance,
                   thermal_time_constant, headroom, duration: float | None = None, heated=None,
                   margin: float = MARGIN, speed_fraction: float = SPEED_FRACTION, share: float = HEAT_SHARE,
                   seed: int = 0) -> HeatingRun:
    """The heating run of the `heated` dofs (indices; default every one with a thermal model,
    R_th > 0), `duration` s in all (default HEAT_TAUS of the slowest heated τ_th each side of the
    move, at most MAX_PLAYED_DURATION in all); per joint: `per_amp` N·m per A at the joint (torque constant × gear ratio), winding
    `resistance` Ω, `thermal_resistance` K/W, `thermal_time_constant` s, `headroom` K."""
    lower, upper, velocity_limit, per_amp, resistance, thermal_resistance, thermal_time_constant, headroom = (
        np.asarray(x, dtype=float) for x in (lower, upper, velocity_limit, per_amp, resistance, thermal_resistance,
                                             thermal_time_constant, headroom))
    modelled = np.flatnonzero(thermal_resistance > 0)
    heated = modelled if heated is None else np.intersect1d(np.asarray(heated, dtype=int), modelled)
    if len(heated) == 0:
        raise ValueError("no joint to heat has a thermal model (thermal_resistance > 0)")
    span = upper - lower
    rng = np.random.default_rng(seed)
    poses = lower + span * margin + rng.random((CANDIDATES, len(lower))) * span * (1 - 2 * margin)
    rise = steady_rise(model, poses, per_amp, resistance, thermal_resistance)
    target = share * headroom
    score = np.minimum(rise[:, heated] / target[heated], 1.0).sum(axis=1)
    hold = poses[int(np.argmax(score))]
    rest = poses[int(np.argmin((rise[:, modelled] / target[modelled]).sum(axis=1)))]
    move_s = max(MIN_MOVE_S, float(np.max(MIN_JERK_PEAK * np.abs(rest - hold) / (speed_fraction * velocity_limit))))
    if duration is None:
        half = min(HEAT_TAUS * float(thermal_time_constant[heated].max()), (MAX_PLAYED_DURATION - move_s) / 2)
        return HeatingRun(hold, rest, half, move_s, half)
    if duration > MAX_PLAYED_DURATION:
        raise ValueError(f"a heating run of {duration:g} s is longer than a swing plays ({MAX_PLAYED_DURATION:g} s)")
    if not duration > move_s:
        raise ValueError(f"a heating run of {duration:g} s leaves no time to hold and rest around its "
                         f"{move_s:.3g} s move")
    half = (duration - move_s) / 2
    return HeatingRun(hold, rest, half, move_s, half)
