"""`servodyn validate`: will this motion, on these servos, at this supply voltage, stay inside
every limit — and what is the fastest uniform timing that does?

The motion is sampled densely, every small_time_step of the played clock (never only at the
keyframes); the joint torques of every sample come from the core's RNEA in one batched call
(gravity and any payload included). Then, per joint and per sample, each check gives a ratio,
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

Exit status 0 pass, 1 fail, 2 bad input; DIR/report.json and plots in DIR.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..control.motion import builtin_motions, load_motion
from ..control.timing import SMALL_TIME_STEP, played_periods
from ..control.trajectory import Trajectory, TrajectoryError, read_trajectory_csv, write_trajectory_csv
from ..hal.bus import backend_class
from ..hal.config import supply_voltage_error
from ..hal.dynamixel.units import ServoMap
from ..readable import fixed, percent

CHECKS = ("position", "speed", "torque_speed", "current", "temperature", "supply", "bus", "command_range")
COPPER_ALPHA = 0.00393      # 1/°C: copper's resistance rises with temperature
AMBIENT = 25.0              # °C
CHUNK = 4096                # samples of the thermal recurrence evaluated at once
MAX_REPEAT = 10_000         # plays of a motion for the heat: hours of even a short motion


@dataclass(frozen=True)
class MotionPath:
    """A motion as a path sampled at its own (human-speed) clock: played at time scale s it is
    sampled again every small_time_step of the played clock (`at_scale`)."""
    name: str
    duration: float                       # s at time scale 1
    evaluate: object                      # t (s, scale-1 clock) -> (q, qd, qdd)

    def at_scale(self, scale: float, dt: float = SMALL_TIME_STEP) -> Trajectory:
        n = played_periods(self.duration, scale, dt)
        t = np.arange(n + 1) * dt
        q, qd, qdd = self.evaluate(np.minimum(t / scale, self.duration))
        return Trajectory(t=t, q=q, qd=qd / scale, qdd=qdd / scale**2, derived=True)


def motion_path(spec: str, model) -> MotionPath:
    """A built-in motion by name, a keyframe file (.toml) or a trajectory CSV (.csv)."""
    if str(spec).lower().endswith(".csv"):
        traj = read_trajectory_csv(spec, model.dof_names)
        return csv_path(Path(spec).stem, traj)
    if str(spec) not in builtin_motions() and not Path(spec).exists():
        raise TrajectoryError(f"{spec}: no such file, and not a built-in motion "
                              f"({', '.join(builtin_motions()) or 'none installed'})")
    motion = load_motion(spec, model)
    return MotionPath(motion.name, motion.duration, motion.at)


def csv_path(name: str, traj: Trajectory) -> MotionPath:
    """A trajectory CSV as a path: its samples where it has them, and between them the C2 cubic
    spline of q (a CSV sampled coarser than the control period is refined, not held)."""
    t0 = traj.t[0]
    if len(traj.t) > 1 and np.max(np.diff(traj.t)) <= SMALL_TIME_STEP * (1 + 1e-9):
        index = np.arange(len(traj.t), dtype=float)

        def evaluate(t):     # the nearest sample, on the CSV's own clock from its first row
            k = np.rint(np.interp(t, traj.t - t0, index)).astype(int)
            return traj.q[k], traj.qd[k], traj.qdd[k]
    else:
        from scipy.interpolate import CubicSpline
        with np.errstate(all="ignore"):
            try:
                spline = CubicSpline(traj.t - t0, traj.q, axis=0)
            except ValueError:          # scipy refuses its own overflowed slopes
                spline = None
        if spline is None or not np.all(np.isfinite(spline.c)):
            raise TrajectoryError(f"{name}.csv: the spline through q overflows between the samples (values "
                                  "or time steps too extreme)")

        def evaluate(t):
            return spline(t), spline(t, 1), spline(t, 2)
    return MotionPath(name, float(traj.t[-1] - t0), evaluate)


@dataclass
class Limits:
    """Every per-joint limit the checks compare with, at one supply voltage (arrays per joint)."""
    lower: np.ndarray
    upper: np.ndarray
    speed: np.ndarray            # rad/s at the joint
    stall_torque: np.ndarray     # N m at the horn, at the supply voltage
    no_load_speed: np.ndarray    # rad/s at the horn, at the supply voltage
    gear: np.ndarray             # horn turns per joint turn
    torque_constant: np.ndarray  # N m / A at the horn
    current: np.ndarray          # A
    no_load_current: np.ndarray  # A
    resistance: np.ndarray       # Ω at 25 °C
    thermal_resistance: np.ndarray
    thermal_time_constant: np.ndarray
    temperature: np.ndarray      # °C
    command: np.ndarray          # N m at the joint
    command_step: np.ndarray     # N m
    voltage: float
    supply_current: float | None
    wire: list = field(default_factory=list)   # (bus name, seconds per tick, description)
    period: float = SMALL_TIME_STEP            # s: the configuration's control period, the sampling

    @classmethod
    def of(cls, config, voltage: float) -> "Limits":
        joints = config.joints
        servos = [j.servo for j in joints]
        command = [backend_class(config.buses[j.bus].kind).command_range(j) for j in joints]
        wire = []
        for name, bus in config.buses.items():
            seconds, what = backend_class(bus.kind).wire_time(config.joints_on(name), bus)
            wire.append((name, seconds, what))
        arr = lambda values: np.array(list(values), dtype=float)
        gear = arr(j.gear_ratio for j in joints)
        no_load = arr(s.no_load_speed_at(voltage) for s in servos)
        return cls(lower=arr(j.position_limits[0] for j in joints), upper=arr(j.position_limits[1] for j in joints),
                   speed=np.minimum(arr(j.velocity_limit for j in joints), no_load / gear),
                   stall_torque=arr(s.stall_torque_at(voltage) for s in servos), no_load_speed=no_load, gear=gear,
                   torque_constant=arr(j.torque_constant for j in joints), current=arr(j.current_limit for j in joints),
                   no_load_current=arr(s.no_load_current for s in servos),
                   resistance=arr(s.winding_resistance for s in servos),
                   thermal_resistance=arr(s.thermal_resistance for s in servos),
                   thermal_time_constant=arr(s.thermal_time_constant for s in servos),
                   temperature=arr(s.temperature_limit for s in servos),
                   command=arr(c[0] for c in command), command_step=arr(c[1] for c in command),
                   voltage=voltage, supply_current=config.supply.current_limit if config.supply else None,
                   wire=wire, period=config.control_period)


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


def check(model, limits: Limits, traj: Trajectory, margin: float = 1.0, repeat: int = 1,
          ambient: float = AMBIENT) -> Result:
    """Every check of a trajectory sampled at the control period (see the module's docstring)."""
    L = limits
    q, qd, qdd = traj.q, traj.qd, traj.qdd
    tau = model.inverse_dynamics(q, qd, qdd)              # one batched call into the C core
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
    ratios["current"] = current / L.current
    values["current"], bounds["current"] = current, np.broadcast_to(L.current, current.shape)

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

    period = traj.t[1] - traj.t[0] if n_samples > 1 else L.period
    wire = max((seconds for _, seconds, _ in L.wire), default=0.0)
    ratios["bus"] = np.full((n_samples, 1), wire / period)
    values["bus"], bounds["bus"] = np.full((n_samples, 1), wire), np.full((n_samples, 1), period)

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


def winding_temperature(current: np.ndarray, dt: float, L: Limits, repeat: int, ambient: float) -> np.ndarray:
    """The winding temperature over the last of `repeat` plays, from ambient at the start of the
    first. Within a sample the current is held, so C·dT/dt = a·T + b is linear in T and each step
    is exact: T ← e^(a·dt/C)·T + (b/a)·(e^(a·dt/C) − 1). Unmodelled servos (R_th = 0) stay at ambient."""
    modelled = L.thermal_resistance > 0
    r_th = np.where(modelled, L.thermal_resistance, 1.0)
    capacity = np.where(modelled, L.thermal_time_constant, 1.0) / r_th
    heat = current**2 * L.resistance                      # W at 25 °C
    a = (heat * COPPER_ALPHA - 1 / r_th) / capacity       # 1/s
    b = (heat * (1 - 25.0 * COPPER_ALPHA) + ambient / r_th) / capacity
    log_decay = a * dt
    gain = np.where(np.abs(a) > 1e-15, np.expm1(log_decay) / np.where(a == 0, 1, a), dt) * b
    temperature = np.full(current.shape[1], float(ambient))
    out = np.empty_like(current)
    for _ in range(max(1, repeat)):
        # T_k = D_k·(T_0 + Σ_{j<k} gain_j / D_{j+1}), D_k = Π_{i<k} decay_i, in chunks short
        # enough that D stays far from overflow
        for start in range(0, len(current), CHUNK):
            cs = np.cumsum(log_decay[start:start + CHUNK], axis=0)
            before = np.vstack([np.zeros((1, cs.shape[1])), cs[:-1]])
            summed = np.cumsum(gain[start:start + CHUNK] * np.exp(-cs), axis=0)
            carried = np.vstack([np.zeros((1, cs.shape[1])), summed[:-1]])
            out[start:start + CHUNK] = np.exp(before) * (temperature + carried)
            temperature = np.exp(cs[-1]) * (temperature + summed[-1])
    return np.where(modelled, out, ambient)


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


# ---------------------------------------------------------------------------- the fastest timing

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
    first, last, ratio = FIT_GRID
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
    while above - below > FIT_TOLERANCE * above:
        middle = math.sqrt(below * above)
        if passes(middle):
            above = middle
        else:
            below = middle
    return above, f"scan x{ratio:g} then bisection to {FIT_TOLERANCE:.1%}: fails at {below:.4f}, passes at {above:.4f}"


# ---------------------------------------------------------------------------- confirmed by simulation

SATURATION_UNITS = 3          # current units between the asked and the delivered current that count
TRACKING_TOLERANCE = math.radians(5.0)   # what a passing motion must track within on the simulated bus


def simulate(config, motion: str, scale: float, result: Result, limits: Limits, out: Path) -> dict:
    """Play the motion on the simulated servos (lock-step) under the swing's controller and compare
    with the prediction. A servo saturates where it delivers less current than the controller asked
    for: its drive ran out of voltage against the back-EMF (the envelope) or the HAL clamped the
    command at the current limit. Per joint: the first saturated tick against the validator's first
    torque_speed or current violation; and the whole run's tracking."""
    from .swing import run_swing
    summary = run_swing(config, out=out, time_scale=scale, motion=motion, force=True, say=lambda *a, **k: None)
    log = np.genfromtxt(out / "swing_log.csv", delimiter=",", names=True)
    names = config.model.dof_names
    unit = ServoMap.from_joints(config.joints).current_unit       # the simulated bus is Dynamixel
    joints = {}
    for j, dof in enumerate(names):
        asked = log[f"tau_{dof}"] / (limits.torque_constant[j] * limits.gear[j])     # A
        delivered = log[f"current_{dof}"]           # the current of each read: what the tick before applied
        short = np.abs(asked[:-1]) - np.abs(delivered[1:]) > SATURATION_UNITS * max(unit[j], 1e-3)
        hits = np.flatnonzero(short)
        observed = float(log["t"][hits[0]]) if hits.size else None
        over = (result.ratios["torque_speed"][:, j] > 1) | (result.ratios["current"][:, j] > 1)
        predicted = float(result.t[np.argmax(over)]) if over.any() else None
        joints[dof] = {"predicted_s": predicted, "saturated_s": observed,
                       "ticks_apart": None if predicted is None or observed is None
                       else int(round((observed - predicted) / limits.period))}
    # after the first saturation the arm leaves the plan, so the later joints' times are the run's,
    # not the prediction's: the first of each is the comparison that holds
    predicted = [(row["predicted_s"], dof) for dof, row in joints.items() if row["predicted_s"] is not None]
    observed = [(row["saturated_s"], dof) for dof, row in joints.items() if row["saturated_s"] is not None]
    first = {"predicted": dict(zip(("t_s", "dof"), min(predicted))) if predicted else None,
             "saturated": dict(zip(("t_s", "dof"), min(observed))) if observed else None}
    if first["predicted"] and first["saturated"]:
        first["ticks_apart"] = int(round((first["saturated"]["t_s"] - first["predicted"]["t_s"]) / limits.period))
    return {"completed": summary["completed"], "tracking_max_rad": summary.get("tracking_max_rad"),
            "tracks": summary.get("tracking_max_rad", math.inf) <= TRACKING_TOLERANCE, "first": first,
            "joints": joints}


# ---------------------------------------------------------------------------- the report

def joint_table(result: Result, dof_names) -> dict:
    """Per joint: peaks, the worst check and its ratio, pass or fail, each check's peak ratio."""
    table = {}
    for j, dof in enumerate(dof_names):
        peaks = {name: float(result.ratios[name][:, min(j, result.ratios[name].shape[1] - 1)].max(initial=0.0))
                 for name in CHECKS}
        worst = max(peaks, key=lambda name: peaks[name] / result.allowed(name))   # nearest its bound
        when = {name: float(result.t[int(np.argmax(result.ratios[name][:, min(j, result.ratios[name].shape[1] - 1)]))])
                for name in CHECKS}
        table[dof] = {
            "peak_torque_nm": float(np.abs(result.tau[:, j]).max()),
            "peak_speed_rad_s": float(np.abs(result.qd[:, j]).max()),
            "peak_current_a": float(result.current[:, j].max()),
            "peak_temperature_c": float(result.temperature[:, j].max()),
            "worst_check": worst, "worst_ratio": peaks[worst],
            "passed": all(peaks[name] <= result.allowed(name) for name in CHECKS),
            "checks": peaks, "worst_at_s": when,
        }
    return table


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


def make_report(config, path: MotionPath, scale: float, result: Result, limits: Limits, *, margin: float,
                repeat: int, ambient: float, payload: dict | None) -> dict:
    found = violations(result, config.model.dof_names)
    for v in found:
        v["message"] = describe(v, config, limits, repeat, margin)
    return {
        "passed": result.passed, "motion": path.name, "config": config.name, "time_scale": scale,
        "duration_s": float(result.t[-1]), "supply_voltage": limits.voltage, "margin": margin,
        "repeat": repeat, "ambient_c": ambient, "payload": payload,
        "sample_period_s": float(result.t[1] - result.t[0]) if len(result.t) > 1 else limits.period,
        "samples": len(result.t),
        "joints": joint_table(result, config.model.dof_names),
        "violations": found,
        "supply": {"peak_current_a": float(result.supply_current.max()), "peak_power_w": float(result.power.max()),
                   "current_limit_a": limits.supply_current},
        "bus": [{"bus": name, "seconds_per_tick": seconds, "what": text} for name, seconds, text in limits.wire],
        "command_quantization_nm": dict(zip(config.model.dof_names, map(float, limits.command_step))),
    }


# ---------------------------------------------------------------------------- the command

def validate(config, motion: str, *, time_scale: float = 1.0, payload: float = 0.0, payload_body=None,
             payload_com=None, supply_voltage: float | None = None, margin: float = 1.0, repeat: int = 1,
             ambient: float = AMBIENT, fit: bool = False, retime_motion: bool = False, simulate_motion: bool = False,
             out: Path | None = None, say=print) -> dict:
    """Validate `motion` on the configuration's servos; the report (and its files in `out`)."""
    if not (math.isfinite(time_scale) and time_scale > 0):
        raise ValueError(f"--time-scale must be a positive number, got {time_scale}")
    if not (math.isfinite(margin) and 0 < margin <= 10):
        raise ValueError(f"--margin must be a fraction of each limit in (0, 10], got {margin}")
    if not 1 <= repeat <= MAX_REPEAT:
        raise ValueError(f"--repeat must be from 1 to {MAX_REPEAT} plays (the winding settles within a few "
                         f"thermal time constants: minutes of play), got {repeat}")
    if not math.isfinite(ambient) or ambient >= min(j.servo.temperature_limit for j in config.joints):
        raise ValueError(f"--ambient must be a temperature below the servos' limits, got {ambient}")
    model = config.model
    payload_info = None
    if payload or payload_body or payload_com is not None:
        model = model.with_payload(payload, payload_body, payload_com)
        payload_info = {"mass_kg": payload, "body": payload_body or model.body_names[-1],
                        "com_m": None if payload_com is None else [float(x) for x in payload_com]}
    voltage = supply_voltage if supply_voltage is not None else config.supply.voltage
    why = supply_voltage_error(voltage, config.joints)
    if why:
        raise ValueError(f"--supply-voltage {why}")
    path = motion_path(motion, model)
    limits = Limits.of(config, voltage)
    result = check(model, limits, path.at_scale(time_scale, limits.period), margin, repeat, ambient)
    report = make_report(config, path, time_scale, result, limits, margin=margin, repeat=repeat,
                         ambient=ambient, payload=payload_info)
    say(f"validate '{path.name}' on '{config.name}': {report['duration_s']:.3f} s at time scale {time_scale:g}, "
        f"{report['samples']} samples every {report['sample_period_s'] * 1e3:g} ms, supply {voltage:g} V, "
        f"margin {margin:g}{f', {repeat} plays' if repeat > 1 else ''}")
    say(summary_table(report))
    if report["violations"]:
        say(f"\nFAIL: {report['violations'][0]['message']}")
        more = len(report["violations"]) - 1
        if more:
            say(f"  ({more} more: every check and joint over its limit is in report.json)")
    else:
        say("\nPASS: every joint within every limit")
    if fit:
        scale, how = fit_time_scale(model, limits, path, margin, repeat, ambient)
        report["fit_time_scale"] = scale
        report["fit_how"] = how
        say(f"fit: {'time scale ' + format(scale, '.4f') + f' ({path.duration * scale:.3f} s)' if scale else 'none'} — {how}")
    if retime_motion:
        from .retime import retime
        traj, checked, info = retime(model, limits, path, margin, repeat, ambient)
        if traj is None:
            report["retime"] = {"passed": False, "why": info}
            say(f"retime: {info}")
        else:
            report["retime"] = {"passed": True, **info}
            fitted = report.get("fit_time_scale")
            durations = f"as written {path.duration:.3f} s" + (f", uniform fit {path.duration * fitted:.3f} s"
                                                               if fitted else "")
            plans = f"{info['tries']} plan{'s' if info['tries'] > 1 else ''}"
            say(f"retime (TOPP-RA): {info['duration_s']:.3f} s, passes the dense check ({plans}, "
                f"{info['seconds']:.2f} s); {durations}")
    if simulate_motion:
        if payload_info is not None:
            from dataclasses import replace
            config = replace(config, model=model)
        report["simulation"] = simulate(config, motion, time_scale, result, limits,
                                        (out or Path("out/validate")) / "simulation")
        say(simulation_summary(report["simulation"]))
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if report.get("retime", {}).get("passed"):
            write_trajectory_csv(out / "retimed.csv", traj, model.dof_names)
            report["retime"]["file"] = str(out / "retimed.csv")
        text = report_json(report)         # strict JSON, or one error before any file is drawn
        title = f"{path.name} on {config.name}, time scale {time_scale:g}, {voltage:g} V"
        from .plots import envelope_figure, limits_in_time_figure
        envelope_figure(out / "envelopes.png", result, limits, model.dof_names, title)
        limits_in_time_figure(out / "current_temperature.png", result, limits, model.dof_names, title)
        (out / "report.json").write_text(text)
        say(f"wrote {out / 'report.json'}, {out / 'envelopes.png'}, {out / 'current_temperature.png'}")
    return report


def report_json(report: dict) -> str:
    """The report as strict JSON (no NaN or Infinity tokens, which JSON has not); ValueError naming
    the first entry that is not a finite number."""
    try:
        return json.dumps(report, indent=1, allow_nan=False) + "\n"
    except ValueError:
        def first(value, where):
            if isinstance(value, float) and not math.isfinite(value):
                return f"{where} = {value}"
            items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
            return next((found for key, item in items if (found := first(item, f"{where}.{key}" if where else str(key)))),
                        None)
        raise ValueError(f"report.json: {first(report, '')} is not a finite number, which JSON cannot hold (the "
                         "inputs took a check out of the range it computes in)") from None


def summary_table(report: dict) -> str:
    short = {"position": "pos", "speed": "speed", "torque_speed": "τ-ω", "current": "current",
             "temperature": "heat", "supply": "supply", "bus": "bus", "command_range": "command"}
    lines = [f"  {'dof':<24}" + "".join(f"{short[c]:>8}" for c in CHECKS) + "   verdict"]
    for dof, row in report["joints"].items():
        cells = "".join(f"{fixed(row['checks'][c]):>8}" for c in CHECKS)
        lines.append(f"  {dof:<24}{cells}   {'PASS' if row['passed'] else 'FAIL (' + row['worst_check'] + ')'}")
    lines.append(f"  (peak ratio to each limit: up to {report['margin']:g} passes, up to 1 for position)")
    return "\n".join(lines)


def simulation_summary(sim: dict) -> str:
    lines = [f"simulated (lock-step, the swing's controller): {'completed' if sim['completed'] else 'stopped'}, "
             f"tracking max {math.degrees(sim['tracking_max_rad'] or 0):.2f} deg"]
    first = sim["first"]
    if first["predicted"] and first["saturated"]:
        lines.append(f"  first saturation: predicted {first['predicted']['dof']} at {first['predicted']['t_s']:.3f} s, "
                     f"simulated {first['saturated']['dof']} at {first['saturated']['t_s']:.3f} s "
                     f"({first['ticks_apart']:+d} ticks); the later ones follow a run that has left the plan:")
    for dof, row in sim["joints"].items():
        if row["predicted_s"] is None and row["saturated_s"] is None:
            continue
        fmt = lambda t: "never" if t is None else f"{t:.3f} s"
        lines.append(f"  {dof:<24} predicted {fmt(row['predicted_s'])}, saturated {fmt(row['saturated_s'])}")
    return "\n".join(lines)
