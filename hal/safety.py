"""The `[safety]` table: what stops a run besides a servo's own fault, and what the arm does then.

    [safety]
    following_error_rad = 0.15          # or a table by dof: { elbow_flexion = 0.2, ... }
    stall_time_s = 0.1                  # at its torque limit and not moving this long: a stall
    reaction = "hold"                   # hold | float | retract | torque_off
    reaction_time_s = 1.0               # how long the reaction runs before torque goes off
    contact = true                      # the momentum observer watches for contact
    contact_threshold_nm = { shoulder_flexion = 0.9, ... }   # `servodyn contact` writes it

Every key has a default (SafetyConfig), so a file without the table is guarded as well. The
defaults and their reasons:

- following error 0.15 rad (8.6°) per joint: many times the tracking error of the built-in
  forehands on their simulated buses (under 1°) and well under what a fault looks like (an
  uncalibrated zero or a joint wired backwards runs tens of degrees off). An error this size means
  the arm is not doing the motion that was validated.
- stall: the commanded torque at STALL_TORQUE_SHARE of the joint's torque limit while the joint
  moves slower than STALL_SPEED_RAD_S, for stall_time_s (0.1 s: a swing's turnaround at full
  torque passes zero speed in a few ms; a joint pressed on a stop stays there).
- reaction "hold": a gravity-loaded arm that loses torque falls (about 190 mm in 300 ms at the
  replica's hand, contact/plan.md); holding the pose under gravity and friction compensation
  stops it within about 10 mm. `torque_off` is never the default of an arm that gravity loads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .config_check import _Checker, _is_number
from .errors import ConfigError

REACTIONS = {
    "hold": "hold the pose under gravity and friction compensation, with the scheduled gains",
    "float": "gravity compensated, no stiffness, lightly damped: the arm yields to a push",
    "retract": "back along the path the arm came by, to where it was 0.2 s before, at a capped speed",
    "torque_off": "torque off at once: the arm falls or coasts",
}
DEFAULT_REACTION = "hold"
FOLLOWING_ERROR_RAD = 0.15        # per joint (module docstring)
STALL_TIME_S = 0.1
STALL_SPEED_RAD_S = 0.05          # ~2 units of a Dynamixel's Present Velocity (0.024 rad/s)
STALL_TORQUE_SHARE = 0.95         # of the joint's torque limit: "at its limit"
REACTION_TIME_S = 1.0
SAFETY_KEYS = {"following_error_rad", "stall_time_s", "reaction", "reaction_time_s", "contact",
               "contact_threshold_nm", "observer_gain"}


@dataclass(frozen=True)
class SafetyConfig:
    """The `[safety]` table of a configuration (module docstring), per dof in model order."""
    following_error: tuple[float, ...]            # rad per dof
    stall_time: float = STALL_TIME_S              # s
    reaction: str = DEFAULT_REACTION              # a key of REACTIONS
    reaction_time: float = REACTION_TIME_S        # s
    contact: bool = True                          # the observer watches (when the loop has one)
    contact_threshold: tuple[float, ...] | None = None   # N m per dof; None: the observer's default
    observer_gain: float | None = None            # 1/s; None: the observer's default

    @classmethod
    def default(cls, dof_names) -> "SafetyConfig":
        return cls(following_error=(FOLLOWING_ERROR_RAD,) * len(dof_names))


def _per_dof(c: _Checker, key: str, dof_names, default: float | None) -> tuple[float, ...] | None:
    """A positive number for every dof, or a table by dof name (unnamed dofs take the default)."""
    if key not in c.table:
        return None if default is None else (default,) * len(dof_names)
    value = c.table[key]
    if _is_number(value):
        values = {name: float(value) for name in dof_names}
    elif isinstance(value, dict):
        unknown = sorted(set(value) - set(dof_names))
        if unknown:
            c.fail(key, f"names {unknown[0]!r}, not a dof of the model ({', '.join(dof_names)})")
        if default is None and len(value) != len(dof_names):
            missing = [d for d in dof_names if d not in value]
            c.fail(key, f"has no value for {missing[0]!r} (every dof needs one)")
        values = {name: value.get(name, default) for name in dof_names}
    else:
        c.fail(key, f"must be a number or a table by dof, got {value!r}")
    for name, v in values.items():
        if not (_is_number(v) and v > 0):
            c.fail(key, f"must be positive for every dof, got {v!r} for {name!r}")
    return tuple(float(values[name]) for name in dof_names)


def safety_from_table(table, where: str, dof_names) -> SafetyConfig:
    c = _Checker(table, where, SAFETY_KEYS)
    reaction = c.get("reaction", "str", DEFAULT_REACTION)
    if reaction not in REACTIONS:
        c.fail("reaction", f"must be one of {', '.join(REACTIONS)}, got {reaction!r}")
    contact = table.get("contact", True)
    if not isinstance(contact, bool):
        raise ConfigError(f"{where}: 'contact' must be true or false, got {contact!r}")
    stall_time = c.get("stall_time_s", "float", STALL_TIME_S)
    reaction_time = c.get("reaction_time_s", "float", REACTION_TIME_S)
    for key, value, high in (("stall_time_s", stall_time, 10.0), ("reaction_time_s", reaction_time, 60.0)):
        if not 0 < value <= high:
            c.fail(key, f"must be in (0, {high:g}] s, got {value:g}")
    gain = c.get("observer_gain", "float", math.nan)
    if "observer_gain" in table and not 0 < gain <= 1000:
        c.fail("observer_gain", f"must be in (0, 1000] 1/s, got {gain:g}")
    return SafetyConfig(following_error=_per_dof(c, "following_error_rad", dof_names, FOLLOWING_ERROR_RAD),
                        stall_time=stall_time, reaction=reaction, reaction_time=reaction_time, contact=contact,
                        contact_threshold=_per_dof(c, "contact_threshold_nm", dof_names, None),
                        observer_gain=gain if "observer_gain" in table else None)
