"""The `[sim]` table: the arm the simulator runs when it is not the configured one (a plant file
over the model file, its masses scaled, its own armatures, friction and thermal data per joint),
and the payload a `[payload]` or `[sim.payload]` table puts on a body (`Payload`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..model.files import read_toml
from .config_check import IDENTIFIED_KEYS, _Checker, _is_number, _thermal
from .errors import ConfigError

PAYLOAD_KEYS = {"body", "mass_kg", "com_m"}
# the [sim] table (and a plant file): the arm the simulator runs, when it is not the configured one
SIM_KEYS = {"plant", "mass_scale", "payload", "joint"}
SIM_JOINT_KEYS = {*IDENTIFIED_KEYS, "friction_static_nm", "stribeck_velocity_rad_s"}


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
