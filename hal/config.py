"""Robot configuration: which servo drives which dof of a model, on which bus (TOML).

    cfg = load_config("replica")          # built-in (hal/configs/replica.toml) or a .toml path
    cfg.model.dof_names                    # the servodyn Model the config refers to
    cfg.joints                             # one JointConfig per dof, in the model's dof order
    cfg.units()                            # hal.units.ServoMap of those joints

The format is in hal/README.md. Every mistake raises ConfigError with one line that names
the file, the entry and the key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .units import RPM, ServoMap

CONFIGS_DIR = Path(__file__).parent / "configs"


class ConfigError(ValueError):
    """A robot configuration that cannot be used; the message names the file, entry and key."""


@dataclass(frozen=True)
class ServoSpec:
    """A servo model's data sheet at its recommended 12 V (ROBOTIS e-manual)."""
    name: str
    kind: str                     # the bus kind that speaks to it
    model_number: int             # Model Number register (address 0)
    gear_ratio: float             # the servo's internal reduction (the horn is its output)
    stall_torque: float           # N m
    stall_current: float          # A
    no_load_speed_rpm: float      # rpm
    current_unit: float           # A per Goal / Present Current unit
    current_limit_max: int        # largest Current Limit (38) value, in current units
    ticks_per_rev: int = 4096     # Goal / Present Position units per horn turn
    velocity_unit: float = 0.229  # rpm per Goal / Present Velocity unit

    @property
    def torque_constant(self) -> float:
        """Default N m per A at the horn: stall torque / stall current (calibrate per joint)."""
        return self.stall_torque / self.stall_current

    @property
    def no_load_speed(self) -> float:
        return self.no_load_speed_rpm * RPM


# emanual.robotis.com/docs/en/dxl/x/<model>/ : specifications and the Current Limit(38) range
SERVOS = {s.name: s for s in (
    ServoSpec("XM430-W350", "dynamixel", 1020, 353.5, 4.1, 2.3, 46.0, 2.69e-3, 1193),
    ServoSpec("XM540-W270", "dynamixel", 1120, 272.5, 10.6, 4.4, 30.0, 2.69e-3, 2047),
    ServoSpec("XH430-W350", "dynamixel", 1000, 353.5, 3.4, 1.3, 30.0, 2.69e-3, 648),
    ServoSpec("XH540-W270", "dynamixel", 1100, 272.5, 9.9, 4.9, 39.0, 2.69e-3, 2047),
)}

BUS_KINDS = ("dynamixel", "can", "loopback")
DYNAMIXEL_BAUDS = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000)
TOP_KEYS = {"name", "description", "model", "bus", "joint", "swing"}
BUS_KEYS = {"kind", "port", "baud", "protocol"}
JOINT_KEYS = {"dof", "bus", "id", "servo", "direction", "zero_offset", "gear_ratio",
              "torque_constant", "current_unit", "position_limits", "velocity_limit", "current_limit"}


@dataclass(frozen=True)
class BusConfig:
    name: str
    kind: str                     # dynamixel | can | loopback
    port: str                     # serial device path, or "auto": the simulated bus
    baud: int
    protocol: float


@dataclass(frozen=True)
class JointConfig:
    dof: str
    bus: str
    id: int
    servo: ServoSpec
    direction: int                # +1 / -1: servo positive = dof positive / negative
    zero_offset: float            # rad: horn angle at dof = 0
    gear_ratio: float             # horn turns per joint turn
    torque_constant: float        # N m per A at the horn
    current_unit: float           # A per current register unit
    position_limits: tuple[float, float]   # rad at the joint
    velocity_limit: float         # rad/s at the joint
    current_limit: float          # A

    @property
    def torque_limit(self) -> float:
        """Joint torque (N m) at the current limit."""
        return self.current_limit * self.torque_constant * self.gear_ratio


@dataclass(frozen=True)
class RobotConfig:
    name: str
    path: Path | None
    model_ref: str                # as written in the file
    model: object                 # servodyn.Model
    buses: dict[str, BusConfig]
    joints: tuple[JointConfig, ...]       # model dof order
    swing_time_scale: float | None = None

    def joints_on(self, bus: str) -> tuple[JointConfig, ...]:
        return tuple(j for j in self.joints if j.bus == bus)

    def units(self, joints=None) -> ServoMap:
        return ServoMap.from_joints(self.joints if joints is None else joints)


class _Checker:
    """Typed look-ups in one TOML table; every failure names `where` and the key."""

    def __init__(self, table, where: str, allowed: set[str]):
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: must be a table")
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise ConfigError(f"{where}: unknown key '{unknown[0]}' (known: {', '.join(sorted(allowed))})")
        self.table, self.where = table, where

    def fail(self, key: str, message: str):
        raise ConfigError(f"{self.where}: '{key}' {message}")

    def get(self, key: str, kind: str, default=None):
        if key not in self.table:
            if default is None:
                self.fail(key, "is missing")
            return default
        value = self.table[key]
        if kind == "str" and isinstance(value, str) and value:
            return value
        if kind == "int" and isinstance(value, int) and not isinstance(value, bool):
            return value
        if kind == "float" and _is_number(value):
            return float(value)
        if kind == "pair" and isinstance(value, list) and len(value) == 2 and all(map(_is_number, value)):
            return float(value[0]), float(value[1])
        expected = {"str": "a non-empty string", "int": "an integer", "float": "a finite number",
                    "pair": "a list of two finite numbers"}[kind]
        self.fail(key, f"must be {expected}, got {value!r}")

    def positive(self, key: str, default=None) -> float:
        value = self.get(key, "float", default)
        if value <= 0:
            self.fail(key, f"must be positive, got {value:g}")
        return value


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _bus(name: str, table, where: str) -> BusConfig:
    c = _Checker(table, where, BUS_KEYS)
    kind = c.get("kind", "str")
    if kind not in BUS_KINDS:
        c.fail("kind", f"must be one of {', '.join(BUS_KINDS)}, got {kind!r}")
    port = c.get("port", "str", "auto")
    baud = c.get("baud", "int", 4_000_000 if kind == "dynamixel" else 1_000_000)
    if kind == "dynamixel" and baud not in DYNAMIXEL_BAUDS:
        c.fail("baud", f"must be a Dynamixel X rate ({', '.join(map(str, DYNAMIXEL_BAUDS))}), got {baud}")
    if baud <= 0:
        c.fail("baud", f"must be positive, got {baud}")
    protocol = c.get("protocol", "float", 2.0)
    if kind == "dynamixel" and protocol != 2.0:
        c.fail("protocol", f"must be 2.0 (the only Dynamixel protocol servodyn speaks), got {protocol:g}")
    return BusConfig(name, kind, port, baud, protocol)


def _joint(table, where: str, model, buses: dict[str, BusConfig]) -> JointConfig:
    c = _Checker(table, where, JOINT_KEYS)
    dof = c.get("dof", "str")
    if dof not in model.dof_names:
        c.fail("dof", f"{dof!r} is not a dof of model '{model.name}' ({', '.join(model.dof_names)})")
    bus_name = c.get("bus", "str") if len(buses) != 1 or "bus" in table else next(iter(buses))
    if bus_name not in buses:
        c.fail("bus", f"{bus_name!r} is not a [bus.<name>] of this file ({', '.join(buses)})")
    bus = buses[bus_name]
    servo_id = c.get("id", "int")
    highest = 252 if bus.kind == "dynamixel" else 255
    if not 0 <= servo_id <= highest:
        c.fail("id", f"{servo_id} is out of range 0..{highest} for a {bus.kind} bus")
    servo_name = c.get("servo", "str")
    if servo_name not in SERVOS:
        c.fail("servo", f"{servo_name!r} is not a known servo ({', '.join(SERVOS)})")
    servo = SERVOS[servo_name]
    if bus.kind != "loopback" and servo.kind != bus.kind:
        c.fail("servo", f"{servo_name} is a {servo.kind} servo but bus '{bus_name}' is {bus.kind}")
    direction = c.get("direction", "int", 1)
    if direction not in (1, -1):
        c.fail("direction", f"must be +1 or -1, got {direction}")
    gear_ratio = c.positive("gear_ratio", 1.0)
    current_unit = c.positive("current_unit", servo.current_unit)
    lower, upper = model.lower[model.dof_names.index(dof)], model.upper[model.dof_names.index(dof)]
    limits = c.get("position_limits", "pair", (lower, upper))
    if not limits[0] < limits[1]:
        c.fail("position_limits", f"must be [lower, upper] with lower < upper, got {list(limits)}")
    if limits[0] < lower - 1e-9 or limits[1] > upper + 1e-9:
        c.fail("position_limits", f"{list(limits)} lies outside the model's limits [{lower:g}, {upper:g}]")
    current_limit = c.positive("current_limit", servo.stall_current)
    if current_limit > servo.current_limit_max * current_unit + 1e-12:
        c.fail("current_limit", f"{current_limit:g} A exceeds the {servo_name}'s largest Current Limit, "
                                f"{servo.current_limit_max} x {current_unit:g} A = "
                                f"{servo.current_limit_max * current_unit:.3g} A")
    return JointConfig(dof=dof, bus=bus_name, id=servo_id, servo=servo, direction=direction,
                       zero_offset=c.get("zero_offset", "float", 0.0), gear_ratio=gear_ratio,
                       torque_constant=c.positive("torque_constant", servo.torque_constant),
                       current_unit=current_unit, position_limits=limits,
                       velocity_limit=c.positive("velocity_limit", servo.no_load_speed / gear_ratio),
                       current_limit=current_limit)


def _load_model(ref: str, base: Path | None, where: str):
    import servodyn
    if ref.lower().endswith((".urdf", ".toml")):
        ref = str((base or Path.cwd()) / ref)
    try:
        return servodyn.load_model(ref)
    except ValueError as err:
        raise ConfigError(f"{where}: 'model' {err}") from None


def config_from_dict(data: dict, origin: str = "config", base: Path | None = None) -> RobotConfig:
    """Build and check a RobotConfig from parsed TOML; `base` resolves relative model paths."""
    top = _Checker(data, origin, TOP_KEYS)
    name = top.get("name", "str")
    model_ref = top.get("model", "str")
    model = _load_model(model_ref, base, origin)
    bus_tables = data.get("bus")
    if not isinstance(bus_tables, dict) or not bus_tables:
        top.fail("bus", "must hold at least one [bus.<name>] table")
    buses = {n: _bus(n, t, f"{origin}: bus '{n}'") for n, t in bus_tables.items()}
    entries = data.get("joint")
    if not isinstance(entries, list) or not entries:
        top.fail("joint", "must be a list of [[joint]] tables, one per dof")
    joints, seen_ids = {}, {}
    for k, entry in enumerate(entries):
        label = entry.get("dof") if isinstance(entry, dict) and isinstance(entry.get("dof"), str) else "?"
        joint = _joint(entry, f"{origin}: joint {k + 1} ({label})", model, buses)
        if joint.dof in joints:
            raise ConfigError(f"{origin}: joint {k + 1} ({label}): 'dof' {joint.dof!r} already has a joint")
        if (joint.bus, joint.id) in seen_ids:
            raise ConfigError(f"{origin}: joint {k + 1} ({label}): 'id' {joint.id} is already used on bus "
                              f"'{joint.bus}' by {seen_ids[joint.bus, joint.id]}")
        joints[joint.dof] = joint
        seen_ids[joint.bus, joint.id] = joint.dof
    missing = [d for d in model.dof_names if d not in joints]
    if missing:
        raise ConfigError(f"{origin}: 'joint' missing for dof '{missing[0]}' (every dof of '{model.name}' needs one)")
    time_scale = None
    if "swing" in data:
        time_scale = _Checker(data["swing"], f"{origin}: swing", {"time_scale"}).positive("time_scale")
    return RobotConfig(name=name, path=None, model_ref=model_ref, model=model, buses=buses,
                       joints=tuple(joints[d] for d in model.dof_names), swing_time_scale=time_scale)


def builtin_configs() -> dict[str, Path]:
    return {p.stem: p for p in sorted(CONFIGS_DIR.glob("*.toml"))}


def load_config(name_or_path: str | Path) -> RobotConfig:
    """A built-in configuration by name, or a configuration file."""
    path = builtin_configs().get(str(name_or_path), Path(name_or_path))
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{name_or_path}: no such file, and not a built-in configuration "
                          f"({', '.join(builtin_configs()) or 'none installed'})") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path.name}: not valid TOML ({err})") from None
    config = config_from_dict(data, origin=path.name, base=path.parent)
    return replace(config, path=path)


def servo_load(config: RobotConfig, traj) -> dict[str, np.ndarray]:
    """Peaks over a trajectory (q, qd, qdd of the model) of what each servo must deliver, per joint:
    torque (N m), current (A) and speed (rad/s), their ratios to the joint's current and velocity
    limits, and the worst point against the servo's 12 V torque-speed line,
    |τ| / stall torque + |ω| / no-load speed (1 = on the line)."""
    tau = np.abs(config.model.inverse_dynamics(traj.q, traj.qd, traj.qdd))
    speed = np.abs(traj.qd)
    gear = np.array([j.gear_ratio for j in config.joints])
    kt = np.array([j.torque_constant for j in config.joints])
    stall = np.array([j.servo.stall_torque for j in config.joints]) * gear
    no_load = np.array([j.servo.no_load_speed for j in config.joints]) / gear
    current = tau.max(axis=0) / (gear * kt)
    return {"torque": tau.max(axis=0), "current": current, "speed": speed.max(axis=0),
            "current_ratio": current / np.array([j.current_limit for j in config.joints]),
            "speed_ratio": speed.max(axis=0) / np.array([j.velocity_limit for j in config.joints]),
            "torque_speed": (tau / stall + speed / no_load).max(axis=0)}


def within(load: dict[str, np.ndarray], margin: float = 0.8) -> bool:
    """True when every joint stays within `margin` of its current limit, its velocity limit and
    its torque-speed line."""
    return bool(max(load["current_ratio"].max(), load["speed_ratio"].max(), load["torque_speed"].max()) <= margin)
