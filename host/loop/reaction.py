"""What the arm does after a guard stops a run: the `[safety] reaction` (hal.safety.REACTIONS).

A reaction is one more segment for the loop (`follow`), reacting for `[safety] reaction_time_s`
before torque goes off:

- hold: a moving arm brought to rest over STOP_TIME_S, then its pose held (for a contact: pulled
  back to where the arm was before it met what it met, servodyn.loop.safety) by the feed-forward
  + PD controller with the gains the run had at that moment, so gravity and friction are
  compensated;
- float: computed torque with no stiffness and FLOAT_DAMPING: gravity compensated, the arm yields
  to a push and comes to rest;
- retract: a minimum-jerk move back to where the plan was RETRACT_BACK_S before the stop, no joint
  faster than RETRACT_SPEED_RAD_S, then held there;
- torque_off: nothing: torque goes off at once.

The reaction is watched by guards of its own (a following error from its own target, a stall):
a hold that cannot hold — a joint wired backwards pushes away from any pose — gives way to
torque off (`Reaction.gave_way`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..control import ControlConfig, Controller
from ..control.schedule import GainSchedule, Segment, homing
from ..control.trajectory import Trajectory
from . import follow
from .safety import Guards, SafetyStop

RETRACT_BACK_S = 0.2          # s of the path a retract goes back along
RETRACT_SPEED_RAD_S = 0.5     # the fastest a joint retracts
FLOAT_DAMPING = 4.0           # 1/s: float's velocity decays with a 0.25 s time constant
MIN_JERK_PEAK = 1.875         # a minimum-jerk move's peak speed over its mean speed
STOP_TIME_S = 0.02            # a hold brings a moving arm to rest over this long
SETTLE_AFTER_S = 0.04         # then, this long after the stop, holds the pose it came to rest at


@dataclass
class Reaction:
    """A reaction planned for one stop: the controller and the segment the loop follows."""
    kind: str
    controller: Controller | None
    segment: Segment | None
    gave_way: str | None = None      # why the reaction was cut short (torque went off)
    settle_tick: int | None = None   # from this tick the target is where the arm is (it came to rest)

    def play(self, bus, log, realtime: bool, config, observer=None, contact=None) -> None:
        """Follow the reaction's segment on the bus; a guard that trips in it ends it early.
        `contact`: the run's contact observer, fed on (its isolation and force estimate settle
        meanwhile), never stopping it."""
        if self.segment is None:
            return
        # float has no target to fall behind: only a stall ends it early
        guard = Guards(config, config.control_period, contact, following=self.kind != "float", detect=False,
                       fresh_observer=False)
        traj = self.segment.traj

        def settle(k):
            # the braking's end: the pose held from here is the one the arm stopped at, not the one
            # planned (a soft PD would creep the last millimetres to it for half a second)
            if k == self.settle_tick and guard.last is not None:
                traj.q[k:] = guard.last[1]
        try:
            follow(bus, self.controller, self.segment, log, realtime, observer=observer, guard=guard,
                   on_tick=settle if self.settle_tick is not None else None)
        except SafetyStop as err:
            self.gave_way = str(err)


def _to_rest(q0, qd0, n: int, period: float, t0: float) -> Trajectory:
    """From (q0, qd0) to rest at a constant deceleration over STOP_TIME_S, then held: the feed-forward
    carries the deceleration, so the arm stops within qd0·STOP_TIME_S/2 of q0 (10 mm from 1 m/s)."""
    t = np.arange(n) * period
    s = np.minimum(t, STOP_TIME_S)[:, None]
    braking = (t < STOP_TIME_S)[:, None]
    q0, qd0 = np.asarray(q0, dtype=float), np.asarray(qd0, dtype=float)
    return Trajectory(t=t0 + t, q=q0 + qd0 * (s - s**2 / (2 * STOP_TIME_S)), qd=qd0 * (1 - s / STOP_TIME_S),
                      qdd=np.where(braking, -qd0 / STOP_TIME_S, 0.0), derived=False)


def _held(kp, kd, lowpass) -> GainSchedule:
    return GainSchedule(t=np.array([0.0, 1.0]), kp=np.array([kp, kp]), kd=np.array([kd, kd]), error_lowpass=lowpass)


def plan_reaction(config, stop: SafetyStop, segment: Segment, k: int, q_now, t0: float,
                  feedforward: bool = True) -> Reaction:
    """The configured reaction to `stop`, which tripped at sample k of `segment` with the arm at
    q_now; its first tick at time t0 on the run's clock (the log's)."""
    safety, period = config.guards, config.control_period
    kind = safety.reaction
    n = max(2, int(round(safety.reaction_time / period)))
    if kind == "torque_off":
        return Reaction(kind, None, None)
    model = config.model
    kp, kd = segment.gains.at(segment.traj.t[k] - segment.traj.t[0])
    lowpass = segment.gains.error_lowpass
    if kind == "float":
        controller = Controller(model, ControlConfig(mode="computed_torque", small_time_step=period,
                                                     kp=0.0, kd=FLOAT_DAMPING))
        gains = _held(np.zeros(model.nv), np.full(model.nv, FLOAT_DAMPING), None)
        return Reaction(kind, controller, Segment("float", Trajectory.still(q_now, n, period, t0), gains))
    friction = config.friction if feedforward else {}
    controller = Controller(model, ControlConfig(mode="feedforward_pd", small_time_step=period, **friction))
    if kind == "hold":
        if stop.velocity is None:
            return Reaction(kind, controller, Segment("hold", Trajectory.still(stop.hold_pose, n, period, t0),
                                                      _held(kp, kd, lowpass)))
        return Reaction(kind, controller, Segment("hold", _to_rest(stop.hold_pose, stop.velocity, n, period, t0),
                                                  _held(kp, kd, lowpass)),
                        settle_tick=min(n - 1, int(round(SETTLE_AFTER_S / period))))
    back = segment.traj.q[max(0, k - int(round(RETRACT_BACK_S / period)))]
    distance = float(np.abs(back - q_now).max())
    duration = max(4 * period, MIN_JERK_PEAK * distance / RETRACT_SPEED_RAD_S)
    move = homing(q_now, back, duration, period)
    rest = Trajectory.still(back, max(2, n - len(move.t)), period)
    traj = Trajectory(t=t0 + np.arange(len(move.t) + len(rest.t)) * period, q=np.vstack([move.q, rest.q]),
                      qd=np.vstack([move.qd, rest.qd]), qdd=np.vstack([move.qdd, rest.qdd]), derived=False)
    return Reaction(kind, controller, Segment("retract", traj, _held(kp, kd, lowpass)))
