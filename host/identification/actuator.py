"""A servo's motor from bench logs (bench.py): k_t, R, armature, Coulomb, viscous and Stribeck
friction and the bench's zero offset, with standard errors, from logs of PWM and supply without current.

1. Linear least squares where the model is linear in its parameters: on each log, resampled evenly and
   low-passed (signals.prepare), the pendulum's torque balance

       m·l²·q̈ + m·g·l·sin q = a·(d·V)·on − b·q̇·on − F_v·q̇ − F_c·sign(q̇) − A·q̈ − m·g·l·q₀·cos q

   with the logged duty d (Present PWM; the position law on the logged q where the PWM was not
   logged) and supply V gives a = k_t/R, b = k_t²/R (so k_t = b/a, R = k_t/a), the armature A, F_v,
   F_c and the zero offset q₀. Back-EMF braking (b) and viscous friction (F_v) are told apart only
   where the torque is off (the motor coasts): without a torque-off stretch b takes both.
2. Refined on the rollout's position error (bench.rollout, the replay `servodyn replay` scores), each
   log weighted alike, by scipy's least_squares, with Stribeck friction added; the rollouts of a
   Jacobian run at once, one lane per parameter. Standard errors from its Jacobian, widened by the
   residuals' correlation (an effective sample count from their lag-one autocorrelation).

Logs without a torque-off stretch never show the motor coasting, so the friction that acts then is
not theirs to tell (with the motor driving, Coulomb friction and the gear's load share trade off):
Coulomb friction is held at k_t × the data sheet's no-load current (the torque the motor spends on
its own and its gear's friction with no load), where the catalogue has one. Logs without the PWM
(the position law's duty on the logged positions stands in for it) determine the law's gain times
k_t/R, not either alone: the law's gain is the catalogue's, and what stands on it is `assumed`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from ..hal.dynamixel.control_table import PWM_FULL
from ..hal.motor import MotorModel
from .bench import GRAVITY, STEP, BenchLog, Grid, rollout
from .bench_servo import BenchServo, bench_servo
from .estimate import REL_SIGMA_MAX, IdentificationError, Parameter
from .signals import SignalError, prepare

RESAMPLE = 0.005       # s: the linear step's even grid
CUTOFF_HZ = 8.0        # Hz: its low-pass (the pendulum swings at ~1.3 Hz, the law's loop below 5 Hz)
MOVING = 0.1           # rad/s: slower samples are left out of the linear step (friction's sign unknown)
DIFF_STEP = 1e-2       # the Jacobian's relative steps: friction makes the rollout flat to smaller ones
STRIBECK_VELOCITIES = (0.2, 0.4, 0.8, 1.6)   # rad/s: the linear step's trial Stribeck velocities (above MOVING)

# the refined parameters: (key in actuator.json, MotorModel field or "offset", unit, scale of its search)
FITTED = (("torque_constant_nm_a", "torque_constant", "N m/A"),
          ("resistance_ohm", "resistance", "ohm"),
          ("armature_kg_m2", "armature", "kg m^2"),
          ("friction_coulomb_nm", "friction_coulomb", "N m"),
          ("friction_viscous_nm_s", "friction_viscous", "N m s/rad"),
          ("friction_stribeck_nm", "friction_stribeck", "N m"),
          ("stribeck_velocity_rad_s", "stribeck_velocity", "rad/s"),
          ("friction_load", "friction_load", "N m/N m"),
          ("zero_offset_rad", "offset", "rad"))
LOWER = dict(torque_constant=0.01, resistance=0.05, armature=0.0, friction_coulomb=0.0, friction_viscous=0.0,
             friction_stribeck=0.0, stribeck_velocity=0.01, friction_load=0.0, offset=-0.5)


@dataclass(frozen=True)
class ActuatorFit:
    """The identified motor, each parameter with its standard error (or why it is not determined)."""
    servo: str
    motor: MotorModel
    offset: float
    parameters: dict          # key → Parameter
    linear: dict              # key → value of the linear step
    errors: list              # per log, mean |q_sim − q_log| (rad) with the fitted motor
    evaluations: int
    assumed: dict             # what the logs leave undetermined and the fit takes from the catalogue, why

    def as_json(self) -> dict:
        out = {"servo": self.servo}
        for key, name, unit in FITTED:      # the best estimate, even where not determined (below)
            if name.startswith("stribeck") or name == "friction_stribeck":
                if not self.motor.friction_stribeck:
                    continue            # not fitted (not_determined says why)
            out[key] = float(self.offset if name == "offset" else getattr(self.motor, name))
        out["standard_errors"] = {k: p.std for k, p in self.parameters.items() if p.std is not None}
        out["not_determined"] = {k: p.note for k, p in self.parameters.items() if not p.determined}
        out["assumed"] = dict(self.assumed)
        out["units"] = {key: unit for key, _, unit in FITTED}
        out["replay_error_rad"] = {"per_log": self.errors, "mean": float(np.mean(self.errors))}
        return out


def law_duty(log: BenchLog, duty_per_rad: float, q=None, max_duty: float = 1.0) -> np.ndarray:
    """The position law's duty on the positions `q` (default: the logged ones), torque on or off."""
    q = log.q if q is None else q
    return np.clip(duty_per_rad * (log.goal - q), -max_duty, max_duty)


def _linear(logs, duty_per_rad, pwm_full) -> dict:
    """The linear step: a, b, F_v, F_c, A, q₀ by least squares over every log's moving samples."""
    rows, rhs = [], []
    coasting = False
    for log, gain in zip(logs, duty_per_rad):
        t = np.arange(log.t[0], log.t[-1], RESAMPLE)
        duty = log.pwm / pwm_full if log.pwm is not None else law_duty(log, gain)
        on = log.enabled.astype(float)
        coasting |= bool(np.any(on < 0.5))
        drive = np.interp(t, log.t, duty * log.volts * on)
        try:
            p = prepare(t, np.interp(t, log.t, log.q)[:, None],
                        np.column_stack([drive, np.interp(t, log.t, on)]), cutoff_hz=CUTOFF_HZ, origin=log.path)
        except SignalError as err:
            raise IdentificationError(str(err)) from None
        q, qd, qdd = p.q[:, 0], p.qd[:, 0], p.qdd[:, 0]
        moving = np.abs(qd) > MOVING
        mgl = log.gravity_torque
        cols = np.column_stack([p.tau[:, 0], -qd * p.tau[:, 1], -qd, -p.sign[:, 0], -qdd, -mgl * np.cos(q), qd])
        rows.append(cols[moving])
        rhs.append((log.load_inertia * qdd + mgl * np.sin(q))[moving])
    a_matrix, y = np.vstack(rows), np.concatenate(rhs)
    speed = a_matrix[:, 6]
    a_matrix = a_matrix[:, :6]
    if not coasting:   # back-EMF and viscous friction are the same column: viscous left to the rollout
        a_matrix[:, 2] = 0.0
    theta = np.linalg.lstsq(a_matrix, y, rcond=None)[0]
    # the gear's load-dependent friction, −K_l·|τ_m|·sign(q̇), with τ_m as the first pass has it
    # (else the Coulomb column takes it, and the rollout starts far from the friction it needs)
    motor_torque = np.abs(a_matrix[:, :2] @ theta[:2])
    a_matrix = np.column_stack([a_matrix, motor_torque * a_matrix[:, 3]])
    theta = np.linalg.lstsq(a_matrix, y, rcond=None)[0]
    a, b, fv, fc, arm, offset, load = theta
    kt = b / a if a > 0 and b > 0 else None
    out = dict(torque_constant=kt, resistance=kt / a if kt else None, friction_viscous=max(fv, 0.0),
               friction_coulomb=max(fc, 0.0), armature=max(arm, 0.0), offset=offset,
               friction_load=float(np.clip(load, 0.0, 0.9)))
    # Stribeck friction: a column −sign(q̇)·exp(−(q̇/ω_s)²) at the ω_s that fits best; kept for the
    # rollout only where the linear step determines it (positive, relative error within REL_SIGMA_MAX)
    best = None
    for ws in STRIBECK_VELOCITIES:
        column = -np.sign(speed) * np.exp(-(speed / ws) ** 2)
        m = np.column_stack([a_matrix, column])
        theta, res, *_ = np.linalg.lstsq(m, y, rcond=None)
        r = y - m @ theta
        if best is None or r @ r < best[0]:
            cov = np.linalg.pinv(m.T @ m) * (r @ r) / max(len(y) - m.shape[1], 1)
            best = (r @ r, ws, theta[-1], math.sqrt(cov[-1, -1]))
    _, ws, fs, sd = best
    out["stribeck"] = (fs, ws) if fs > 0 and sd <= REL_SIGMA_MAX * fs else None
    out["stribeck_note"] = f"{fs:.3g} ± {sd:.2g} N m at {ws:g} rad/s in the linear step"
    return out


def _lanes(base: MotorModel, names, x, coulomb_per_kt=None) -> tuple[MotorModel, np.ndarray]:
    """A motor whose fields named in `names` are the columns of x (lanes, params); the offset apart;
    Coulomb friction tied to k_t (× `coulomb_per_kt` A) where that is given."""
    changes = {n: x[:, i:i + 1] for i, n in enumerate(names) if n != "offset"}
    if coulomb_per_kt is not None:
        changes["friction_coulomb"] = changes.get("torque_constant", base.torque_constant) * coulomb_per_kt
    offset = x[:, names.index("offset"), None] if "offset" in names else 0.0
    return base.with_(**changes), offset


def free_swings(logs) -> list:
    """The torque-off stretches of the logs (from the release to the end), as logs of their own whose
    first speed is the position's slope (Present Velocity lags it by ~4 samples)."""
    out = []
    for log in logs:
        off = np.flatnonzero(~log.enabled)
        if off.size < 20 or np.any(np.diff(off) != 1) or off[-1] != len(log.t) - 1:
            continue
        i = off[0]
        k = slice(i, None)
        speed = log.speed[k].copy()
        speed[0] = np.polyfit(log.t[i:i + 8] - log.t[i], log.q[i:i + 8], 2)[1]   # the slope at the release
        out.append(replace(log, t=log.t[k], q=log.q[k], speed=speed, pwm=None if log.pwm is None else log.pwm[k],
                           volts=log.volts[k], temp=log.temp[k], goal=log.goal[k], enabled=log.enabled[k]))
    return out


class _Refine:
    """Least squares on the rollout's position error over `names` (MotorModel fields and "offset"),
    the others held at `base`'s; every Jacobian's rollouts at once, one lane each."""

    def __init__(self, logs, base: MotorModel, gains, dt: float, coulomb_per_kt=None):
        self.logs, self.base, self.dt, self.coulomb_per_kt = logs, base, dt, coulomb_per_kt
        self.grid = Grid.of(logs, dt)
        self.gain = np.asarray(gains, dtype=float)
        self.weights = [1.0 / math.sqrt(len(log.t)) for log in logs]   # each log counts as one
        self.evaluations = 0

    def residuals(self, names, xs) -> np.ndarray:
        motor, offset = _lanes(self.base, names, xs, self.coulomb_per_kt)
        self.evaluations += xs.shape[0]
        qs = rollout(self.grid, motor, self.gain, offset)[0]
        return np.concatenate([(self.grid.sample(qs, j) - log.q[:, None]).T * w for j, (log, w) in
                               enumerate(zip(self.logs, self.weights))], axis=1)

    def fit(self, names, start: dict, max_nfev: int = 40):
        x0 = np.array([start[n] for n in names])
        scale = np.array([max(abs(v), 1e-3) for v in x0])
        cache = {}

        def fun(z):
            key = z.tobytes()
            if key not in cache:
                h = DIFF_STEP * np.maximum(np.abs(z), 1e-2)
                r = self.residuals(names, np.vstack([z, z + np.diag(h)]) * scale)
                cache.clear()
                cache[key] = (r[0], ((r[1:] - r[0]) / h[:, None]).T)
            return cache[key][0]

        lower = np.array([LOWER[n] for n in names]) / scale
        z0 = np.maximum(x0 / scale, lower + 1e-9)
        fit = least_squares(fun, z0, jac=lambda z: (fun(z), cache[z.tobytes()][1])[1], bounds=(lower, np.inf),
                            max_nfev=max_nfev, ftol=1e-4, xtol=1e-4)
        return fit, scale

    def errors(self, motor, offset) -> list:
        qs = rollout(self.grid, motor, self.gain, offset)[0]
        return [float(np.mean(np.abs(self.grid.sample(qs, j)[:, 0] - log.q))) for j, log in enumerate(self.logs)]


def identify_actuator(logs, servo, dt: float = STEP) -> ActuatorFit:
    """The servo's motor from its bench logs (see the module): `servo` a BenchServo (or a catalogue
    servo, looked up by its name)."""
    servo = servo if isinstance(servo, BenchServo) else bench_servo(servo.name)
    gains = [servo.duty_per_rad(log.kp) for log in logs]
    lin = _linear(logs, gains, servo.pwm_full)
    guess = servo.motor
    start = {n: (lin.get(n) if lin.get(n) is not None else getattr(guess, n)) for n in
             ("torque_constant", "resistance", "armature", "friction_coulomb", "friction_viscous")}
    stribeck = lin["stribeck"]
    start.update(friction_stribeck=stribeck[0] if stribeck else 0.0, stribeck_velocity=stribeck[1] if stribeck else 0.1,
                 friction_load=lin["friction_load"], offset=lin["offset"])
    base = guess.with_(back_emf_constant=None, **{k: v for k, v in start.items() if k != "offset"})
    names = [n for _, n, _ in FITTED if stribeck or n not in ("friction_stribeck", "stribeck_velocity")]
    evaluations = 0
    swings = free_swings(logs)
    tie = None if swings or not servo.no_load_current else servo.no_load_current
    if swings:      # the free swing alone: the armature, cleanly (the motor coasts)
        free = _Refine(swings, base, [servo.duty_per_rad(log.kp) for log in swings], dt)
        held = ["armature", "friction_coulomb", "friction_viscous", "offset"]
        fit, scale = free.fit(held, start)
        start.update(zip(held, fit.x * scale))
        free_params = _errors(fit, scale, fit.x * scale, held)
        base = base.with_(armature=start["armature"])
        names.remove("armature")
        evaluations += free.evaluations
    else:           # the motor never coasts: viscous friction is the back-EMF's twin, held at the catalogue's
        names.remove("friction_viscous")
        start["friction_viscous"] = guess.friction_viscous
        base = base.with_(friction_viscous=guess.friction_viscous)
        if tie:
            names.remove("friction_coulomb")
    whole = _Refine(logs, base, gains, dt, tie)
    fit, scale = whole.fit(names, start)
    x = fit.x * scale
    params = _errors(fit, scale, x, names)
    if swings:
        params["armature_kg_m2"] = free_params["armature_kg_m2"]
    if not stribeck:
        for key in ("friction_stribeck_nm", "stribeck_velocity_rad_s"):
            params[key] = Parameter(None, None, "not determined: " + lin["stribeck_note"])
    motor = base.with_(**{n: float(v) for n, v in zip(names, x) if n != "offset"})
    if not swings:
        params["friction_viscous_nm_s"] = Parameter(None, None, "not determined: held at the catalogue's (no torque "
                                                                "off: it acts as the back-EMF does)")
    if tie:
        motor = motor.with_(friction_coulomb=motor.torque_constant * tie)
        kt = params["torque_constant_nm_a"]
        params["friction_coulomb_nm"] = Parameter(motor.friction_coulomb, None if kt.std is None else kt.std * tie)
    offset = float(x[names.index("offset")])
    linear = {key: lin.get(n) for key, n, _ in FITTED if n in lin}
    return ActuatorFit(servo=servo.name, motor=motor, offset=offset, parameters=params, linear=linear,
                       errors=whole.errors(motor, offset), evaluations=evaluations + whole.evaluations,
                       assumed=_assumed(logs, servo, motor, whole, offset, tie, swings))


def _assumed(logs, servo: BenchServo, motor: MotorModel, whole, offset, tie, swings) -> dict:
    """What the logs leave undetermined, each with the catalogue's figure the fit stands on."""
    out = {}
    if all(log.pwm is None for log in logs):
        p = float(np.median([log.kp for log in logs]))
        volts = float(np.median(np.concatenate([log.volts for log in logs])))
        stiffness = servo.duty_per_rad(p) * volts * motor.torque_constant / motor.resistance
        out["position_law"] = (f"the logs have no PWM: they determine the law's gain x k_t/R (the stiffness, "
                               f"{stiffness:.1f} N m/rad at P {p:g} and {volts:.1f} V), not either alone; the gain is "
                               f"the catalogue's, {servo.law}: k_t/R and the stall torque stand on it")
    duties = rollout(whole.grid, motor, whole.gain, offset)[1]
    peak = float(np.max(np.abs(duties)))
    if peak < motor.max_duty:
        out["max_duty"] = (f"never reached (the law's largest duty on these logs {peak:.2f}): "
                           f"{motor.max_duty:g} taken from the catalogue")
    if not swings:
        out["friction_coulomb_nm"] = (
            "no torque-off stretch: the friction that acts while the motor coasts is not in the logs; "
            + (f"held at k_t x {tie:g} A, the catalogue's no-load current" if tie else "fitted with the motor driving"))
        out["friction_viscous_nm_s"] = ("no torque-off stretch: viscous friction and back-EMF braking (k_t^2/R) "
                                         f"act alike with the motor driving: held at the catalogue's "
                                         f"{servo.motor.friction_viscous:.3g} N m s/rad, k_e = k_t takes the rest")
    fastest = max(float(np.max(np.abs(np.diff(log.goal) / np.diff(log.t)))) for log in logs)
    out["goal_speed"] = (f"the fastest goal in these logs moves {fastest:.1f} rad/s: any limit the firmware puts on "
                         "its goal's speed above that is not exercised (the replay applies none)")
    if all(abs(log.kp - logs[0].kp) < 1e-9 for log in logs):
        out["p_gain"] = (f"one P gain ({logs[0].kp:g}) in every log: the law's dead band and its scaling with P "
                         "are not exercised")
    return out


def _errors(fit, scale, x, names) -> dict:
    """Standard errors from the Jacobian, widened by the residuals' lag-one autocorrelation ρ
    (n_eff = n·(1 − ρ)/(1 + ρ)); relative ones above REL_SIGMA_MAX are not determined."""
    r, jac = fit.fun, fit.jac
    n, p = jac.shape
    rho = float(np.clip(np.sum(r[1:] * r[:-1]) / max(np.sum(r * r), 1e-300), 0.0, 0.999))
    s2 = float(r @ r) / max(n - p, 1) * (1 + rho) / (1 - rho)
    std = np.sqrt(np.abs(np.diag(np.linalg.pinv(jac.T @ jac) * s2))) * scale
    out = {}
    for key, name, unit in FITTED:
        if name not in names:
            continue
        value, sd = float(x[names.index(name)]), float(std[names.index(name)])
        if name != "offset" and not (math.isfinite(sd) and abs(sd) <= REL_SIGMA_MAX * abs(value)):
            out[key] = Parameter(None, sd if math.isfinite(sd) else None,
                                 f"not determined: {value:.4g} ± {sd:.2g} {unit}, the logs cannot tell it")
        else:
            out[key] = Parameter(value, sd)
    return out


def pwm_read_lag(logs, gains, pwm_full: float = PWM_FULL, longest: float = 0.010) -> float:
    """The delay (s, 0..`longest`, 0.5 ms steps) between a log's position and its Present PWM reading
    that best fits the position law on the logged positions to the logged PWM, over every log at
    once (a recorder reads one register after the other): the replay compares its duty there."""
    with_pwm = [(log, g) for log, g in zip(logs, gains) if log.pwm is not None]
    if not with_pwm:
        return 0.0
    lags = np.arange(0.0, longest + 1e-9, 0.0005)
    cost = [sum(np.mean(np.abs(law_duty(log, g, np.interp(log.t + lag, log.t, log.q)) - log.pwm / pwm_full)
                        [log.enabled]) for log, g in with_pwm) for lag in lags]
    return float(lags[int(np.argmin(cost))])


def load_actuator(path, base: MotorModel) -> tuple[MotorModel, float]:
    """The motor and zero offset of an actuator.json (`servodyn identify --actuator`), over `base`."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise IdentificationError(f"{path}: not an actuator.json (not JSON)") from None
    if not isinstance(data, dict):
        raise IdentificationError(f"{path}: not an actuator.json (not a JSON object)")
    fields = {}
    for key, name, unit in FITTED:
        value = data.get(key)
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or value < LOWER[name]:
            raise IdentificationError(f"{path}: `{key}` must be a number of at least {LOWER[name]:g} {unit}, "
                                      f"not {value!r}")
        fields[name] = float(value)
    missing = [k for k, n, _ in FITTED[:5] if n not in fields]
    if missing:
        raise IdentificationError(f"{path}: no `{missing[0]}` (an actuator.json has "
                                  f"{', '.join(k for k, _, _ in FITTED[:5])})")
    offset = fields.pop("offset", 0.0)
    return base.with_(back_emf_constant=None, **fields), offset
