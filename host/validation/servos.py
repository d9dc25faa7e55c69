"""The servos sizing picks from: every backend's catalogue (hal: the Dynamixel SERVOS, the CAN
MOTORS) by family, why a servo is no candidate at a supply voltage, and a servo's housing mass
(model/parts.toml). The search is validation/sizing.py."""

from __future__ import annotations

import tomllib

from ..errors import ServodynError
from ..hal.backend import backend, servo_catalogue
from ..hal.config import builtin_configs
from ..model.modelfile import parts

FAMILIES = ("dynamixel", "can", "feetech", "any")
# 'any' mixes the families whose buses can share one robot (one bus each, one supply); a Feetech bus
# speaks neither Dynamixel nor CAN, and the SO-101's arms are sized within it (--family feetech)
ANY = ("dynamixel", "can")


class SizingError(ServodynError, ValueError):
    """Input sizing cannot work with; one line."""



def rated_span(servo) -> tuple[float, float]:
    """V: the supply range the data sheet allows, or the span of its rated rows where none is given."""
    if servo.supply_range is not None:
        return servo.supply_range
    volts = [servo.nominal_voltage, *(row[0] for row in servo.ratings)]
    return min(volts), max(volts)


def drivable(servo) -> bool:
    """Whether the servo's backend can drive it by its torque: by current, or (a Dynamixel without
    current control) through PWM."""
    return servo.current_control or backend(servo.kind).torque_through_pwm


def unusable(servo, voltage: float) -> str | None:
    """Why sizing never picks `servo` at this supply voltage, or None."""
    if not drivable(servo):
        return "no current control mode (the backend drives every joint by its torque)"
    low, high = rated_span(servo)
    if not low <= voltage <= high:
        return f"{voltage:g} V is outside its supply range, {low:g} to {high:g} V"
    if servo.name not in parts():
        return "no housing in parts.toml (mass and size unknown)"
    if parts()[servo.name]["armature"] is None:
        return "no armature in parts.toml (its rotor inertia unknown, not 0)"
    return None


def _builtin_configs_of(model_ref: str) -> list[dict]:
    """The built-in configurations (hal/configs) of the model `model_ref` names, as TOML tables."""
    found = []
    for path in builtin_configs().values():
        data = tomllib.loads(path.read_text(encoding="utf-8"))
        if data.get("model") == model_ref:
            found.append(data)
    return found


def default_family(model_ref: str) -> str:
    """The family a model is sized within when none is named: its built-in configurations' bus kind
    where they all share one (the SO-101's Feetech bus: a Feetech bus drives no Dynamixel), else
    the first family."""
    kinds = {bus.get("kind") for data in _builtin_configs_of(model_ref) for bus in data.get("bus", {}).values()}
    return kinds.pop() if len(kinds) == 1 and kinds <= set(FAMILIES) else FAMILIES[0]


def configured_voltages(model_ref: str) -> list[float]:
    """The supply voltages the model's built-in configurations run at (the SO-101's 5 V)."""
    return sorted({float(data["supply"]["voltage"]) for data in _builtin_configs_of(model_ref)
                   if isinstance(data.get("supply", {}).get("voltage"), (int, float))})


def catalogue(family: str) -> dict:
    """The servos of a family by name (every backend's for 'any')."""
    if family not in FAMILIES:
        raise SizingError(f"no servo family {family!r} (the families: {', '.join(FAMILIES)})")
    kinds = ANY if family == "any" else (family,)
    found = {}
    for kind in kinds:
        found.update(servo_catalogue(kind))
    return found


def supply_voltages(family: str, model_ref: str | None = None) -> list[float]:
    """The supply voltages worth trying when none is given: each servo's nominal voltage, and those
    the model's built-in configurations run at (what the robot has today)."""
    configured = configured_voltages(model_ref) if model_ref else []
    return sorted({s.nominal_voltage for s in catalogue(family).values() if drivable(s)} | set(configured))


def part_mass(name: str) -> float:
    return float(parts()[name]["mass"])
