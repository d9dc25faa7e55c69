"""Offline validation: will this motion, on these servos, at this supply voltage, stay inside
every limit — and what is the fastest uniform timing that does?

The motion is sampled densely, every small_time_step of the played clock (never only at the
keyframes); the joint torques of every sample come from the core's RNEA in one batched call
(gravity and any payload included: `[payload]` is in the configuration's model, `--payload` adds
on top), plus each joint's friction from the configuration (F_c·sign(q̇) + F_v·q̇): the torque
the servo gives. Currents convert with the configuration's torque constant times its identified
scale, heat with each joint's thermal constants (the servo's data sheet's unless configured). Then, per joint and per sample, each check gives a ratio,
1 at its limit; a check passes where every ratio stays within the margin:

  position       |q − middle| / half the range                   (the configured joint limits)
  speed          |q̇| / min(velocity limit, ω₀(V) / gear)          (no-load speed at the supply)
  torque_speed   the DC-motor envelope at supply V, at the horn:
                   driving (τ·ω ≥ 0):  |τ|/τ_s(V) + |ω|/ω₀(V)     (1 on the line τ_s·(1 − |ω|/ω₀))
                   braking (τ·ω < 0):  |τ| / (τ_s(V)·(1 + |ω|/ω₀(V))): the back-EMF adds to the
                   supply, so the winding can carry more than the stall current; what bounds it is
                   the current limit, checked next
  current        (|τ| / (K_t·gear) + I₀) / the joint's current limit
  temperature    (T − T_amb) / (T_limit − T_amb), T from the first-order winding model
                   C_th·dT/dt = I²·R·(1 + α(T − 25 °C)) − (T − T_amb)/R_th over `repeat` plays
  supply         the robot's supply current, Σ max(0, Σ_servos I²R + τ·ω) / V, / its rating
  bus            one tick's bytes or frames on the wire / the control period
  command_range  |τ| / the largest torque the wire can command (Dynamixel: Goal Current within
                   ±Current Limit); its quantization step is reported

`Limits.of(config, V)` gathers every limit of a configuration at a supply voltage; `check` runs
every check over a trajectory sampled at the control period (`control.MotionPath.at_scale`);
`violations` and `describe` say where and why it fails (`judge` does all three for a motion); `fit_time_scale` finds the slowest
uniform timing needed, `retime` a TOPP-RA timing (toppra) that passes. `people` checks each link's
speed against ISO/TS 15066's transient-contact limits near people (`validate --near-people`). `servodyn validate`
(host/report/validation.py) is its report, `servodyn validate` the command; the swing and the view ask the same checks.
"""

from .checks import (CHECKS, Judgement, MotionRefused, Result, check, describe, judge, torque_speed_ratio,
                     violations)
from .fit import fit_time_scale
from .limits import Limits
from .retime import retime
from ..hal.thermal import AMBIENT, winding_temperature

__all__ = ["AMBIENT", "CHECKS", "Judgement", "Limits", "MotionRefused", "Result", "check", "describe",
           "fit_time_scale", "judge", "retime", "torque_speed_ratio", "violations", "winding_temperature"]
