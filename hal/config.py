"""Robot configuration: which servo drives which dof of a model, on which bus (TOML).

    cfg = load_config("replica")          # built-in (hal/configs/replica.toml) or a .toml path
    cfg.model.dof_names                    # the servodyn Model the config refers to
    cfg.joints                             # one JointConfig per dof, in the model's dof order

The format is in hal/README.md. Every mistake raises ConfigError with one line that names
the file, the entry and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..control.motion import DEFAULT_MOTION
from ..control.timing import SMALL_TIME_STEP, check_control_period
from ..model import load_model
from ..model.files import read_toml, string_key
from .backend import BACKENDS, backend, servo_catalogue
from .errors import ConfigError
from .servos import ServoSpec

CONFIGS_DIR = Path(__file__).parent / "configs"
TOP_KEYS = {"name", "description", "model", "bus", "joint", "swing", "supply", "control", "payload", "sim"}
SUPPLY_KEYS = {"voltage", "current_limit"}
BUS_KEYS = {"kind", "port", "baud", "protocol"}
# what identification measures (`servodyn identify` writes these names in its patch): each a
# number >= 0 in its RANGES; absent, the model's armature, the servo's thermal data, no friction
IDENTIFIED_KEYS = ("friction_coulomb_nm", "friction_viscous_nm_s", "torque_constant_scale", "armature_kg_m2",
                   "thermal_resistance_k_w", "thermal_time_constant_s")
JOINT_KEYS = {"dof", "bus", "id", "servo", "direction", "zero_offset", "gear_ratio",
              "torque_constant", "position_limits", "velocity_limit", "current_limit", *IDENTIFIED_KEYS}
PAYLOAD_KEYS = {"body", "mass_kg", "com_m"}
# the [sim] table (and a plant file): the arm the simulator runs, when it is not the configured one
SIM_KEYS = {"plant", "mass_scale", "payload", "joint"}
SIM_JOINT_KEYS = {*IDENTIFIED_KEYS, "friction_static_nm", "stribeck_velocity_rad_s"}

# physically sane ranges (lowest, highest, why): a typo like 1e300 would otherwise reach the
# firmware's single-precision tables as inf
RANGES = {
    "zero_offset": (-2 * math.pi, 2 * math.pi, "rad, the horn's angle at dof = 0: one turn either way "
                                               "covers every mounting"),
    "gear_ratio": (0.1, 100.0, "horn turns per joint turn, a belt or gear stage after the servo; below 1/10 "
                               "the joint would turn ten times the servo's speed with a tenth of its torque"),
    "torque_constant": (0.01, 100.0, "N m per A at the horn; the catalogue's servos and motors have 0.8 to 4.1, a "
                                     "calibration 100 times off is a slip of units"),
    "velocity_limit": (0.0, 1000.0, "rad/s at the joint, ten times the fastest servo's no-load speed"),
    "current_unit": (0.0, 1.0, "A per register unit; Dynamixel's is a few mA"),
    "voltage": (0.0, 100.0, "V at the servos; their supplies are 5 to 48 V"),
    "current_limit": (0.0, 1000.0, "A"),
    "friction_coulomb_nm": (0.0, 100.0, "N m at the joint, more than the largest catalogue servo's stall torque"),
    "friction_static_nm": (0.0, 100.0, "N m at the joint, more than the largest catalogue servo's stall torque"),
    "friction_viscous_nm_s": (0.0, 100.0, "N m s/rad at the joint: 100 would stop any servo at 0.1 rad/s"),
    "stribeck_velocity_rad_s": (1e-4, 10.0, "rad/s: the speed over which static friction falls to Coulomb's"),
    "torque_constant_scale": (0.25, 4.0, "the torque a current really gives over torque_constant's; identified "
                                         "scales are within 10-30 %, four times off is a slip of units"),
    "armature_kg_m2": (0.0, 10.0, "kg m^2 reflected at the joint; the replicas' rotors give 0.01 to 0.1"),
    "thermal_resistance_k_w": (0.0, 100.0, "K/W winding to ambient; servo motors have 1 to 20"),
    "thermal_time_constant_s": (0.0, 100_000.0, "s; a winding heats in tens to thousands of seconds"),
    "mass_scale": (0.1, 10.0, "every body's mass and inertia times this"),
    "mass_kg": (0.0, 100.0, "kg of payload, more than any servo arm lifts"),
}


@dataclass(frozen=True)
class BusConfig:
    name: str
    kind: str                     # a key of hal.backend.BACKENDS
    port: str                     # serial device path, or "auto": the simulated bus
    baud: int
    protocol: float
    options: dict = field(default_factory=dict)   # the backend's own keys (CAN: interface)


@dataclass(frozen=True)
class JointConfig:
    dof: str
    bus: str
    id: int
    servo: ServoSpec              # the backend's catalogue entry (its data sheet)
    direction: int                # +1 / -1: servo positive = dof positive / negative
    zero_offset: float            # rad: horn angle at dof = 0
    gear_ratio: float             # horn turns per joint turn
    torque_constant: float        # N m per A at the horn, effective: the configured one x torque_constant_scale
    position_limits: tuple[float, float]   # rad at the joint
    velocity_limit: float         # rad/s at the joint
    current_limit: float          # A
    options: dict = field(default_factory=dict)   # the backend's own keys (Dynamixel: current_unit)
    # identified (IDENTIFIED_KEYS; the armature is the model's)
    torque_constant_scale: float = 1.0   # torque_constant = configured value x this
    friction_coulomb: float = 0.0        # N m at the joint
    friction_viscous: float = 0.0        # N m s/rad at the joint
    thermal_resistance: float = 0.0      # K/W winding to ambient (0: not modelled); default the servo's
    thermal_time_constant: float = 0.0   # s; default the servo's

    @property
    def configured_torque_constant(self) -> float:
        """N m per A at the horn as the file's `torque_constant` (or the servo's) gives it, before the
        identified scale: what the simulator's servos are built from."""
        return self.torque_constant / self.torque_constant_scale

    @property
    def torque_limit(self) -> float:
        """Joint torque (N m) at the current limit."""
        return self.current_limit * self.torque_constant * self.gear_ratio


@dataclass(frozen=True)
class SupplyConfig:
    """The power supply every servo of the robot draws from."""
    voltage: float                # V at the servos
    current_limit: float | None   # A the supply can deliver (None: not given, not checked)


@dataclass(frozen=True)
class RobotConfig:
    name: str
    path: Path | None
    model_ref: str                # as written in the file
    model: object                 # servodyn.Model
    buses: dict[str, BusConfig]
    joints: tuple[JointConfig, ...]       # model dof order
    swing_time_scale: float | None = None
    supply: SupplyConfig | None = None    # None: the servos' nominal voltage, no current rating
    control_period: float = SMALL_TIME_STEP   # s: one read and write of every bus (`[control] period`)
    payload: "Payload | None" = None      # `[payload]`, already in `model`
    plant: "PlantSpec | None" = None      # `[sim]`: the arm the simulator runs (None: this one)

    def time_scale_for(self, motion: str) -> float:
        """The time scale a motion plays at by default: the configuration's (`swing_time_scale`) for
        the forehand it was tuned on, 1 for any other motion."""
        return (self.swing_time_scale if motion == DEFAULT_MOTION else None) or 1.0

    @property
    def friction(self) -> dict:
        """The joints' friction (model dof order) as the controller compensates it: ControlConfig's
        friction_coulomb and friction_viscous keywords."""
        return {"friction_coulomb": [j.friction_coulomb for j in self.joints],
                "friction_viscous": [j.friction_viscous for j in self.joints]}

    def joints_on(self, bus: str) -> tuple[JointConfig, ...]:
        return tuple(j for j in self.joints if j.bus == bus)

    @property
    def builtin(self) -> bool:
        """Shipped with servodyn (hal/configs): part of the package, not the user's file."""
        return self.path is not None and Path(self.path).resolve().parent == CONFIGS_DIR.resolve()

    @property
    def argument(self) -> str:
        """How a command line names it: its built-in name, or its file."""
        return self.name if self.path is None or self.builtin else str(self.path)


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
        """A positive number inside its physical range (RANGES)."""
        value = self.get(key, "float", default)
        if value <= 0:
            self.fail(key, f"must be positive, got {value:g}")
        if key in RANGES and value > RANGES[key][1]:
            self.fail(key, f"{value:g} is beyond {RANGES[key][1]:g} ({RANGES[key][2]})")
        if key in RANGES and value < RANGES[key][0]:
            self.fail(key, f"{value:g} is below {RANGES[key][0]:g} ({RANGES[key][2]})")
        return value

    def within(self, key: str, default: float) -> float:
        """A number inside the key's physical range (RANGES)."""
        value = self.get(key, "float", default)
        low, high, why = RANGES[key]
        if not low <= value <= high:
            self.fail(key, f"{value:g} is outside [{low:g}, {high:g}] ({why})")
        return value


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def supply_voltage_error(voltage: float, joints) -> str | None:
    """Why `voltage` cannot supply these joints' servos, or None. The lowest is half the lowest voltage
    any of their data sheets rates them at (a Dynamixel X's 11.1 V row; its driver cuts out below
    9.5 V, the floor of its Min Voltage Limit): below it no servo runs, and the validator's envelope,
    in proportion to V, would be scaled towards zero, down to 0/0 for a voltage like 5e-324. Then
    the supply range each data sheet allows (ServoSpec.supply_range): 12 V burns a 5 V XL330 (when
    one supply can feed every servo; servos of no common voltage have a supply each)."""
    rated = min(min([j.servo.nominal_voltage, *(row[0] for row in j.servo.ratings)]) for j in joints)
    low, high = rated / 2, RANGES["voltage"][1]
    if not (_is_number(voltage) and low <= voltage <= high):
        return (f"{voltage:g} V is outside [{low:g}, {high:g}] V: half the lowest voltage the servos' data sheets "
                f"rate them at ({rated:g} V; below it their drivers cut out), and no servo's supply is above 48 V")
    # a supply the data sheet does not allow burns or browns out the servo; when no one voltage suits
    # every servo (replica_mixed: 24 V Damiao motors, 12 V Dynamixels), the robot has a supply per
    # kind and this one voltage is only the validator's figure: not checked against the ranges
    spans = [j.servo.supply_range or (j.servo.nominal_voltage,) * 2 for j in joints]
    if max(low for low, _ in spans) > min(high for _, high in spans):
        return None
    for joint in joints:
        allowed = joint.servo.supply_range
        if allowed is not None and not allowed[0] <= voltage <= allowed[1]:
            return (f"{voltage:g} V is outside the {joint.servo.name}'s supply range, {allowed[0]:g} to "
                    f"{allowed[1]:g} V (its data sheet; joint {joint.dof!r})")
    return None


def _bus(name: str, table, where: str) -> BusConfig:
    first = _Checker(table, where, set(table) if isinstance(table, dict) else BUS_KEYS)
    kind = first.get("kind", "str")
    if kind not in BACKENDS:
        first.fail("kind", f"must be one of {', '.join(BACKENDS)}, got {kind!r}")
    spec = backend(kind)
    # a spec may name the port and the rate in its own words (CAN: channel, bitrate)
    port_key, baud_key = spec.port_key, spec.baud_key
    c = _Checker(table, where, {"kind", "protocol", port_key, baud_key} | spec.bus_keys)
    port = c.get(port_key, "str", "auto")
    baud = c.get(baud_key, "int", spec.default_baud)
    if spec.bauds is not None and baud not in spec.bauds:
        c.fail(baud_key, f"must be a {kind} rate ({', '.join(map(str, spec.bauds))}), got {baud}")
    if baud <= 0:
        c.fail(baud_key, f"must be positive, got {baud}")
    protocol = c.get("protocol", "float", spec.protocols[0] if spec.protocols else 1.0)
    if spec.protocols is not None and protocol not in spec.protocols:
        c.fail("protocol", f"must be {' or '.join(f'{p:.1f}' for p in spec.protocols)} (what servodyn "
                           f"speaks on a {kind} bus), got {protocol:.1f}")
    return BusConfig(name, kind, port, baud, protocol, spec.bus_options(c))


def _joint(table, where: str, model, buses: dict[str, BusConfig]) -> JointConfig:
    bus_name = table.get("bus") if isinstance(table, dict) and isinstance(table.get("bus"), str) else None
    if bus_name is None and len(buses) == 1:
        bus_name = next(iter(buses))
    spec = backend(buses[bus_name].kind) if bus_name in buses else None
    # the keys of the bus's spec; a bus without a catalogue of its own (loopback) or an unknown
    # bus takes every spec's, so the error that follows can name what is really wrong
    if spec is not None and spec.servos is not None:
        own_keys = spec.joint_keys
    else:
        own_keys = {k for kind in BACKENDS for k in backend(kind).joint_keys}
    device_keys = {"servo"} | ({spec.device_key} if spec is not None else
                               {backend(kind).device_key for kind in BACKENDS})
    c = _Checker(table, where, JOINT_KEYS | own_keys | device_keys)
    dof = c.get("dof", "str")
    if dof not in model.dof_names:
        c.fail("dof", f"{dof!r} is not a dof of model '{model.name}' ({', '.join(model.dof_names)})")
    bus_name = c.get("bus", "str") if len(buses) != 1 or "bus" in table else next(iter(buses))
    if bus_name not in buses:
        c.fail("bus", f"{bus_name!r} is not a [bus.<name>] of this file ({', '.join(buses)})")
    bus = buses[bus_name]
    servo_id = c.get("id", "int")
    if not 0 <= servo_id <= spec.max_id:
        c.fail("id", f"{servo_id} is out of range 0..{spec.max_id} for a {bus.kind} bus")
    # the device's model: `servo`, or the bus's own word for it (a CAN bus's `motor`), once
    given = [k for k in sorted(device_keys) if k in table]
    if len(given) > 1:
        c.fail(given[1], f"and '{given[0]}' both name the device: give one")
    device_key = given[0] if given else (spec.device_key if spec is not None else "servo")
    servo_name = c.get(device_key, "str")
    catalogue = servo_catalogue(bus.kind)
    if servo_name not in catalogue:
        others = {k: s for k, s in servo_catalogue(None).items() if k not in catalogue}
        if servo_name in others:
            c.fail(device_key, f"{servo_name} is a {others[servo_name].kind} device but bus '{bus_name}' is "
                               f"{bus.kind}")
        c.fail(device_key, f"{servo_name!r} is not a known {bus.kind} {spec.device_key} ({', '.join(catalogue)})")
    servo = catalogue[servo_name]
    if not servo.current_control:
        drivable = ", ".join(k for k, s in catalogue.items() if s.current_control)
        c.fail(device_key, f"{servo_name} has no current control mode, and the {bus.kind} backend drives every "
                           f"joint by its torque (Goal Current); choose one that has ({drivable})")
    direction = c.get("direction", "int", 1)
    if direction not in (1, -1):
        c.fail("direction", f"must be +1 or -1, got {direction}")
    gear_ratio = c.positive("gear_ratio", 1.0)
    servo_backend = backend(servo.kind)        # whose units and registers the servo has
    options = servo_backend.joint_options(c, servo)
    lower, upper = model.lower[model.dof_names.index(dof)], model.upper[model.dof_names.index(dof)]
    limits = c.get("position_limits", "pair", (lower, upper))
    if not limits[0] < limits[1]:
        c.fail("position_limits", f"must be [lower, upper] with lower < upper, got {list(limits)}")
    if limits[0] < lower - 1e-9 or limits[1] > upper + 1e-9:
        c.fail("position_limits", f"{list(limits)} lies outside the model's limits [{lower:g}, {upper:g}]")
    current_limit = c.positive("current_limit", servo.stall_current)
    highest, how = servo_backend.max_current(servo, options)
    if current_limit > highest + 1e-12:
        c.fail("current_limit", f"{current_limit:g} A exceeds the {servo_name}'s largest current limit, "
                                f"{how} = {highest:.3g} A")
    scale = c.within("torque_constant_scale", 1.0)
    thermal = _thermal(c, servo.thermal_resistance, servo.thermal_time_constant)
    return JointConfig(dof=dof, bus=bus_name, id=servo_id, servo=servo, direction=direction,
                       zero_offset=c.within("zero_offset", 0.0), gear_ratio=gear_ratio,
                       torque_constant=c.positive("torque_constant", servo.torque_constant) * scale,
                       position_limits=limits,
                       velocity_limit=c.positive("velocity_limit", servo.no_load_speed / gear_ratio),
                       current_limit=current_limit, options=options, torque_constant_scale=scale,
                       friction_coulomb=c.within("friction_coulomb_nm", 0.0),
                       friction_viscous=c.within("friction_viscous_nm_s", 0.0),
                       thermal_resistance=thermal[0], thermal_time_constant=thermal[1])


def _thermal(c: _Checker, resistance: float, time_constant: float) -> tuple[float, float]:
    """(R_th, τ_th) of a table, each defaulting to the given; both > 0 (modelled) or both 0."""
    resistance = c.within("thermal_resistance_k_w", resistance)
    time_constant = c.within("thermal_time_constant_s", time_constant)
    if (resistance > 0) != (time_constant > 0):
        key = "thermal_time_constant_s" if resistance > 0 else "thermal_resistance_k_w"
        c.fail(key, f"must be positive when {'thermal_resistance_k_w' if resistance > 0 else 'thermal_time_constant_s'} "
                    "is (a winding model needs both; 0 and 0: not modelled)")
    return resistance, time_constant


@dataclass(frozen=True)
class Payload:
    """A point mass carried rigidly by a body (`[payload]`, `[sim.payload]`)."""
    body: str
    mass: float                   # kg
    com: tuple | None             # m in the body's frame; None: at the body's own centre of mass

    def on(self, model):
        return model.with_payload(self.mass, self.body, self.com)


def _payload(table, where: str, model) -> Payload:
    c = _Checker(table, where, PAYLOAD_KEYS)
    body = c.get("body", "str", model.body_names[-1])
    if body not in model.body_names:
        c.fail("body", f"{body!r} is not a body of model '{model.name}' ({', '.join(model.body_names)})")
    com = None
    if "com_m" in table:
        value = table["com_m"]
        if not (isinstance(value, list) and len(value) == 3 and all(map(_is_number, value))):
            c.fail("com_m", f"must be a list of three finite numbers (m in the body's frame), got {value!r}")
        if max(map(abs, value)) > 10.0:
            c.fail("com_m", f"{value} is more than 10 m from the body's origin")
        com = tuple(float(v) for v in value)
    return Payload(body=body, mass=c.within("mass_kg", 0.0), com=com)


@dataclass(frozen=True)
class PlantJoint:
    """One joint of the simulated arm as it really is (`[sim.joint.<dof>]`); None: the simulated
    servo's own (its data sheet's torque constant and thermal data, its built-in friction)."""
    friction_coulomb: float | None = None       # N m at the joint, sliding
    friction_viscous: float | None = None       # N m s/rad
    friction_static: float | None = None        # N m to break away from rest (default: Coulomb's)
    stribeck_velocity: float = 0.02             # rad/s over which static friction falls to Coulomb's
    torque_constant_scale: float = 1.0          # the torque a current gives / the configured torque_constant's
    thermal_resistance: float | None = None     # K/W
    thermal_time_constant: float | None = None  # s

    @property
    def has_friction(self) -> bool:
        return self.friction_coulomb is not None or self.friction_viscous is not None or \
            self.friction_static is not None


@dataclass(frozen=True)
class PlantSpec:
    """The arm the simulator runs when the configuration has a `[sim]` table: the model as its file
    describes it (not the configuration's identified armature and payload), its masses times
    `mass_scale`, then `[sim]`'s armatures and payload; per joint what `[sim.joint.<dof>]` says."""
    model: object                 # servodyn.Model of the plant
    joints: dict                  # dof -> PlantJoint (every dof)
    payload: Payload | None
    mass_scale: float
    source: str                   # where it was read (the configuration, or its plant file)


def _plant(table, where: str, base: Path | None, nominal_model) -> PlantSpec:
    """The `[sim]` table, over its plant file's keys when it names one (relative to the configuration)."""
    c = _Checker(table, where, SIM_KEYS)
    merged, source = {}, where
    if "plant" in table:
        ref = c.get("plant", "str")
        path = (base or Path.cwd()) / ref
        try:
            merged = read_toml(path, ConfigError, label=path.name)
        except FileNotFoundError:
            c.fail("plant", f"{str(path)!r}: no such file")
        source = path.name
        _Checker(merged, source, SIM_KEYS - {"plant"})
    for key, value in table.items():       # [sim]'s own keys over the file's, joint by joint
        if key == "joint" and isinstance(value, dict) and isinstance(merged.get("joint"), dict):
            merged["joint"] = {**merged["joint"], **{d: {**merged["joint"].get(d, {}), **t} if isinstance(t, dict)
                                                     else t for d, t in value.items()}}
        elif key != "plant":
            merged[key] = value
    c = _Checker(merged, source, SIM_KEYS - {"plant"})
    scale = c.within("mass_scale", 1.0)
    model = nominal_model.with_mass_scale(scale) if scale != 1.0 else nominal_model
    tables = merged.get("joint", {})
    if not isinstance(tables, dict):
        c.fail("joint", "must be a table of [sim.joint.<dof>] tables")
    joints, armature = {}, {}
    for dof, t in tables.items():
        if dof not in model.dof_names:
            c.fail("joint", f"{dof!r} is not a dof of model '{model.name}' ({', '.join(model.dof_names)})")
        j = _Checker(t, f"{source}: joint '{dof}'", SIM_JOINT_KEYS)
        given = lambda key: j.within(key, 0.0) if key in t else None
        thermal = _thermal(j, 0.0, 0.0) if {"thermal_resistance_k_w", "thermal_time_constant_s"} & set(t) else \
            (None, None)
        joints[dof] = PlantJoint(friction_coulomb=given("friction_coulomb_nm"),
                                 friction_viscous=given("friction_viscous_nm_s"),
                                 friction_static=given("friction_static_nm"),
                                 stribeck_velocity=j.within("stribeck_velocity_rad_s", PlantJoint.stribeck_velocity),
                                 torque_constant_scale=j.within("torque_constant_scale", 1.0),
                                 thermal_resistance=thermal[0], thermal_time_constant=thermal[1])
        if "armature_kg_m2" in t:
            armature[dof] = j.within("armature_kg_m2", 0.0)
        static, coulomb = joints[dof].friction_static, joints[dof].friction_coulomb or 0.0
        if static is not None and static < coulomb:
            j.fail("friction_static_nm", f"{static:g} N m is below friction_coulomb_nm ({coulomb:g}): an arm "
                                         "at rest holds at least what slides it")
    model = model.with_armature(armature) if armature else model
    payload = _payload(merged["payload"], f"{source}: payload", model) if "payload" in merged else None
    model = payload.on(model) if payload is not None else model
    joints = {d: joints.get(d, PlantJoint()) for d in model.dof_names}
    return PlantSpec(model=model, joints=joints, payload=payload, mass_scale=scale, source=source)


def _load_model(ref: str, base: Path | None, where: str):
    if ref.lower().endswith((".urdf", ".toml")):
        ref = str((base or Path.cwd()) / ref)
    try:
        return load_model(ref)
    except ValueError as err:
        raise ConfigError(f"{where}: 'model' {err}") from None


def _geared_armature(model, joints: dict[str, JointConfig]):
    """The model with the armature of every motor it names (at the motor's output) multiplied by
    the square of the gear stage its joint puts after that output. The motor is the model's, like
    its housing's mass: a configuration that drives the dof with another servo changes neither."""
    scaled = {d.name: d.armature * joints[d.name].gear_ratio ** 2
              for b in model.bodies for d in b.dofs if d.motor and joints[d.name].gear_ratio != 1.0}
    return model.with_armature(scaled) if scaled else model


def config_from_dict(data: dict, origin: str = "config", base: Path | None = None) -> RobotConfig:
    """Build and check a RobotConfig from parsed TOML; `base` resolves relative model paths."""
    top = _Checker(data, origin, TOP_KEYS)
    name = top.get("name", "str")
    string_key(data, "description", "", ConfigError, origin)      # a string, if given
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
        label = label if label.isprintable() else repr(label)     # a line break would split the error
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
    idle = [n for n in buses if not any(j.bus == n for j in joints.values())]
    if idle:
        raise ConfigError(f"{origin}: bus '{idle[0]}' has no joint (a [[joint]] with bus = \"{idle[0]}\"); remove the "
                          "bus, or give it its joints")
    model = _geared_armature(model, joints)
    nominal_model = model                 # as the model file describes it: what a [sim] plant starts from
    armature = {}
    for k, entry in enumerate(entries):
        if "armature_kg_m2" in entry:
            c = _Checker(entry, f"{origin}: joint {k + 1} ({entry['dof']})", set(entry))
            armature[entry["dof"]] = c.within("armature_kg_m2", 0.0)
    model = model.with_armature(armature) if armature else model
    payload = _payload(data["payload"], f"{origin}: payload", model) if "payload" in data else None
    model = payload.on(model) if payload is not None else model
    plant = _plant(data["sim"], f"{origin}: sim", base, nominal_model) if "sim" in data else None
    nominal = {j.servo.nominal_voltage for j in joints.values()}
    supply = SupplyConfig(voltage=max(nominal), current_limit=None)
    if "supply" in data:
        c = _Checker(data["supply"], f"{origin}: supply", SUPPLY_KEYS)
        supply = SupplyConfig(voltage=c.positive("voltage", supply.voltage),
                              current_limit=c.positive("current_limit") if "current_limit" in data["supply"] else None)
        why = supply_voltage_error(supply.voltage, joints.values())
        if why:
            c.fail("voltage", why)
    time_scale = None
    if "swing" in data:
        time_scale = _Checker(data["swing"], f"{origin}: swing", {"time_scale"}).positive("time_scale")
    period = SMALL_TIME_STEP
    if "control" in data:
        c = _Checker(data["control"], f"{origin}: control", {"period"})
        period = c.get("period", "float")
        why = check_control_period(period)
        if why:
            c.fail("period", why)
    return RobotConfig(name=name, path=None, model_ref=model_ref, model=model, buses=buses,
                       joints=tuple(joints[d] for d in model.dof_names), swing_time_scale=time_scale,
                       supply=supply, control_period=period, payload=payload, plant=plant)


def builtin_configs() -> dict[str, Path]:
    return {p.stem: p for p in sorted(CONFIGS_DIR.glob("*.toml"))}


def load_config(name_or_path: str | Path) -> RobotConfig:
    """A built-in configuration by name, or a configuration file."""
    path = builtin_configs().get(str(name_or_path), Path(name_or_path))
    try:
        data = read_toml(path, ConfigError, label=path.name)
    except FileNotFoundError:
        raise ConfigError(f"{name_or_path}: no such file, and not a built-in configuration "
                          f"({', '.join(builtin_configs()) or 'none installed'})") from None
    config = config_from_dict(data, origin=path.name, base=path.parent)
    return replace(config, path=path)

