"""The loop's timing and stiffness, defined once: the host loop, the simulated plant, the firmware's
generated tables (`servodyn codegen`), the experiments and the demo all read them from here."""

import math

from ..errors import InputError

SMALL_TIME_STEP = 1e-3   # s: the default control period (one servo read and write; a configuration
                         # may set its own, `[control] period`) and the longest RK4 step of the plant
MIN_CONTROL_PERIOD = 1e-4   # s: 10 kHz, beyond any servo bus's round trip
TIME_STEP = 1e-2         # s: the inverse dynamics period (paper: ~10 small steps), held in between
BANDWIDTH = 20.0         # rad/s of each joint's PD on its own inertia, unless its sensors' resolution
                         # bounds it (QUANTUM_SHARE)
MAX_BANDWIDTH = 100.0    # rad/s: at 1 kHz the discrete loop keeps its damping up to about here
MIN_STIFFNESS = 2.0      # N m/rad: a servo's friction (~0.02 N m) then leaves ~0.01 rad of error
QUANTUM_SHARE = 0.3      # the torque the PD commands for one count of each sensor (an encoder tick
                         # and a velocity unit, kp dq + kd dv) stays within this share of the joint's
                         # torque scale (the largest feed-forward of its plan); through the error
                         # low-pass that leaves the command's part above 20 Hz near 2 % of its peak
ERROR_FILTER_RATIO = 6.0  # the PD's errors are low-passed at this many times the joint's bandwidth:
                          # the closed loop (PD, filter, a period's hold) then keeps a damping ratio
                          # of 0.9 or more (tests/test_gains.py)
HOME_DURATION = 2.0      # s to move from wherever the arm is to a motion's start pose
GAIN_PERIOD = 0.1        # s between two knots of a gain schedule (on the played, scaled clock)
BUS_WATCHDOG = 0.1       # s of bus silence after which the servos drop torque by themselves
OVERRUN_TOLERANCE = 10e-3   # s a real-time loop may fall behind its period schedule before it stops
                            # (overrun): a one-off delay is caught up within it, a loop slower than
                            # its period falls further behind each tick and stops within a few

MIN_PLAYED_PERIODS = 10      # a motion played faster than written spans at least this many control
                             # periods: sampled any coarser, its interior falls between two samples
MAX_PLAYED_DURATION = 600.0  # s: a played motion is sampled whole into memory (about 1 kB a period
                             # through the checks), so ten minutes is the most it may last


def check_control_period(period: float) -> str | None:
    """Why `period` (s) cannot be a control period, or None: it must be a positive number from
    MIN_CONTROL_PERIOD to TIME_STEP that divides TIME_STEP, since the inverse dynamics, computed
    every TIME_STEP, are held over a whole number of control periods."""
    if not (isinstance(period, (int, float)) and MIN_CONTROL_PERIOD <= period <= TIME_STEP):
        return (f"must be from {MIN_CONTROL_PERIOD * 1e3:g} to {TIME_STEP * 1e3:g} ms (the inverse dynamics "
                f"period), got {period!r} s")
    ratio = TIME_STEP / period
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        return (f"must divide the inverse dynamics period, {TIME_STEP * 1e3:g} ms, into whole periods "
                f"(e.g. 1, 2, 2.5 or 5 ms), got {period * 1e3:g} ms")
    return None


def plant_step(period: float) -> float:
    """The simulated plant's RK4 step for a control period: the period cut into equal steps of at
    most SMALL_TIME_STEP, so lock-step advances the plant a whole number of steps per tick."""
    return period / math.ceil(period / SMALL_TIME_STEP - 1e-9)


def played_periods(duration: float, time_scale: float, dt: float = SMALL_TIME_STEP) -> int:
    """How many control periods of dt a motion of `duration` s lasts played `time_scale` times
    slower; ValueError for a time scale that is not a positive number, or that makes it too long
    to sample, or so much faster than written that it spans under MIN_PLAYED_PERIODS (a motion
    played as written or slower is sampled at least as finely as its own clock: never refused)."""
    if not (time_scale > 0 and time_scale < float("inf")):
        raise InputError(f"the time scale must be a positive number, got {time_scale}")
    played = duration * time_scale
    if played > MAX_PLAYED_DURATION:
        raise InputError(f"at time scale {time_scale:g} the motion would last {played:.3g} s; at most "
                         f"{MAX_PLAYED_DURATION:g} s is played or checked, sampled every {dt * 1e3:g} ms")
    if time_scale < 1 and duration > 0 and played < MIN_PLAYED_PERIODS * dt:
        raise InputError(f"at time scale {time_scale:g} the motion would last {played * 1e3:.3g} ms, under "
                         f"{MIN_PLAYED_PERIODS} control periods ({MIN_PLAYED_PERIODS * dt * 1e3:g} ms): too "
                         "fast to play, and its samples would skip the motion between its ends")
    return max(1, int(round(played / dt)))
