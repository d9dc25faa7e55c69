"""The run's guards: a following error, a stall, a contact — each a safe stop of its own.

`Guards(config, period, observer)` is checked by the loop every tick after the read and before
the write (`follow`'s `guard`), on the measured state, the desired position and the torque the
tick would command:

- following error: |q_d − q| of a joint above its limit (`[safety] following_error_rad`);
- stall: the commanded torque at STALL_TORQUE_SHARE of the joint's torque limit while the joint
  moves slower than STALL_SPEED_RAD_S, for `stall_time_s` without a break;
- contact: the observer (servodyn.control.contact, when the run has one) detects one.

Each raises a SafetyStop whose `detail` is what summary.json says of it; its times are on the
motion's clock (0 when the motion starts, negative while homing). The reaction it asks for is the
configuration's (`[safety] reaction`, hal.safety), run by servodyn.loop.reaction.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from ..errors import FAULT_CODES, ExitCode, ServodynError, exit_code
from ..hal.safety import STALL_SPEED_RAD_S, STALL_TORQUE_SHARE

# s before a contact's detection: the pose a hold keeps, about the observer's detection delay (the
# arm was that much further into what it met when the detection came)
HOLD_LOOKBACK_S = 0.01


class SafetyStop(ServodynError):
    """A run stopped by a guard; `stop_reason` is summary.json's word for it, `detail` its fields
    there, `hold_pose` the pose a `hold` reaction keeps and `velocity` the joints' speed at the stop:
    given, the hold first brings the arm to rest from it (servodyn.loop.reaction); None (a contact),
    it pulls back to `hold_pose`, where the arm was before it met what it met."""
    stop_reason = "safety"

    def __init__(self, message: str, detail: dict, hold_pose, velocity=None):
        self.detail, self.hold_pose = detail, np.array(hold_pose, dtype=float)
        self.velocity = None if velocity is None else np.array(velocity, dtype=float)
        super().__init__(message)


class FollowingError(SafetyStop):
    exit_code = ExitCode.FOLLOWING_ERROR
    stop_reason = "following_error"


class Stall(SafetyStop):
    exit_code = ExitCode.STALL
    stop_reason = "stall"


class ContactStop(SafetyStop):
    exit_code = ExitCode.CONTACT
    stop_reason = "contact"


class Guards:
    """The checks of one run (module docstring). `offset` is added to a segment's time to put it
    on the motion's clock (`at_offset`); `observer`: a contact observer with reset(q, qd),
    update(t, q, qd, tau_measured) and `detection` (None or its Detection), or None; reset at
    the first tick unless `fresh_observer` is False (a reaction's guards go on feeding the run's)."""

    def __init__(self, config, period: float, observer=None, *, following=True, stall=True, detect=True,
                 fresh_observer=True):
        safety = config.guards
        self.names = config.model.dof_names
        self.limit = np.array(safety.following_error) if following else None
        self.torque_limit = np.array([j.torque_limit for j in config.joints])
        self.stall_ticks = max(1, int(np.ceil(safety.stall_time / period - 1e-9))) if stall else None
        self.observer, self.period = observer, period
        self.offset = 0.0
        self._pressed = np.zeros(len(self.names), dtype=int)
        # the poses of the last ticks: a contact's hold pose is where the arm was before it began
        self._recent = deque(maxlen=max(1, int(round(HOLD_LOOKBACK_S / period))) + 1)
        self.detect = detect              # False: the observer is fed, its detection stops nothing
        self._started = not fresh_observer
        self.last = None

    def at_offset(self, offset: float) -> "Guards":
        """From now on a segment's time t is t + offset on the motion's clock."""
        self.offset = offset
        return self

    def __call__(self, t: float, q_d, state, tau) -> None:
        q, qd = state.q, state.qd
        when = float(t + self.offset)
        self.last = (t, q)          # the segment's time and the pose of the last tick checked
        self._recent.append(q)
        if self.observer is not None:
            if not self._started:
                self.observer.reset(q, qd)
                self._started = True
            self.observer.update(when, q, qd, state.tau)
        if self.limit is not None:
            error = np.abs(np.asarray(q_d) - q)
            over = error > self.limit
            if over.any():
                j = int(np.argmax(np.where(over, error / self.limit, 0.0)))
                raise FollowingError(
                    f"following error: joint '{self.names[j]}' {np.degrees(error[j]):.1f}° from its command at "
                    f"t = {when:.3f} s (limit {np.degrees(self.limit[j]):.1f}°)",
                    {"joint": self.names[j], "t_s": when, "value": float(error[j]), "limit": float(self.limit[j])},
                    q, qd)
        if self.stall_ticks is not None:
            pressed = (np.abs(tau) >= STALL_TORQUE_SHARE * self.torque_limit) & (np.abs(qd) < STALL_SPEED_RAD_S)
            self._pressed = np.where(pressed, self._pressed + 1, 0)
            if (self._pressed >= self.stall_ticks).any():
                j = int(np.argmax(self._pressed))
                held = self._pressed[j] * self.period
                raise Stall(
                    f"stall: joint '{self.names[j]}' commanded {abs(tau[j]):.2f} N m (its limit "
                    f"{self.torque_limit[j]:.2f}) without moving for {held * 1e3:.0f} ms, at t = {when:.3f} s",
                    {"joint": self.names[j], "t_s": when, "value": float(abs(tau[j])),
                     "limit": float(self.torque_limit[j])}, q, qd)
        if self.observer is not None and self.detect:
            found = self.observer.detection
            if found is not None:
                raise ContactStop(
                    f"contact: link '{found.link}' at t = {found.t_s:.3f} s, about {found.force_estimate_n:.1f} N "
                    f"(joint '{found.joint}' first over its threshold)",
                    {"detected_t_s": float(found.t_s), "link": found.link,
                     "force_estimate_n": float(found.force_estimate_n)}, self._recent[0])


def stop_reason(error, completed: bool) -> str:
    """summary.json's `stop_reason`: "completed", a guard's word (contact, following_error, stall),
    the fault's name as the firmware says it (timeout, status, ... : ExitCode's, lower case),
    "interrupted" for a signal, "incomplete" for a run that ended early without an error."""
    if error is None:
        return "completed" if completed else "incomplete"
    if isinstance(error, SafetyStop):
        return error.stop_reason
    code = exit_code(error)
    if code > 128:
        return "interrupted"
    return ExitCode(code).name.lower() if code in FAULT_CODES else "error"
