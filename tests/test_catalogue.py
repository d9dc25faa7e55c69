"""The servo catalogue (hal/dynamixel/control_table.py SERVOS, hal/can/motors.py MOTORS,
host/model/parts.toml): every entry has a source, a housing part a model mounts with its mass,
data-sheet rows monotonic in the supply voltage; one built into a one-joint configuration loads
and its simulated servo answers as that model (a Dynamixel's ping gives its Model Number and its
control table its registers; a CAN motor's reply decodes in its ranges, a Damiao motor's TMAX
register is its own). The servos the backend cannot drive (no current control) and the supply
that would burn a 5 V servo are refused with one line."""

import math

import numpy as np
import pytest

from servodyn.hal.can import dialects, frames
from servodyn.hal.can.motors import MOTORS
from servodyn.hal.config import ConfigError, config_from_dict, supply_voltage_error
from servodyn.hal.dynamixel import decode_frame, instructions as inst
from servodyn.hal.dynamixel.control_table import SERVOS
from servodyn.model.modelfile import parts
from servodyn.sim.robot import SimulatedRobot

CATALOGUE = {**SERVOS, **MOTORS}
# the figures of the e-manual a sizing rests on, re-read: (Model Number, stall torque N m and no-load
# rpm at the nominal voltage, gear ratio, grams)
EMANUAL = {
    "XL330-M288": (1200, 5.0, 0.52, 103, 288.4, 18), "XL430-W250": (1060, 11.1, 1.4, 57, 258.5, 57.2),
    "XC330-T288": (1220, 11.1, 0.92, 65, 288.35, 23), "XC430-W240": (1080, 12.0, 1.9, 70, 245.22, 65),
    "XM430-W210": (1030, 12.0, 3.0, 77, 212.6, 82), "XM430-W350": (1020, 12.0, 4.1, 46, 353.5, 82),
    "XM540-W150": (1130, 12.0, 7.3, 53, 152.3, 165), "XM540-W270": (1120, 12.0, 10.6, 30, 272.5, 165),
    "XH430-W210": (1010, 12.0, 2.5, 50, 212.6, 82), "XH430-W350": (1000, 12.0, 3.4, 30, 353.5, 82),
    "XH540-W150": (1110, 12.0, 7.1, 70, 152.3, 165), "XH540-W270": (1100, 12.0, 9.9, 39, 272.5, 165),
    "XW540-T260": (1170, 12.0, 9.5, 40, 260.6, 185),
}
# the CAN motors' figures in their manufacturers' documents, re-read (hal/can/motors.py says which):
# (nominal V, gear ratio, peak and rated torque N m, {V: no-load rpm}, supply range V or None, grams,
# outer diameter and height mm)
MANUFACTURER = {
    "DM-J4310": (24.0, 10.0, 7.0, 3.0, {24.0: 200.0}, None, 300, 56.0, 46.0),
    "DM-J4340": (24.0, 40.0, 27.0, 9.0, {24.0: 52.5, 48.0: 100.0}, None, 362, 57.0, 53.3),
    "DM-J6006": (24.0, 6.0, 12.0, 4.0, {24.0: 240.0}, (24.0, 48.0), 335, 76.0, 36.5),
    "DM-J8009": (24.0, 9.0, 40.0, 20.0, {24.0: 160.0, 48.0: 320.0}, (24.0, 48.0), 896, 98.0, 61.7),
    "AK60-6": (24.0, 6.0, 9.0, 3.0, {24.0: 320.0}, None, 368, 79.0, 39.5),
    "AK70-10": (24.0, 10.0, 24.8, 8.3, {24.0: 240.0, 48.0: 480.0}, (18.0, 52.0), 521, 89.0, 50.25),
    "AK80-9": (48.0, 9.0, 18.0, 9.0, {48.0: 390.0}, (18.0, 52.0), 485, 98.0, 38.5),
}
# CAN entries with a figure (other than the thermal ones, which no vendor publishes) still estimated:
# the AK80-9's no-load speed (CubeMars' rated speed, a bound from below)
CAN_ESTIMATED = {"AK80-9"}
ISSUE_24 = {"XL330-M288", "XL430-W250", "XC330-T288", "XC430-W240", "XM430-W210", "XM430-W350", "XM540-W150",
            "XM540-W270", "XH430-W210", "XH430-W350", "XH540-W150", "XH540-W270", "XW540-T260", "DM-J4310",
            "DM-J4340", "DM-J6006", "DM-J8009", "AK60-6", "AK70-10", "AK80-9"}


def one_joint(name: str, tmp_path, supply: float | None = None) -> dict:
    """A one-joint arm whose joint is driven by `name` and carries its housing (the catalogue's
    part, placed by the model file) and a 0.1 kg load 0.1 m out; the configuration as parsed TOML."""
    spec = CATALOGUE[name]
    (tmp_path / "arm.toml").write_text(f'''name = "one_joint"
[[body]]
name = "link"
parent = "base"
pos = [0.0, 0.0, 0.0]
  [[body.dof]]
  name = "j"
  axis = [0.0, 1.0, 0.0]
  lower = -3.0
  upper = 3.0
  [[body.solid]]
  part = "{name}"
  pos = [0.0, 0.0, 0.0]
  [[body.solid]]
  type = "sphere"
  radius = 0.02
  mass = 0.1
  pos = [0.1, 0.0, 0.0]
''')
    if spec.kind == "can":
        bus = {"kind": "can", "interface": "virtual", "channel": "auto", "bitrate": 1_000_000}
        joint = {"dof": "j", "id": 1, "motor": name}
    else:
        bus = {"kind": "dynamixel", "port": "auto", "baud": 1_000_000}
        joint = {"dof": "j", "id": 1, "servo": name}
    data = {"name": "one", "model": "arm.toml", "bus": {"b": bus}, "joint": [joint]}
    if supply is not None:
        data["supply"] = {"voltage": supply}
    return data


def load(data, tmp_path):
    return config_from_dict(data, origin="one.toml", base=tmp_path)


def test_the_catalogue_is_the_issues_list():
    assert set(CATALOGUE) == ISSUE_24, f"missing {ISSUE_24 - set(CATALOGUE)}, extra {set(CATALOGUE) - ISSUE_24}"
    assert len({s.model_number for s in SERVOS.values()}) == len(SERVOS), "one Model Number per Dynamixel"


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_every_entry_has_a_source_a_housing_and_monotonic_ratings(name):
    spec = CATALOGUE[name]
    assert len(spec.source) > 40, f"{name}: a source that says where its figures come from"
    part = parts()[name]
    assert 0.01 <= part["mass"] <= 2.0, f"{name}: the housing's mass, {part['mass']} kg, is a servo's (10 g - 2 kg)"
    assert "source" in part and len(part["source"]) > 40, f"{name}: the housing's figures have a source"
    rows = spec._rows()
    assert len(rows) >= (3 if spec.kind == "dynamixel" else 1), f"{name}: every published voltage's row"
    steps = np.diff(rows, axis=0)
    assert np.all(steps[:, 3] > 0), f"{name}: the no-load speed rises with the voltage"
    assert np.all(steps[:, 1:3] >= 0), f"{name}: stall (peak) torque and current never fall with the voltage " \
                                       "(a CAN motor's peak is its current limit's, the same at 24 and 48 V)"
    assert spec.torque_constant > 0 and spec.no_load_speed > 0 and spec.gear_ratio >= 1
    if spec.kind == "can":
        assert ("ESTIMATE" in spec.source) == (name in CAN_ESTIMATED), \
            f"{name}: an entry says ESTIMATE exactly when one of its data-sheet figures is one"


@pytest.mark.parametrize("name", sorted(MANUFACTURER))
def test_can_figures_are_the_manufacturers(name):
    volts, gear, peak, rated, no_load, supply, grams, diameter, height = MANUFACTURER[name]
    spec, part = MOTORS[name], parts()[name]
    assert (spec.nominal_voltage, spec.gear_ratio, spec.rated_torque, spec.supply_range) == \
        (volts, gear, rated, supply), f"{name}: nominal voltage, gear, rated torque, supply range"
    for v, rpm in no_load.items():
        assert spec.stall_torque_at(v) == pytest.approx(peak, abs=1e-9), f"{name}: peak {peak} N m at {v} V"
        assert spec.no_load_speed_at(v) == pytest.approx(rpm * 2 * math.pi / 60, rel=1e-9), \
            f"{name}: no-load {rpm} rpm at {v} V"
    assert part["type"] == "cylinder", f"{name}: a round housing"
    assert part["mass"] == pytest.approx(grams / 1000, abs=1e-9), f"{name}: {grams} g"
    assert (2 * part["radius"], part["length"]) == (pytest.approx(diameter / 1000, abs=1e-9),
                                                    pytest.approx(height / 1000, abs=1e-9)), \
        f"{name}: {diameter} mm x {height} mm"
    assert peak <= spec.ranges.t_max, f"{name}: the MIT torque range ({spec.ranges.t_max} N m) holds its peak"


@pytest.mark.parametrize("name", sorted(EMANUAL))
def test_dynamixel_figures_are_the_emanuals(name):
    number, volts, torque, rpm, gear, grams = EMANUAL[name]
    spec = SERVOS[name]
    assert (spec.model_number, spec.nominal_voltage, spec.gear_ratio) == (number, volts, gear), name
    assert spec.stall_torque_at(volts) == pytest.approx(torque, abs=1e-9), f"{name}: stall torque at {volts} V"
    assert spec.no_load_speed_at(volts) == pytest.approx(rpm * 2 * math.pi / 60, rel=1e-9), f"{name}: no-load"
    assert parts()[name]["mass"] == pytest.approx(grams / 1000, abs=1e-9), f"{name}: {grams} g"


@pytest.mark.parametrize("name", sorted(n for n, s in CATALOGUE.items() if s.current_control))
def test_every_drivable_entry_loads_and_its_simulated_servo_answers_as_it(name, tmp_path):
    spec = CATALOGUE[name]
    config = load(one_joint(name, tmp_path), tmp_path)
    joint = config.joints[0]
    assert joint.servo is spec, "the configuration holds the catalogue's entry"
    mass = sum(body.mass for body in config.model.bodies)
    assert mass == pytest.approx(parts()[name]["mass"] + 0.1, abs=1e-9), "the housing is mounted on the model"
    assert config.supply.voltage == spec.nominal_voltage, "no [supply]: the servo's nominal voltage"
    port = SimulatedRobot(config).port()
    if spec.kind == "dynamixel":
        reply = decode_frame(port.handle(inst.ping(1).encode()))
        assert int.from_bytes(reply.params[:2], "little") == spec.model_number, f"a ping: {name}'s Model Number"
        reply = decode_frame(port.handle(inst.read(1, 44, 4).encode()))
        assert int.from_bytes(reply.params[:4], "little") == spec.velocity_limit_default, \
            f"its table: Velocity Limit(44) defaults to {spec.velocity_limit_default}"
        reply = decode_frame(port.handle(inst.read(1, 38, 2).encode()))
        assert int.from_bytes(reply.params[:2], "little") == spec.current_limit_max, "its Current Limit(38)"
        return
    answers = port.handle(1, bytes(7 * [0xFF]) + bytes([frames.ENTER]))
    assert len(answers) == 1, f"{name} answers the enable frame once"
    fid, data = answers[0]
    assert fid == joint.options["feedback_id"], "on its reply id"
    reply = DIALECT_UNPACK[spec.dialect](spec.ranges, data)
    assert abs(reply.p) <= spec.ranges.p_max and abs(reply.t) <= spec.ranges.t_max / 1000 + 2 * spec.ranges.t_max / 4095
    if spec.dialect == "damiao":
        request = frames.pack_register(frames.Register(1, frames.REG_READ, dialects.REG_TMAX))
        (_, echo), = port.handle(frames.REGISTER_ID, request)
        value = dialects.register_value(dialects.REG_TMAX, frames.unpack_register(echo))
        assert value == pytest.approx(spec.ranges.t_max, rel=1e-6), f"its TMAX register: {spec.ranges.t_max} N m"


DIALECT_UNPACK = {"damiao": frames.unpack_damiao_feedback, "cubemars": frames.unpack_cubemars_reply}


@pytest.mark.parametrize("name", sorted(n for n, s in SERVOS.items() if not s.current_control))
def test_a_servo_without_current_control_is_driven_by_pwm(name, tmp_path):
    """XL430-W250 and XC430-W240: Operating Mode(11) has no current mode, their tables no Goal
    Current; a configuration naming one drives it by PWM (hal/dynamixel/pwm.py: the torque becomes a
    duty through the motor model), which its table has."""
    assert name in ("XL430-W250", "XC430-W240")
    config = load(one_joint(name, tmp_path), tmp_path)
    assert config.joints[0].options.get("drive", "pwm") == "pwm", config.joints[0].options
    items = {item.name for item in SERVOS[name].items()}
    assert not items & {"current_limit", "goal_current", "present_current"} and {"present_load", "goal_pwm"} <= items, \
        "its table: no current items, Present Load(126) and Goal PWM(100)"


def test_a_5_volt_servo_at_12_volts_is_refused(tmp_path):
    """The XL330-M288 is a 5 V servo (3.7-6.0 V): its own supply loads, 12 V is refused by the
    configuration and by the validator's --supply-voltage check (one function)."""
    spec = SERVOS["XL330-M288"]
    assert spec.supply_range == (3.7, 6.0) and spec.nominal_voltage == 5.0
    assert load(one_joint("XL330-M288", tmp_path, supply=6.0), tmp_path).supply.voltage == 6.0
    with pytest.raises(ConfigError) as err:
        load(one_joint("XL330-M288", tmp_path, supply=12.0), tmp_path)
    assert "XL330-M288's supply range, 3.7 to 6 V" in str(err.value) and "\n" not in str(err.value), str(err.value)
    config = load(one_joint("XL330-M288", tmp_path), tmp_path)
    assert supply_voltage_error(12.0, config.joints) is not None and supply_voltage_error(5.0, config.joints) is None
    # the envelope at 5 V is the e-manual's, at 6 V its 6 V row: 0.60 N m, 123 rpm
    assert spec.stall_torque_at(6.0) == pytest.approx(0.60) and spec.no_load_speed_at(6.0) == \
        pytest.approx(123 * 2 * math.pi / 60)


def test_x330_tables_count_current_in_milliamps(tmp_path):
    """XL330/XC330: Current Limit(38) in 1 mA units up to 1750 / 910, Velocity Limit up to 2047, Baud
    Rate up to 4 Mbps (index 6); the XW540 has no LED(65)."""
    xl, xc = SERVOS["XL330-M288"], SERVOS["XC330-T288"]
    assert xl.current_unit == xc.current_unit == 1e-3
    assert xl.max_current == pytest.approx(1.75) and xc.max_current == pytest.approx(0.91), "1750 / 910 mA"
    item = {i.name: i for i in xl.items()}
    assert item["velocity_limit"].high == 2047 and item["baud_rate"].high == 6 and item["temperature_limit"].default == 70
    assert "led" not in {i.name for i in SERVOS["XW540-T260"].items()}, "no LED on the XW540"
    config = load(one_joint("XL330-M288", tmp_path), tmp_path)
    assert config.joints[0].current_limit == pytest.approx(1.47), "default: the stall current at 5 V"


# the parts whose armature a published model gives (parts.toml's sources say which); every other
# is an estimate by the rule in parts.toml's header, recomputed here
SOURCED_ARMATURE = {"XM430-W350", "XM540-W270", "XL330-M288", "DM-J4310", "DM-J4340", "DM-J8009"}
CASE_REFERENCE = {"X330": "XL330-M288", "X430": "XM430-W350", "X540": "XM540-W270"}
CAN_ROTOR = 1.0e-4          # kg m^2: OpenArm's rotor for every Damiao frame it models


def _rotor(name: str) -> float:
    """A servo's rotor inertia (kg m^2) by parts.toml's rule: a sourced one's from its armature; a
    gear variant of a motor (same case, same stall current) shares the variant's with the higher
    gear; else the case reference's, scaled by the motor-side stall torque to the power 5/3."""
    spec = CATALOGUE[name]
    if spec.kind == "can":
        return parts()[name]["armature"] / spec.gear_ratio ** 2 if name in SOURCED_ARMATURE else CAN_ROTOR
    if name in SOURCED_ARMATURE:
        return parts()[name]["armature"] / spec.gear_ratio ** 2
    case = "X" + name[2:5]
    variants = [n for n in SERVOS if n != name and n[2:5] == name[2:5] and n[:2] == name[:2]
                and SERVOS[n].stall_current == spec.stall_current and SERVOS[n].gear_ratio > spec.gear_ratio]
    if variants:
        return _rotor(variants[0])
    ref = CATALOGUE[CASE_REFERENCE[case]]
    motor_torque = lambda s: s.stall_torque / s.gear_ratio
    return _rotor(ref.name) * (motor_torque(spec) / motor_torque(ref)) ** (5 / 3)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_every_part_has_an_armature_sourced_or_estimated_by_the_rule(name):
    """No part without a rotor inertia (sizing would take it as 0 and favour it); an estimate says
    so in its source and is the rule's figure to its rounding (2 to 3 significant figures: 2 %)."""
    part = parts()[name]
    assert part["armature"] is not None and part["armature"] > 0, f"{name}: an armature in parts.toml"
    estimated = "estimate" in part["source"].lower().split("armature", 1)[-1]
    if name in SOURCED_ARMATURE:
        return
    assert estimated, f"{name}: its armature is an estimate and its source must say so"
    expected = _rotor(name) * CATALOGUE[name].gear_ratio ** 2
    assert part["armature"] == pytest.approx(expected, rel=0.02), f"{name}: the rule gives {expected:.4g} kg m^2"
