"""The checks of a trajectory against a configuration's limits (see the package's docstring), the
violations they find and a sentence for each."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control.trajectory import MotionPath, Trajectory
from ..errors import ServodynError
from ..readable import fixed, percent
from .limits import Limits
from ..hal.thermal import AMBIENT, winding_temperature

class MotionRefused(ServodynError, ValueError):
    """The validator says a motion would leave a servo's limits: nothing moved. One line, the
    first violation; `violations` has every one (`servodyn swing --verbose` prints them)."""

    def __init__(self, message: str, violations: list[str] = ()):
        super().__init__(message)
        self.violations = list(violations)


CHECKS = ("position", "speed", "torque_speed", "current", "temperature", "supply", "bus", "command_range")


@dataclass
class Result:
    """The checks of one motion at one time scale."""
    t: np.ndarray                # (N,) s, played clock
    q: np.ndarray                # (N, n)
    qd: np.ndarray
    tau: np.ndarray              # (N, n) N m at the joints
    current: np.ndarray          # (N, n) A drawn
    temperature: np.ndarray      # (N, n) °C over the last play
    supply_current: np.ndarray   # (N,) A from the supply
    power: np.ndarray            # (N,) W electrical, all servos
    ratios: dict                 # check -> (N, n) ratios (supply and bus: (N, 1))
    values: dict                 # check -> (N, n) the compared value
    limits_at: dict              # check -> (N, n) the limit it is compared with
    margin: float

    def peak(self, check: str) -> np.ndarray:
        return self.ratios[check].max(axis=0)

    def allowed(self, check_name: str) -> float:
        """The ratio a check may reach: the margin, but the full range for position (the
        configured joint limits are the range itself)."""
        return 1.0 if check_name == "position" else self.margin

    @property
    def passed(self) -> bool:
        return all(float(r.max(initial=0.0)) <= self.allowed(name) for name, r in self.ratios.items())

    def worst(self) -> tuple[str, float]:
        """The check nearest (or furthest past) what it allows, and its peak ratio."""
        name = max(self.ratios, key=lambda c: float(self.ratios[c].max(initial=0.0)) / self.allowed(c))
        return name, float(self.ratios[name].max(initial=0.0))


def check(model, limits: Limits, traj: Trajectory, margin: float = 1.0, repeat: int = 1,
          ambient: float = AMBIENT) -> Result:
    """Every check of a trajectory sampled at the control period (see the module's docstring)."""
    L = limits
    q, qd, qdd = traj.q, traj.qd, traj.qdd
    # the torque each servo gives: rigid body (one batched call into the C core) and the joint's friction
    tau = model.inverse_dynamics(q, qd, qdd) + L.friction(qd)
    n_samples = len(traj.t)
    ratios, values, bounds = {}, {}, {}

    middle, half = (L.lower + L.upper) / 2, (L.upper - L.lower) / 2
    ratios["position"] = np.abs(q - middle) / half
    values["position"] = q
    bounds["position"] = np.where(q >= middle, L.upper, L.lower)

    ratios["speed"] = np.abs(qd) / L.speed
    values["speed"], bounds["speed"] = np.abs(qd), np.broadcast_to(L.speed, qd.shape)

    ratios["torque_speed"], driving, along = torque_speed_ratio(L, tau, qd)
    torque = np.abs(tau) / L.gear                         # at the horn
    values["torque_speed"] = np.abs(tau)
    bounds["torque_speed"] = L.gear * L.stall_torque * np.where(driving, np.maximum(0.0, 1 - along), 1 + along)

    motor = torque / L.torque_constant                    # A the torque needs
    current = motor + L.no_load_current
    # a joint in PWM mode has no current limit: the duty its torque needs at its speed (back-EMF included)
    duty = np.abs(L.duty(tau, qd))
    ratios["current"] = np.where(L.pwm, duty, current / L.current)
    values["current"], bounds["current"] = np.where(L.pwm, duty, current), np.where(L.pwm, 1.0, L.current + 0 * current)

    temperature = winding_temperature(current, traj.t[1] - traj.t[0] if n_samples > 1 else L.period,
                                      L, repeat, ambient)
    modelled = L.thermal_resistance > 0
    rise = np.where(modelled, (temperature - ambient) / (L.temperature - ambient), 0.0)
    ratios["temperature"] = rise
    values["temperature"], bounds["temperature"] = temperature, np.broadcast_to(L.temperature, temperature.shape)

    # the supply: each servo's electrical power, copper loss plus mechanical (negative braking:
    # regenerated into the shared bus), the no-load current's losses at the back-EMF aside
    power = (motor**2 * L.resistance + tau * qd).sum(axis=1)   # horn τ·ω is the joint's τ·q̇
    supply = np.maximum(power, 0.0) / L.voltage
    if L.supply_current:
        ratios["supply"] = (supply / L.supply_current)[:, None]
    else:
        ratios["supply"] = np.zeros((n_samples, 1))
    values["supply"] = supply[:, None]
    bounds["supply"] = np.full((n_samples, 1), L.supply_current or math.inf)

    # one tick's transactions against the configuration's control period, however the motion
    # was sampled (a retimed path's last sample is closer than a period)
    wire = max((seconds for _, seconds, _ in L.wire), default=0.0)
    ratios["bus"] = np.full((n_samples, 1), wire / L.period)
    values["bus"], bounds["bus"] = np.full((n_samples, 1), wire), np.full((n_samples, 1), L.period)

    ratios["command_range"] = np.abs(tau) / L.command
    values["command_range"], bounds["command_range"] = np.abs(tau), np.broadcast_to(L.command, tau.shape)
    return Result(t=traj.t, q=q, qd=qd, tau=tau, current=current, temperature=temperature,
                  supply_current=supply, power=power, ratios=ratios, values=values, limits_at=bounds,
                  margin=margin)


def torque_speed_ratio(L: Limits, tau: np.ndarray, qd: np.ndarray):
    """Each joint torque's share of its servo's DC-motor envelope at its speed (1 on the limit),
    and per sample whether it drives (τ·q̇ ≥ 0) and the speed's share of the no-load speed."""
    omega = np.abs(qd) * L.gear                           # at the horn
    torque = np.abs(tau) / L.gear
    driving = tau * qd >= 0
    along = omega / L.no_load_speed
    ratio = np.where(driving, torque / L.stall_torque + along, torque / (L.stall_torque * (1 + along)))
    return ratio, driving, along


def violations(result: Result, dof_names) -> list[dict]:
    """The first sample over the margin, per check and joint (supply and bus: dof None)."""
    found = []
    for name in CHECKS:
        over = result.ratios[name] > result.allowed(name)
        for j in range(over.shape[1]):
            hits = np.flatnonzero(over[:, j])
            if hits.size:
                k = int(hits[0])
                found.append({"check": name, "dof": dof_names[j] if over.shape[1] > 1 else None,
                              "t_s": float(result.t[k]), "value": float(result.values[name][k, j]),
                              "limit": float(result.limits_at[name][k, j]),
                              "ratio": float(result.ratios[name][k, j])})
                worst = int(np.argmax(result.ratios[name][:, j]))
                found[-1].update(worst_ratio=float(result.ratios[name][worst, j]), worst_t_s=float(result.t[worst]))
                if name == "torque_speed":
                    found[-1]["speed_rad_s"] = float(result.qd[k, j])
    return sorted(found, key=lambda v: (v["t_s"], CHECKS.index(v["check"])))


def describe(violation: dict, config, limits: Limits, repeat: int, margin: float) -> str:
    """One line a person understands, for a violation (naming the margin when it is not 1)."""
    line = _describe(violation, config, limits, repeat)
    if violation["worst_ratio"] > violation["ratio"] * 1.001:
        line += f"; at worst {percent(violation['worst_ratio'])} of its limit, at t = {fixed(violation['worst_t_s'], 3)} s"
    if margin != 1 and violation["check"] != "position":
        line += f" (the margin allows {margin:.0%})"
    return line


def _describe(violation: dict, config, limits: Limits, repeat: int) -> str:
    check_name, dof, t, value, limit = (violation[k] for k in ("check", "dof", "t_s", "value", "limit"))
    when = f"at t = {fixed(t, 3)} s"
    if dof is not None:
        j = config.model.dof_names.index(dof)
        servo = config.joints[j].servo.name
    V = f"{limits.voltage:g} V"
    if check_name == "position":
        return f"{dof} reaches {fixed(value, 3)} rad {when}; its limit is {fixed(limit, 3)} rad"
    if check_name == "speed":
        return f"{dof} needs {fixed(abs(value), 2)} rad/s {when}; its {servo} turns {fixed(limit, 2)} rad/s at {V} (or its velocity limit)"
    if check_name == "torque_speed":
        return (f"{dof} needs {fixed(value, 2)} N·m at {fixed(abs(violation['speed_rad_s']), 2)} rad/s {when}: "
                f"{percent(violation['ratio'])} of its {servo}'s torque-speed envelope at {V} (it gives {fixed(limit, 2)} N·m "
                f"at that speed)")
    if check_name == "current" and limits.pwm[j]:
        return (f"{dof} needs {percent(value)} duty of the {V} supply {when} (its torque and back-EMF); "
                f"its {servo}'s PWM Limit gives 100 %")
    if check_name == "current":
        return f"{dof} draws {fixed(value, 2)} A {when}; its current limit is {fixed(limit, 2)} A"
    if check_name == "temperature":
        return (f"{dof}'s winding reaches {fixed(value, 1)} °C {when} of play {repeat}; the {servo} faults at "
                f"{fixed(limit, 0)} °C")
    if check_name == "supply":
        return f"the servos draw {fixed(value, 2)} A from the {V} supply {when}; it is rated {fixed(limit, 2)} A"
    if check_name == "bus":
        what = "; ".join(f"{name}: {text}" for name, _, text in limits.wire)
        return f"one tick's transactions take {fixed(value * 1e3, 3)} ms on the wire ({what}); the period is {limit * 1e3:g} ms"
    return f"{dof} needs {fixed(value, 2)} N·m {when}; its wire commands at most {fixed(limit, 2)} N·m"


@dataclass
class Judgement:
    """A motion's checks on a configuration: the limits, the result and its violations (each with
    its sentence, `message`), first in time first."""
    path: MotionPath
    time_scale: float
    limits: Limits
    result: Result
    violations: list

    @property
    def passed(self) -> bool:
        return self.result.passed


def judge(config, path: MotionPath, time_scale: float = 1.0, *, model=None, voltage: float | None = None,
          margin: float = 1.0, repeat: int = 1, ambient: float = AMBIENT) -> Judgement:
    """Every check of `path` played `time_scale` times slower on the configuration's servos (and
    `model`, e.g. with a payload; default the configuration's), at `voltage` (default its supply's),
    sampled at its control period."""
    model = model or config.model
    limits = Limits.of(config, config.supply.voltage if voltage is None else voltage)
    result = check(model, limits, path.at_scale(time_scale, limits.period), margin, repeat, ambient)
    found = violations(result, model.dof_names)
    for v in found:
        v["message"] = describe(v, config, limits, repeat, margin)
    return Judgement(path, time_scale, limits, result, found)
