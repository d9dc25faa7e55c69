"""The checks a configuration's tables go through (hal/config.py, hal/plant_spec.py): the physically
sane range of every number (`RANGES`), the keys identification measures, typed look-ups in one
table that fail in one line naming the file, the entry and the key (`_Checker`), and a winding's
thermal pair (`_thermal`)."""

from __future__ import annotations

import math

from .errors import ConfigError

# what identification measures (`servodyn identify` writes these names in its patch): each a
# number >= 0 in its RANGES; absent, the model's armature, the servo's thermal data, no friction
IDENTIFIED_KEYS = ("friction_coulomb_nm", "friction_viscous_nm_s", "torque_constant_scale", "armature_kg_m2",
                   "thermal_resistance_k_w", "thermal_time_constant_s")

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


class _Checker:
    """Typed look-ups in one TOML table; every failure names `where` and the key."""

    def __init__(self, table, where: str, allowed: set[str]):
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: must be a table")
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(allowed))})")
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


def _thermal(c: _Checker, resistance: float, time_constant: float) -> tuple[float, float]:
    """(R_th, τ_th) of a table, each defaulting to the given; both > 0 (modelled) or both 0."""
    resistance = c.within("thermal_resistance_k_w", resistance)
    time_constant = c.within("thermal_time_constant_s", time_constant)
    if (resistance > 0) != (time_constant > 0):
        key = "thermal_time_constant_s" if resistance > 0 else "thermal_resistance_k_w"
        c.fail(key, f"must be positive when {'thermal_resistance_k_w' if resistance > 0 else 'thermal_time_constant_s'} "
                    "is (a winding model needs both; 0 and 0: not modelled)")
    return resistance, time_constant
