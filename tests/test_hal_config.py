"""Robot configurations (hal/config.py), the built-in replica and its model, and whether the
replica's servos can follow the tennis swing."""

import copy
import dataclasses
import math
import shutil
import tomllib

import numpy as np
import pytest

import servodyn
from servodyn.hal.dynamixel.control_table import SERVOS
from servodyn.hal.config import CONFIGS_DIR, ConfigError, config_from_dict, load_config
from servodyn.control.motion import DEFAULT_MOTION, load_motion

with open(CONFIGS_DIR / "replica.toml", "rb") as f:
    REPLICA = tomllib.load(f)


def build(mutate):
    data = copy.deepcopy(REPLICA)
    mutate(data)
    return config_from_dict(data, origin="test.toml")


def set_joint(k, key, value):
    def mutate(data):
        data["joint"][k][key] = value
    return mutate


def test_builtin_replica():
    """Seven joints in the model's dof order on one bus, IDs 1-7, the servos the model is built
    from, torque constants from the servo table (stall torque / stall current at 12 V)."""
    config = load_config("replica")
    assert [j.dof for j in config.joints] == list(config.model.dof_names), "one joint per dof, in the model's order"
    assert [j.id for j in config.joints] == list(range(1, 8)), "IDs 1-7 from the shoulder out"
    assert {j.bus for j in config.joints} == {"arm"} and config.buses["arm"].baud == 4_000_000, \
        "every joint on the one bus 'arm', at 4 Mbps"
    assert [j.servo.name for j in config.joints] == ["XM540-W270"] * 3 + ["XM430-W350"] * 4, \
        "XM540-W270 at the shoulder, XM430-W350 from the elbow out"
    for j in config.joints:
        assert j.torque_constant == pytest.approx(j.servo.torque_constant, abs=5e-4), \
            f"{j.dof}: the file's kt is stall torque / stall current, rounded to 1e-3"
        assert j.position_limits == pytest.approx(
            (config.model.lower[config.model.dof_names.index(j.dof)],
             config.model.upper[config.model.dof_names.index(j.dof)])), \
            f"{j.dof}: position_limits left out, so the model's"
    assert config.swing_time_scale == 4.0, "the [swing] time_scale, the smallest that fits (test below)"


def test_time_scale_applies_to_the_default_motion_only():
    """The [swing] time_scale was chosen for the default motion: time_scale_for gives it for that
    motion, 1.0 for any other, and 1.0 when the file has no [swing] table."""
    config = load_config("replica")
    assert config.time_scale_for(DEFAULT_MOTION) == 4.0, "the forehand at the file's scale"
    assert config.time_scale_for("wave") == 1.0, "another motion as written"
    unscaled = dataclasses.replace(config, swing_time_scale=None)
    assert unscaled.time_scale_for(DEFAULT_MOTION) == 1.0, "no [swing] time_scale: as written"


def test_servo_table():
    """e-manual numbers: the XM540-W270 lists 2.409 N m/A at 12 V; Current Limit ranges 1193 and
    2047 units of 2.69 mA are 3.21 and 5.51 A, above the stall currents 2.3 and 4.4 A."""
    xm540, xm430 = SERVOS["XM540-W270"], SERVOS["XM430-W350"]
    assert xm540.torque_constant == pytest.approx(2.409, abs=5e-4), "XM540-W270: 10.6 N m / 4.4 A"
    assert xm430.torque_constant == pytest.approx(1.783, abs=5e-4), "XM430-W350: 4.1 N m / 2.3 A"
    assert xm430.current_limit_max * xm430.current_unit == pytest.approx(3.209, abs=1e-3), "1193 x 2.69 mA"
    assert xm540.current_limit_max * xm540.current_unit == pytest.approx(5.506, abs=1e-3), "2047 x 2.69 mA"
    assert xm430.no_load_speed == pytest.approx(46 * 2 * math.pi / 60), "XM430-W350: 46 rpm no-load at 12 V"
    assert {n: SERVOS[n].model_number for n in ("XM430-W350", "XM540-W270", "XH430-W350", "XH540-W270")} == \
        {"XM430-W350": 1020, "XM540-W270": 1120, "XH430-W350": 1000, "XH540-W270": 1100}, "Model Number(0), e-manual"


def test_defaults_come_from_the_servo_and_the_model():
    """A joint that gives only dof, id and servo gets direction +1, no offset, direct drive, the
    servo's constants, its no-load speed and stall current as limits, the model's position limits."""
    def strip(data):
        data["joint"] = [{k: j[k] for k in ("dof", "id", "servo")} for j in data["joint"]]
    config = build(strip)
    elbow = config.joints[3]
    assert (elbow.direction, elbow.zero_offset, elbow.gear_ratio) == (1, 0.0, 1.0), \
        "direction +1, no offset, direct drive"
    assert elbow.torque_constant == pytest.approx(4.1 / 2.3), "the XM430-W350's stall torque / stall current"
    assert elbow.options["current_unit"] == 2.69e-3 and elbow.current_limit == 2.3, \
        "the XM430-W350's 2.69 mA unit; the limit is its 2.3 A stall current"
    assert elbow.velocity_limit == pytest.approx(46 * 2 * math.pi / 60), "the XM430-W350's 46 rpm no-load speed"
    assert elbow.position_limits == pytest.approx((0.0, 2.618)), "the model's elbow range, 0 to 150 deg"
    assert elbow.bus == "arm", "the only bus is the default"
    assert elbow.torque_limit == pytest.approx(4.1), "at the stall current the joint gives the stall torque"


def test_gear_ratio_scales_the_default_speed_limit():
    """With a 2:1 reduction after the horn the joint turns at half the servo's speed, with twice
    its torque; an explicit velocity_limit is kept as given."""
    assert build(set_joint(0, "gear_ratio", 2.0)).joints[0].velocity_limit == 3.1416, \
        "replica.toml's velocity_limit for joint 1, kept as given"

    def geared(data):
        data["joint"][0]["gear_ratio"] = 2.0
        del data["joint"][0]["velocity_limit"]
    flexion = build(geared).joints[0]
    assert flexion.velocity_limit == pytest.approx(math.pi / 2), "30 rpm at the horn / 2"
    assert flexion.torque_limit == pytest.approx(2 * 10.6, abs=0.01), "2.409 N m/A x 4.4 A x 2"


def drop_last_joint(data):
    data["joint"].pop()


def bus_kind_ethercat(data):
    data["bus"]["arm"]["kind"] = "ethercat"


def bus_kind_can(data):
    data["bus"]["arm"]["kind"] = "can"


BAD = [  # (what is wrong, mutation, words the one-line message must contain)
    ("unknown dof", set_joint(0, "dof", "r_shoulder"), ["joint 1", "'dof'", "r_shoulder"]),
    ("dof missing a joint", drop_last_joint, ["'joint'", "r_wrist_deviation"]),
    ("dof twice", set_joint(1, "dof", "r_shoulder_flexion"), ["joint 2", "'dof'", "already"]),
    ("duplicate id on a bus", set_joint(1, "id", 1), ["joint 2", "'id'", "already used", "r_shoulder_flexion"]),
    ("id out of range", set_joint(2, "id", 253), ["joint 3", "'id'", "253"]),
    ("unknown servo", set_joint(3, "servo", "XM999"), ["joint 4", "'servo'", "XM999"]),
    ("direction 0", set_joint(4, "direction", 0), ["joint 5", "'direction'", "+1 or -1"]),
    ("direction 2", set_joint(4, "direction", 2), ["'direction'"]),
    ("direction not an integer", set_joint(4, "direction", 1.0), ["'direction'", "integer"]),
    ("gear ratio 0", set_joint(5, "gear_ratio", 0.0), ["joint 6", "'gear_ratio'", "positive"]),
    ("negative torque constant", set_joint(5, "torque_constant", -1.7), ["'torque_constant'", "positive"]),
    ("zero current unit", set_joint(6, "current_unit", 0.0), ["joint 7", "'current_unit'", "positive"]),
    ("limits out of order", set_joint(3, "position_limits", [2.0, 1.0]), ["'position_limits'", "lower < upper"]),
    ("limits beyond the model", set_joint(0, "position_limits", [-2.0, 1.0]),
     ["'position_limits'", "outside the model's limits"]),
    ("limits not numbers", set_joint(0, "position_limits", [0.0, "1"]), ["'position_limits'", "two finite"]),
    ("unknown bus", set_joint(2, "bus", "leg"), ["joint 3", "'bus'", "leg"]),
    ("bus as a list", set_joint(2, "bus", []), ["joint 3", "'bus'", "non-empty string"]),
    ("id as a string", set_joint(0, "id", "1"), ["'id'", "integer"]),
    ("offset as a string", set_joint(0, "zero_offset", "0"), ["'zero_offset'", "finite number"]),
    ("offset not finite", set_joint(0, "zero_offset", math.nan), ["'zero_offset'", "finite number"]),
    ("current limit above the register", set_joint(3, "current_limit", 4.0), ["'current_limit'", "XM430-W350"]),
    ("unknown joint key", set_joint(0, "gear", 2.0), ["joint 1", "unknown key 'gear'"]),
    ("unknown top-level key", lambda d: d.update(joints=[]), ["unknown key 'joints'"]),
    ("missing name", lambda d: d.pop("name"), ["'name'", "missing"]),
    ("unknown model", lambda d: d.update(model="robot9"), ["'model'", "robot9"]),
    ("no bus", lambda d: d.pop("bus"), ["'bus'"]),
    ("no joints", lambda d: d.pop("joint"), ["'joint'"]),
    ("bus kind", lambda d: d["bus"]["arm"].update(kind="rs485"), ["bus 'arm'", "'kind'", "rs485"]),
    ("baud rate", lambda d: d["bus"]["arm"].update(baud=12345), ["bus 'arm'", "'baud'", "12345"]),
    ("protocol 3.0", lambda d: d["bus"]["arm"].update(protocol=3.0), ["'protocol'", "2.0 or 1.0"]),
    ("a bus kind without a backend", bus_kind_ethercat, ["bus 'arm'", "'kind'", "'ethercat'", "dynamixel, loopback, can"]),
    ("a CAN bus with a serial bus's keys", bus_kind_can, ["bus 'arm'", "unknown key 'baud'", "bitrate, channel"]),
    ("swing time scale", lambda d: d["swing"].update(time_scale=-1.0), ["swing", "'time_scale'", "positive"]),
    ("absurd zero offset", set_joint(0, "zero_offset", 1e300), ["joint 1", "'zero_offset'", "1e+300", "one turn"]),
    ("absurd gear ratio", set_joint(1, "gear_ratio", 1e300), ["joint 2", "'gear_ratio'", "beyond 100", "gear stage"]),
    ("absurd torque constant", set_joint(2, "torque_constant", 1e300), ["'torque_constant'", "beyond 100", "N m per A"]),
    ("absurd current unit", set_joint(6, "current_unit", 1e300), ["joint 7", "'current_unit'", "beyond 1", "A per"]),
    ("absurd velocity limit", set_joint(3, "velocity_limit", 1e300), ["'velocity_limit'", "beyond 1000"]),
    ("absurd supply voltage", lambda d: d.update(supply={"voltage": 1e300}), ["supply", "'voltage'", "beyond 100"]),
    ("control period zero", lambda d: d.update(control={"period": 0.0}), ["control", "'period'", "from 0.1 to 10 ms"]),
    ("control period beyond the inverse dynamics'", lambda d: d.update(control={"period": 0.02}),
     ["control", "'period'", "10 ms"]),
    ("control period not dividing 10 ms", lambda d: d.update(control={"period": 0.003}),
     ["control", "'period'", "whole periods", "3 ms"]),
    ("control period as a string", lambda d: d.update(control={"period": "2 ms"}), ["'period'", "finite number"]),
    ("control period not finite", lambda d: d.update(control={"period": math.inf}), ["'period'", "finite number"]),
    ("control table without a period", lambda d: d.update(control={}), ["control", "'period'", "missing"]),
    ("unknown control key", lambda d: d.update(control={"rate": 500}), ["control", "unknown key 'rate'"]),
    ("a motor on a Dynamixel bus", lambda d: d["joint"][0].update(motor=d["joint"][0].pop("servo")),
     ["joint 1", "unknown key 'motor'"]),
]


def test_the_control_period_is_the_configurations():
    """1 ms unless `[control] period` says otherwise: the CAN builds run slower, as their buses need."""
    assert load_config("replica").control_period == 1e-3, "the default period"
    assert build(lambda d: d.update(control={"period": 0.0025})).control_period == 0.0025, "as written"
    assert load_config("replica_can").control_period == 0.0025, "seven Damiao motors on one CAN bus"
    assert load_config("replica_mixed").control_period == 0.002, "four on CAN, three on Dynamixel"


def test_a_can_joint_names_its_motor_in_either_word():
    """A CAN joint's device is its `motor` (the CAN backend's word) or, as on a serial bus, its `servo`;
    naming it twice is a mistake."""
    with open(CONFIGS_DIR / "replica_can.toml", "rb") as f:
        data = tomllib.load(f)
    assert all("motor" in j for j in data["joint"]), "replica_can names its motors `motor`"
    as_servo = copy.deepcopy(data)
    for joint in as_servo["joint"]:
        joint["servo"] = joint.pop("motor")
    a, b = config_from_dict(data, "a.toml"), config_from_dict(as_servo, "b.toml")
    assert [j.servo.name for j in a.joints] == [j.servo.name for j in b.joints] == \
        ["DM-J4340"] * 4 + ["DM-J4310"] * 3, "either word names the same motors"
    both = copy.deepcopy(data)
    both["joint"][2]["servo"] = "DM-J4340"
    with pytest.raises(ConfigError, match=r"joint 3 .*'servo' and 'motor' both name the device"):
        config_from_dict(both, "c.toml")
    unknown = copy.deepcopy(data)
    unknown["joint"][0]["motor"] = "DM-J9999"
    with pytest.raises(ConfigError, match=r"joint 1 .*'motor' 'DM-J9999' is not a known can motor"):
        config_from_dict(unknown, "d.toml")


@pytest.mark.parametrize("mutate, words", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_config_gives_one_line_naming_the_key(mutate, words):
    with pytest.raises(ConfigError) as err:
        build(mutate)
    message = str(err.value)
    assert "\n" not in message and message.startswith("test.toml: "), message
    for word in words:
        assert word in message, f"{word!r} not in: {message}"


def test_files(tmp_path):
    """A model path is relative to the config file; a missing file and bad TOML are ConfigErrors."""
    shutil.copy(servodyn.model.BUILTIN_DIR / "replica.toml", tmp_path / "arm.toml")
    text = (CONFIGS_DIR / "replica.toml").read_text().replace('model = "replica"', 'model = "arm.toml"')
    (tmp_path / "robot.toml").write_text(text)
    config = load_config(tmp_path / "robot.toml")
    assert config.model.name == "replica" and config.path == tmp_path / "robot.toml", \
        "model = 'arm.toml' found beside robot.toml"
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "missing.toml")
    (tmp_path / "bad.toml").write_text("name = \n")
    with pytest.raises(ConfigError, match="bad.toml: not valid TOML"):
        load_config(tmp_path / "bad.toml")


def test_replica_model_matches_human_arm():
    """Same dof names, axes, order and limits as human_arm, so its keyframes play; its shoulder,
    elbow and wrist axes meet at one point each, so the segment directions are human_arm's at
    every pose; 0.991 kg of moving arm (model description)."""
    replica, human = servodyn.load_model("replica"), servodyn.load_model("human_arm")
    assert replica.dof_names == human.dof_names, "same dof names in the same order"
    assert np.array_equal(replica.lower, human.lower) and np.array_equal(replica.upper, human.upper), \
        "same joint limits"
    axes = lambda m: {d.name: d.axis for b in m.bodies for d in b.dofs}
    for name, axis in axes(human).items():
        assert np.array_equal(axes(replica)[name], axis), name
    assert replica.total_mass == pytest.approx(0.991, abs=1e-3), "0.991 kg of moving arm (the model's description)"
    unit = lambda v: v / np.linalg.norm(v)
    for q in np.random.default_rng(7).uniform(human.lower, human.upper, size=(50, 7)):
        (_, p), (_, h) = replica.body_poses(q), human.body_poses(q)
        assert np.allclose(unit(p[3]), unit(h[1]), atol=1e-12), "upper arm direction"
        assert np.allclose(unit(p[5] - p[3]), unit(h[2] - h[1]), atol=1e-12), "forearm direction"


@pytest.mark.parametrize("servo_name", sorted(n for n, s in SERVOS.items() if s.current_control))
def test_every_servo_the_configuration_accepts_is_simulated(servo_name):
    """One data sheet per servo model, read by the configuration and by the simulator: a replica
    whose wrist servo is any accepted model loads, and the simulated servo answers a ping with
    that model's number (a configuration with an XH430-W350 used to load and then crash the
    simulator)."""
    from servodyn.hal.dynamixel import decode_frame, instructions as inst
    from servodyn.sim.robot import SimulatedRobot
    spec = SERVOS[servo_name]

    def wrist(data):
        joint = data["joint"][6]
        joint.update(servo=servo_name, current_limit=min(joint["current_limit"], spec.max_current),
                     torque_constant=spec.torque_constant)
    config = build(wrist)
    assert config.joints[6].servo is spec, "the configuration holds the catalogue's data sheet itself"
    arm = SimulatedRobot(config).port()
    reply = decode_frame(arm.handle(inst.ping(7).encode()))
    assert int.from_bytes(reply.params[:2], "little") == spec.model_number, \
        f"servo 7 answers as model {spec.model_number} ({servo_name})"


@pytest.mark.parametrize("make,words", [
    (lambda p: p.write_bytes(bytes(range(256)) * 4), ["robot.toml", "not a text file"]),
    (lambda p: p.mkdir(), ["robot.toml", "is a folder"]),
])
def test_unreadable_config_files_are_one_config_error_naming_the_file(tmp_path, make, words):
    make(tmp_path / "robot.toml")
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path / "robot.toml")
    assert "\n" not in str(err.value), str(err.value)
    for word in words:
        assert word in str(err.value), f"{word!r} not in: {err.value}"


def test_a_byte_order_mark_before_the_toml_is_dropped(tmp_path):
    """Some editors start a UTF-8 file with a byte-order mark; TOML has none, but the file is the
    same configuration: it loads as the one without."""
    plain = (CONFIGS_DIR / "replica.toml").read_bytes()
    marked = tmp_path / "marked.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.replace(b'model = "replica"', b'model = "replica"', 1))
    config = load_config(marked)
    assert config.name == "replica" and len(config.joints) == 7, "the marked file is the replica"


def test_a_gear_stage_scales_the_motors_armature():
    """A 2:1 stage after the horn turns the servo's rotor twice as fast as the joint: its armature
    at the joint is 4 x the motor's (XM540-W270: 0.14 kg m², parts.toml); the other dofs keep
    their motor's."""
    config = build(set_joint(0, "gear_ratio", 2.0))
    plain = load_config("replica").model.armature
    assert config.model.armature[0] == pytest.approx(4 * 0.14), "0.14 kg m² x 2²"
    assert np.array_equal(config.model.armature[1:], plain[1:]), "the other dofs unchanged"
    assert plain[0] == 0.14, "without a stage, the motor's own"


# --- the identified numbers: [[joint]] keys, [payload], [sim] -------------------------------------

@pytest.mark.parametrize("key, value, message", [
    ("friction_coulomb_nm", -0.1, "'friction_coulomb_nm' -0.1 is outside [0, 100]"),
    ("friction_viscous_nm_s", math.nan, "'friction_viscous_nm_s' must be a finite number, got nan"),
    ("torque_constant_scale", 5.0, "'torque_constant_scale' 5 is outside [0.25, 4]"),
    ("torque_constant_scale", "1.1", "'torque_constant_scale' must be a finite number, got '1.1'"),
    ("armature_kg_m2", 11.0, "'armature_kg_m2' 11 is outside [0, 10]"),
    ("thermal_resistance_k_w", 0.0, "'thermal_resistance_k_w' must be positive when thermal_time_constant_s is"),
    ("thermal_time_constant_s", math.inf, "'thermal_time_constant_s' must be a finite number, got inf"),
])
def test_identified_joint_keys_refused_in_one_line(key, value, message):
    """Each identified key out of its range (or not a finite number) stops the load with one line
    naming the file, the joint and the key."""
    with pytest.raises(ConfigError) as err:
        build(set_joint(3, key, value))
    text = str(err.value)
    assert "\n" not in text and text.startswith("test.toml: joint 4 (r_elbow_flexion): ") and message in text, text


def test_identified_joint_keys_are_used():
    """Accepted: the torque constant every conversion uses is the configured one x the scale
    (2.409 x 1.15 = 2.770 N m/A), friction and thermal constants as given, the armature replaces
    the model's at that dof (0.02 kg m², the other dofs keep theirs)."""
    def mutate(data):
        data["joint"][0].update(torque_constant_scale=1.15, friction_coulomb_nm=0.3, friction_viscous_nm_s=0.05,
                                armature_kg_m2=0.02, thermal_resistance_k_w=4.0, thermal_time_constant_s=100.0)
    config, nominal = build(mutate), load_config("replica")
    j = config.joints[0]
    assert j.torque_constant == pytest.approx(2.409 * 1.15, rel=1e-12), "effective Kt = configured x scale"
    assert j.configured_torque_constant == pytest.approx(2.409, rel=1e-12), "the file's torque_constant"
    assert (j.friction_coulomb, j.friction_viscous) == (0.3, 0.05), "friction as given"
    assert (j.thermal_resistance, j.thermal_time_constant) == (4.0, 100.0), "thermal constants as given"
    assert config.model.armature[0] == pytest.approx(0.02, abs=1e-15), "the armature key replaces the model's"
    assert np.allclose(config.model.armature[1:], nominal.model.armature[1:], atol=0), "other dofs keep theirs"
    assert config.joints[1].thermal_resistance == config.joints[1].servo.thermal_resistance > 0, \
        "a joint without thermal keys: its servo's data sheet estimate"


def test_payload_table_is_in_the_model():
    """[payload] 0.3 kg at the hand's centre of mass adds exactly 0.3 kg and, at rest, the
    gravity torque the model's own with_payload gives (1e-12 N m: the same operation)."""
    config = build(lambda d: d.update(payload={"mass_kg": 0.3}))
    nominal = load_config("replica").model
    assert config.model.total_mass - nominal.total_mass == pytest.approx(0.3, abs=1e-12), "0.3 kg more"
    q = (nominal.lower + nominal.upper) / 2
    zero = np.zeros(nominal.nv)
    expected = nominal.with_payload(0.3, "r_hand").inverse_dynamics(q, zero, zero)
    assert np.allclose(config.model.inverse_dynamics(q, zero, zero), expected, atol=1e-12), "gravity with the payload"
    assert config.payload.body == "r_hand", "the last body by default"


@pytest.mark.parametrize("table, message", [
    ({"mass_kg": -1.0}, "test.toml: payload: 'mass_kg' -1 is outside [0, 100]"),
    ({"mass_kg": 0.3, "body": "r_foot"}, "test.toml: payload: 'body' 'r_foot' is not a body of model 'replica'"),
    ({"mass_kg": 0.3, "com_m": [0.0, 0.1]}, "test.toml: payload: 'com_m' must be a list of three finite numbers"),
    ({"mass": 0.3}, "test.toml: payload: unknown key 'mass'"),
])
def test_payload_table_refused_in_one_line(table, message):
    with pytest.raises(ConfigError) as err:
        build(lambda d: d.update(payload=table))
    assert str(err.value).startswith(message) and "\n" not in str(err.value), str(err.value)


@pytest.mark.parametrize("table, message", [
    ({"mass_scale": 0.0}, "test.toml: sim: 'mass_scale' 0 is outside [0.1, 10]"),
    ({"joint": {"r_knee": {}}}, "test.toml: sim: 'joint' 'r_knee' is not a dof of model 'replica'"),
    ({"joint": {"r_elbow_flexion": {"friction_coulomb_nm": 0.3, "friction_static_nm": 0.2}}},
     "test.toml: sim: joint 'r_elbow_flexion': 'friction_static_nm' 0.2 N m is below friction_coulomb_nm (0.3)"),
    ({"joint": {"r_elbow_flexion": {"stiction": 1.0}}}, "test.toml: sim: joint 'r_elbow_flexion': unknown key 'stiction'"),
    ({"plant": "no_such_plant.toml"}, "test.toml: sim: 'plant'"),
    ({"payload": {"mass_kg": 200.0}}, "test.toml: sim: payload: 'mass_kg' 200 is outside [0, 100]"),
])
def test_sim_table_refused_in_one_line(table, message):
    with pytest.raises(ConfigError) as err:
        build(lambda d: d.update(sim=table))
    assert str(err.value).startswith(message) and "\n" not in str(err.value), str(err.value)


def test_sim_plant_file_and_its_table(tmp_path):
    """A plant file (relative to the configuration) gives the plant; [sim]'s own keys override it
    key by key. The plant starts from the model file, not from the configuration's identified
    [payload] and armature: patching the configuration leaves the simulated arm as it was."""
    (tmp_path / "plant.toml").write_text(
        "mass_scale = 1.1\n[payload]\nmass_kg = 0.3\n"
        "[joint.r_elbow_flexion]\nfriction_coulomb_nm = 0.2\ntorque_constant_scale = 1.2\n"
        "[joint.r_wrist_flexion]\narmature_kg_m2 = 0.03\n")
    data = copy.deepcopy(REPLICA)
    data["model"] = "replica"
    data["payload"] = {"mass_kg": 0.5}                       # the controller's belief
    data["joint"][3]["armature_kg_m2"] = 0.09
    data["sim"] = {"plant": "plant.toml", "joint": {"r_elbow_flexion": {"torque_constant_scale": 0.9}}}
    config = config_from_dict(data, origin="test.toml", base=tmp_path)
    nominal = load_config("replica").model
    plant = config.plant
    assert plant.model.total_mass == pytest.approx(1.1 * nominal.total_mass + 0.3, rel=1e-12), \
        "masses x 1.1, then the file's 0.3 kg payload (not the configuration's 0.5 kg)"
    elbow = plant.joints["r_elbow_flexion"]
    assert (elbow.friction_coulomb, elbow.torque_constant_scale) == (0.2, 0.9), "[sim]'s scale over the file's"
    assert plant.model.armature[5] == pytest.approx(0.03, abs=1e-15), "the file's armature"
    assert plant.model.armature[3] == pytest.approx(nominal.armature[3], abs=1e-15), \
        "the configuration's identified armature is not the plant's"
    assert plant.joints["r_shoulder_flexion"].has_friction is False, "a joint the plant does not name: its own"
