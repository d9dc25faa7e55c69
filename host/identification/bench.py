"""Servo-bench logs and their replay: one servo in its own position mode swinging a pendulum.

The log (JSON, the format of BAM's recorders, documented in docs/servo-bench.md): `mass` (kg) at
`length` (m) on the horn, the servo's Position P Gain `kp`, the nominal supply `vin` (V), and
`entries`, samples of `position` (rad, 0 = hanging), `speed` (rad/s), `load` (the raw Present PWM
as an unsigned 16-bit number, a Feetech's raw Present Load, or 0 throughout when not recorded), `input_volts` (V), `temp` (°C),
`timestamp` (s), `goal_position` (rad), `torque_enable`.

The replay (`rollout`): from the first logged position and speed, the servo's own position law runs
on the *simulated* position from the logged goals, gain, supply and temperature, through the motor
model (hal.motor) into the pendulum, J·q̈ = τ_m − m·g·l·sin(q + q₀) + friction, J = m·l² + armature,
explicit steps of `dt` (friction as hal.motor's stopping budget). The motors may be arrays of
candidates (one per lane): identification runs many candidate parameter sets at once.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..hal.motor import MotorModel
from ..model.tree import DEFAULT_GRAVITY

GRAVITY = abs(DEFAULT_GRAVITY[2])
STEP = 0.005                 # s: the replay's integration step (BAM's; 2 ms moves the mean by < 0.0005 rad)
ENTRY_KEYS = ("position", "speed", "load", "input_volts", "temp", "timestamp", "goal_position", "torque_enable")
TOP_KEYS = ("mass", "length", "kp", "vin", "entries")


class BenchLogError(InputError):
    """A bench log that cannot be read or replayed (one line naming the file)."""


@dataclass(frozen=True)
class BenchLog:
    """One bench run, in SI; `pwm` is the logged Present PWM in register counts (None: not logged)."""
    path: str
    motor: str
    trajectory: str
    mass: float
    length: float
    kp: float
    vin: float
    t: np.ndarray
    q: np.ndarray
    speed: np.ndarray
    pwm: np.ndarray | None
    volts: np.ndarray
    temp: np.ndarray
    goal: np.ndarray
    enabled: np.ndarray

    @property
    def name(self) -> str:
        return Path(self.path).stem

    @property
    def load_inertia(self) -> float:
        return self.mass * self.length ** 2

    @property
    def gravity_torque(self) -> float:
        """m·g·l, N·m: the pendulum's largest gravity torque."""
        return self.mass * GRAVITY * self.length


def _number(value, what: str, path: str, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (positive and value <= 0):
        raise BenchLogError(f"{path}: `{what}` must be a {'positive ' if positive else ''}number, not {value!r}")
    return float(value)


def twos_complement(load: np.ndarray) -> np.ndarray:
    """A Dynamixel's Present PWM logged as an unsigned 16-bit number, signed."""
    return np.where(load > 32767, load - 65536, load)


def read_bench_log(path, decode_load=twos_complement) -> BenchLog:
    """A bench log read and checked: any fault is one BenchLogError line naming the file. `decode_load`
    turns the logged `load` register into signed PWM units (the servo's: a Feetech's Present Load is
    sign-magnitude)."""
    path = str(path)
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except json.JSONDecodeError as err:
        raise BenchLogError(f"{path}: not JSON ({err.msg} at line {err.lineno})") from None
    except UnicodeDecodeError:
        raise BenchLogError(f"{path}: not a text file") from None
    if not isinstance(data, dict):
        raise BenchLogError(f"{path}: a bench log is a JSON object with {', '.join(TOP_KEYS)}")
    missing = [k for k in TOP_KEYS if k not in data]
    if missing:
        raise BenchLogError(f"{path}: no `{missing[0]}` (a bench log has {', '.join(TOP_KEYS)})")
    entries = data["entries"]
    if not isinstance(entries, list) or len(entries) < 2:
        raise BenchLogError(f"{path}: `entries` must be a list of at least 2 samples")
    columns = {}
    for k in ENTRY_KEYS:
        try:
            columns[k] = np.array([e[k] for e in entries], dtype=float)
        except (KeyError, TypeError):
            i = next(i for i, e in enumerate(entries) if not isinstance(e, dict) or k not in e)
            raise BenchLogError(f"{path}: entry {i} has no `{k}`") from None
        except ValueError:
            raise BenchLogError(f"{path}: `{k}` holds a value that is not a number") from None
        if not np.all(np.isfinite(columns[k])):
            i = int(np.flatnonzero(~np.isfinite(columns[k]))[0])
            raise BenchLogError(f"{path}: entry {i}: `{k}` is not finite")
    t = columns["timestamp"]
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise BenchLogError(f"{path}: entry {i}: the timestamps must increase")
    load = columns["load"]
    pwm = decode_load(load) if np.any(load) else None
    volts = columns["input_volts"]
    if np.any(volts <= 0):
        raise BenchLogError(f"{path}: `input_volts` must be positive")
    return BenchLog(path=path, motor=str(data.get("motor", "")), trajectory=str(data.get("trajectory", "")),
                    mass=_number(data["mass"], "mass", path), length=_number(data["length"], "length", path),
                    kp=_number(data["kp"], "kp", path, positive=False), vin=_number(data["vin"], "vin", path),
                    t=t, q=columns["position"], speed=columns["speed"], pwm=pwm, volts=volts,
                    temp=columns["temp"], goal=columns["goal_position"], enabled=columns["torque_enable"] > 0.5)


@dataclass(frozen=True)
class Grid:
    """Several logs on one step grid: each log's held inputs (the last sample at or before each
    step) as (steps, logs) arrays, and how to read a step series back at the logs' own timestamps."""
    dt: float
    goal: np.ndarray
    volts: np.ndarray
    temp: np.ndarray
    enabled: np.ndarray
    q0: np.ndarray
    v0: np.ndarray
    mass_length: np.ndarray      # m·l per log
    load_inertia: np.ndarray     # m·l² per log
    kp: np.ndarray
    at: list                     # per log (index, weight) of its timestamps on its grid

    @classmethod
    def of(cls, logs, dt: float = STEP) -> Grid:
        steps = int(math.ceil(max(log.t[-1] - log.t[0] for log in logs) / dt)) + 2
        cols = {k: np.empty((steps, len(logs))) for k in ("goal", "volts", "temp", "enabled")}
        at = []
        for j, log in enumerate(logs):
            grid = log.t[0] + dt * np.arange(steps)
            held = np.clip(np.searchsorted(log.t, grid + 1e-9, side="right") - 1, 0, len(log.t) - 1)
            for k, series in (("goal", log.goal), ("volts", log.volts), ("temp", log.temp), ("enabled", log.enabled)):
                cols[k][:, j] = series[held]
            x = (log.t - log.t[0]) / dt
            i = np.minimum(np.floor(x).astype(int), steps - 2)
            at.append((i, x - i))
        return cls(dt=dt, q0=np.array([log.q[0] for log in logs]), v0=np.array([log.speed[0] for log in logs]),
                   mass_length=np.array([log.mass * log.length for log in logs]),
                   load_inertia=np.array([log.load_inertia for log in logs]),
                   kp=np.array([log.kp for log in logs]), at=at, **cols)

    def sample(self, series: np.ndarray, j: int, shift: float = 0.0) -> np.ndarray:
        """Log j's column of a (steps, ..., logs) series at the log's timestamps (+ shift s), linear."""
        i, w = self.at[j]
        if shift:
            x = i + w + shift / self.dt
            i = np.clip(np.floor(x).astype(int), 0, series.shape[0] - 2)
            w = x - i
        s = series[..., j]
        w = w.reshape((-1,) + (1,) * (s.ndim - 1))
        return s[i] * (1 - w) + s[i + 1] * w


def rollout(grid: Grid, motor: MotorModel, duty_per_rad, offset=0.0):
    """The simulated position and duty, (steps, lanes, logs) each, of the servos and pendula of
    `grid` under `motor` (fields floats or (lanes, 1) arrays of candidates), the position law
    duty = clip(duty_per_rad·(goal − q), ±max_duty) (duty_per_rad per log; 0 with the torque off),
    zero offset q₀."""
    shape = np.broadcast_shapes(np.shape(motor.armature), np.shape(offset), np.shape(motor.resistance),
                                (1, grid.q0.size))
    q = np.broadcast_to(grid.q0, shape).copy()
    v = np.broadcast_to(grid.v0, shape).copy()
    inertia = grid.load_inertia + motor.armature
    mgl = grid.mass_length * GRAVITY
    dt = grid.dt
    high = motor.max_duty
    resistance = motor.resistance_at(grid.temp[:, None, :])     # (steps, lanes, logs): R warms with the log
    enabled = grid.enabled.astype(bool)
    qs = np.empty((grid.goal.shape[0],) + shape)
    duties = np.empty_like(qs)
    for k in range(grid.goal.shape[0]):
        qs[k] = q
        duty = np.minimum(np.maximum(duty_per_rad * (grid.goal[k] - q), -high), high)
        duties[k] = duty * enabled[k]
        # torque off: the bridge is open, no current, the motor coasts (no back-EMF braking)
        drive = motor.torque(duty, grid.volts[k], v, resistance=resistance[k]) * enabled[k]
        load = drive - mgl * np.sin(q + offset)
        load = load + motor.friction(v, load, inertia, dt, drive)
        v = v + load * (dt / inertia)
        q = q + v * dt
    return qs, duties
