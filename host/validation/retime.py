"""TOPP-RA for `servodyn validate --retime`: the path re-timed to the servos' limits by toppra,
then checked densely by the validator like any motion."""

from __future__ import annotations

import time

import numpy as np

from ..control.trajectory import MotionPath, Trajectory
from .checks import check
from .limits import Limits

RETIME_GRID = 400             # path points toppra plans on
RETIME_SPEED_SHARE = 0.5      # of the no-load speed given to speed, the rest of the envelope to torque
RETIME_SHRINK = 0.93          # each retry plans on limits this much tighter
RETIME_TRIES = 12
TIMELESS = {"position": "the path leaves the joint limits", "bus": "one tick's transactions outlast the control period"}
RETIME_TRIM = 1e-3            # s cut from each end of the path, where it is at rest


def retime(model, limits: Limits, path: MotionPath, margin: float, repeat: int, ambient: float):
    """The path re-timed by TOPP-RA (toppra), checked densely afterwards like any motion.

    toppra plans with constant bounds, so the envelope is linearised: each joint may turn at up to
    half its no-load speed at the supply voltage (and its velocity limit), and then needs at most
    half the stall torque to stay inside the driving line τ_s·(1 − |ω|/ω₀); its current limit
    bounds the torque too. Both are scaled by the margin. toppra sees servodyn's rigid-body RNEA
    (gravity, any payload). Its result is then re-checked every control period of the
    configuration (`limits.period`), the sampling the loop will play it at: between its grid
    points it can exceed its bounds, so a failing plan is tried again on bounds 7 % tighter.
    Where the path is at rest its speed along the path vanishes and toppra's controllable set at
    that end is undefined (it reports none); so its first and last millisecond are cut, which
    moves the start and the end by the `trimmed_rad` the result reports (~1e-7 rad on a motion
    keyframed at rest).
    Returns (trajectory, result, {duration_s, tries, toppra_s}) or (None, None, why)."""
    import toppra as ta
    import toppra.algorithm as algo
    import toppra.constraint as constraint

    ss = np.linspace(RETIME_TRIM, path.duration - RETIME_TRIM, RETIME_GRID)
    waypoints = path.evaluate(ss)[0]
    ends = path.evaluate(np.array([0.0, path.duration]))[0]
    trimmed = float(max(np.abs(waypoints[0] - ends[0]).max(), np.abs(waypoints[-1] - ends[1]).max()))
    spline = ta.SplineInterpolator(ss, waypoints)
    grid = np.linspace(ss[0], ss[-1], RETIME_GRID + 1)
    speed = np.minimum(limits.speed, RETIME_SPEED_SHARE * limits.no_load_speed / limits.gear)
    envelope = limits.gear * limits.stall_torque * (1 - RETIME_SPEED_SHARE)
    current = (limits.current - limits.no_load_current) * limits.torque_constant * limits.gear
    torque = np.minimum(envelope, np.minimum(current, limits.command))

    spent = {"rnea": 0.0, "toppra": 0.0}

    def inverse_dynamics(q, qd, qdd):
        start = time.perf_counter()
        tau = model.inverse_dynamics(q, qd, qdd)
        spent["rnea"] += time.perf_counter() - start
        return tau

    began, scale, failing = time.perf_counter(), margin, {}
    period = limits.period
    for tries in range(1, RETIME_TRIES + 1):
        vel = constraint.JointVelocityConstraint(np.column_stack([-scale * speed, scale * speed]))
        tau = constraint.JointTorqueConstraint(inverse_dynamics, np.column_stack([-scale * torque, scale * torque]),
                                               np.zeros(len(speed)),
                                               discretization_scheme=constraint.DiscretizationType.Interpolation)
        start = time.perf_counter()
        planned = algo.TOPPRA([vel, tau], spline, gridpoints=grid,
                              parametrizer="ParametrizeConstAccel").compute_trajectory(0, 0)
        spent["toppra"] += time.perf_counter() - start
        if planned is None:
            return None, None, f"toppra found no feasible timing (try {tries}: 'controllable set is empty')"
        t = np.arange(int(np.floor(planned.duration / period)) + 1) * period
        t = np.append(t, planned.duration) if planned.duration - t[-1] > 1e-9 else t
        traj = Trajectory(t=t, q=planned(t), qd=planned(t, 1), qdd=planned(t, 2), derived=True)
        result = check(model, limits, traj, margin, repeat, ambient)
        if result.passed:
            return traj, result, {"duration_s": float(planned.duration), "tries": tries,
                                  "seconds": time.perf_counter() - began, "trimmed_rad": trimmed,
                                  "toppra_s": spent["toppra"] - spent["rnea"], "rnea_s": spent["rnea"]}
        name, ratio = result.worst()
        failing[name] = failing.get(name, 0) + 1
        if name in TIMELESS:
            return None, None, (f"the '{name}' check fails at {ratio:.3g} of its limit whatever the timing "
                                f"({TIMELESS[name]}): no retiming passes")
        scale *= RETIME_SHRINK
    return None, None, (f"toppra's timings still failed the dense check after {RETIME_TRIES} tries, each on bounds "
                        f"{1 - RETIME_SHRINK:.0%} tighter than the last: the '{name}' check kept failing "
                        f"({ratio:.3g} of its limit on the last try; failed tries by check: "
                        f"{', '.join(f'{k} {v}' for k, v in sorted(failing.items()))})")
