"""Robot configuration: which servo drives which dof of a model, on which bus (TOML).

    cfg = load_config("replica")          # built-in (hal/configs/replica.toml) or a .toml path
    cfg.model.dof_names                    # the servodyn Model the config refers to
    cfg.joints                             # one JointConfig per dof, in the model's dof order

The format is in hal/README.md. Every mistake raises ConfigError with one line that names
the file, the entry and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from ..control.motion import DEFAULT_MOTION, builtin_motions
from ..control.timing import SMALL_TIME_STEP, check_control_period
from ..model import load_model
from ..model.files import read_toml, string_key
from .backend import BACKENDS, backend, servo_catalogue
from .config_check import IDENTIFIED_KEYS, RANGES, _Checker, _is_number, _thermal
from .errors import ConfigError
from .plant_spec import Payload, PlantSpec, _payload, _plant
from .safety import SafetyConfig, safety_from_table
from .servos import ServoSpec

CONFIGS_DIR = Path(__file__).parent / "configs"
TOP_KEYS = {"name", "description", "model", "bus", "joint", "swing", "supply", "control", "payload", "sim", "safety"}
SUPPLY_KEYS = {"voltage", "current_limit"}
BUS_KEYS = {"kind", "port", "baud", "protocol"}
JOINT_KEYS = {"dof", "bus", "id", "servo", "direction", "zero_offset", "gear_ratio",
              "torque_constant", "position_limits", "velocity_limit", "current_limit", *IDENTIFIED_KEYS}


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
    swing_motion: str = DEFAULT_MOTION   # `[swing] motion`: what a swing plays unless told otherwise
    supply: SupplyConfig | None = None    # None: the servos' nominal voltage, no current rating
    control_period: float = SMALL_TIME_STEP   # s: one read and write of every bus (`[control] period`)
    payload: "Payload | None" = None      # `[payload]`, already in `model`
    plant: "PlantSpec | None" = None      # `[sim]`: the arm the simulator runs (None: this one)
    safety: SafetyConfig | None = None    # `[safety]` (hal.safety); None: its defaults (`guards`)

    @property
    def guards(self) -> SafetyConfig:
        """The `[safety]` table, or its defaults when the file has none."""
        return self.safety if self.safety is not None else SafetyConfig.default(self.model.dof_names)

    def time_scale_for(self, motion: str) -> float:
        """The time scale a motion plays at by default: the configuration's (`[swing] time_scale`) for
        its own motion (`[swing] motion`, the forehand unless it names another), 1 for any other."""
        return (self.swing_time_scale if motion == self.swing_motion else None) or 1.0

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
    own = backend(bus.kind).catalogue(bus)
    catalogue = dict(own) if own is not None else servo_catalogue(bus.kind)
    if servo_name not in catalogue:
        others = {k: s for k, s in servo_catalogue(None).items() if k not in catalogue}
        if servo_name in others:
            c.fail(device_key, f"{servo_name} is a {others[servo_name].kind} device but bus '{bus_name}' is "
                               f"{bus.kind}")
        c.fail(device_key, f"{servo_name!r} is not a known {bus.kind} {spec.device_key} ({', '.join(catalogue)})")
    servo = catalogue[servo_name]
    if not servo.current_control and not backend(servo.kind).torque_through_pwm:
        drivable = ", ".join(k for k, s in catalogue.items() if s.current_control)
        c.fail(device_key, f"{servo_name} has no current control mode, and the {bus.kind} backend drives every "
                           f"joint by its torque (Goal Current); choose one that has ({drivable})")
    direction = c.get("direction", "int", 1)
    if direction not in (1, -1):
        c.fail("direction", f"must be +1 or -1, got {direction}")
    gear_ratio = c.positive("gear_ratio", 1.0)
    servo_backend = backend(servo.kind)        # whose units and registers the servo has
    servo_backend.check_joint(c, servo, bus)
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


def _swing_motion(c, base: Path | None) -> str:
    """`[swing] motion`: a built-in motion's name, or a keyframe file or trajectory CSV (relative to
    the configuration's folder) that exists."""
    name = c.get("motion", "str")
    if name in builtin_motions():
        return name
    path = (base or Path.cwd()) / name
    if path.suffix not in (".toml", ".csv") or not path.is_file():
        c.fail("motion", f"{name!r} is neither a built-in motion ({', '.join(builtin_motions())}) nor a keyframe "
                         ".toml or trajectory .csv file")
    return str(path)


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
    time_scale, swing_motion = None, DEFAULT_MOTION
    if "swing" in data:
        c = _Checker(data["swing"], f"{origin}: swing", {"time_scale", "motion"})
        time_scale = c.positive("time_scale") if "time_scale" in data["swing"] else None
        swing_motion = _swing_motion(c, base) if "motion" in data["swing"] else DEFAULT_MOTION
    period = SMALL_TIME_STEP
    if "control" in data:
        c = _Checker(data["control"], f"{origin}: control", {"period"})
        period = c.get("period", "float")
        why = check_control_period(period)
        if why:
            c.fail("period", why)
    return RobotConfig(name=name, path=None, model_ref=model_ref, model=model, buses=buses,
                       joints=tuple(joints[d] for d in model.dof_names), swing_time_scale=time_scale, swing_motion=swing_motion,
                       supply=supply, control_period=period, payload=payload, plant=plant,
                       safety=safety_from_table(data["safety"], f"{origin}: safety", model.dof_names)
                       if "safety" in data else None)


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

