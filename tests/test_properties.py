"""Property-based tests (hypothesis) of what hostile input meets first: the Python Dynamixel codec
and reader, the simulated servo bus, the configuration, motion, trajectory and model loaders, and
the C core through the binding.

Each property says what every input must give: a packet or a PacketError; the same events however
the bytes are cut; an answer to a good request after any garbage; a valid object or one line of
error of the loader's own kind; finite dynamics or a FloatingPointError (the core's counted
non-finite warning, raised by the binding). The example counts are hypothesis' defaults or set
per test below; `pytest --hypothesis-show-statistics` prints what ran."""

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, assume, given, settings
from hypothesis import strategies as st

import servodyn
from servodyn.control.motion import builtin_motions, load_motion
from servodyn.control.trajectory import Trajectory, TrajectoryError, read_trajectory_csv
from servodyn.hal.config import RobotConfig, builtin_configs, config_from_dict, load_config
from servodyn.hal.dynamixel import (ALERT_BIT, BROADCAST_ID, BadFrame, Fault, InstructionPacket, PacketError,
                                    PacketReader, StatusPacket, decode_frame, stuff, unstuff)
from servodyn.hal.dynamixel import instructions as inst
from servodyn.hal.errors import ConfigError
from servodyn.model import ModelError, builtin_models, load_model
from servodyn.model.modelfile import model_from_dict
from servodyn.model.tree import Model
from servodyn.model.urdf_write import write_urdf
from servodyn.sim.dynamixel import Servo, DynamixelWire

# every property: no deadline (the machine is shared and slow); the tmp_path fixture is reused
# across examples on purpose (each example writes its own file name)
PROPERTY = settings(deadline=None, phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink],
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# an overflow numpy only warns about is a silently wrong number here
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

ids = st.one_of(st.integers(0, 0xFC), st.just(BROADCAST_ID))
# bytes rich in the codec's special values, so headers and stuffing turn up often
wire_bytes = st.lists(st.one_of(st.sampled_from([0xFF, 0xFD, 0x00, 0x55, 0xFE]), st.integers(0, 255)),
                      max_size=300).map(bytes)


def one_line(err: Exception) -> bool:
    text = str(err)
    return bool(text) and "\n" not in text


# --- the Python codec -----------------------------------------------------------------------------

@PROPERTY
@given(wire_bytes)
def test_decode_frame_gives_a_packet_or_a_packet_error(data):
    try:
        packet = decode_frame(data)
    except PacketError as err:
        assert one_line(err), f"decode_frame error is not one line: {err!r}"
        return
    again = decode_frame(packet.encode())
    assert again == packet, "a decoded frame encodes to a frame that decodes to the same packet"


@PROPERTY
@given(ids, st.integers(0, 255), st.binary(max_size=300))
def test_instruction_packets_round_trip(packet_id, instruction, params):
    assume(instruction != 0x55)
    packet = InstructionPacket(packet_id, instruction, params)
    frame = packet.encode()
    assert decode_frame(frame) == packet, "encode then decode gives the packet back"
    assert unstuff(stuff(params)) == params, "unstuff(stuff(x)) == x"


@PROPERTY
@given(st.integers(0, 0xFC), st.integers(0, 255), st.binary(max_size=300))
def test_status_packets_round_trip(packet_id, error, params):
    packet = StatusPacket(packet_id, error, params)
    assert decode_frame(packet.encode()) == packet, "a status packet decodes to itself"


@PROPERTY
@given(wire_bytes, st.lists(st.integers(1, 50), max_size=20))
def test_reader_events_do_not_depend_on_how_the_bytes_are_cut(data, cuts):
    whole = PacketReader(byte_timeout=None).feed(data)
    reader, pieces, at = PacketReader(byte_timeout=None), [], 0
    for cut in cuts:
        pieces += reader.feed(data[at:at + cut])
        at += cut
    pieces += reader.feed(data[at:])

    def garbage(events):
        return b"".join(e.raw for e in events if isinstance(e, BadFrame) and e.fault is Fault.GARBAGE)

    def rest(events):
        return [e for e in events if not (isinstance(e, BadFrame) and e.fault is Fault.GARBAGE)]
    # a run of garbage may be reported in pieces as it came; every other event is the same
    assert rest(pieces) == rest(whole), "the same packets and bad frames however the bytes are cut"
    assert garbage(pieces) == garbage(whole), "the same garbage bytes however the bytes are cut"


@PROPERTY
@given(wire_bytes, ids, st.integers(0, 255), st.binary(max_size=200), wire_bytes)
def test_a_good_frame_is_found_in_any_garbage(before, packet_id, instruction, params, after):
    assume(instruction != 0x55)
    packet = InstructionPacket(packet_id, instruction, params)
    # enough zeros after it that any frame a garbage header began has ended, with a bad CRC
    padding = bytes(PacketReader().max_frame + 16)
    events = PacketReader(byte_timeout=None).feed(before + packet.encode() + after + padding)
    assert packet in events, "a good frame inside garbage is read (after a bad frame the reader searches again)"
    assert all(isinstance(e, (BadFrame, InstructionPacket, StatusPacket)) for e in events), "events only"


# --- the simulated bus ----------------------------------------------------------------------------

# any bytes: garbage, or well-framed instruction packets with arbitrary instruction and params
hostile_piece = st.one_of(
    wire_bytes,
    st.builds(lambda i, n, p: InstructionPacket(i, n, p).encode(),
              st.sampled_from([1, 2, BROADCAST_ID, 9]),
              st.sampled_from([0x01, 0x02, 0x03, 0x04, 0x05, 0x08, 0x10, 0x82, 0x83, 0x8A, 0x92, 0x93,
                               0x9A, 0x00, 0x55, 0x77]),
              st.binary(max_size=40)),
)


@settings(PROPERTY, max_examples=150)
@given(st.lists(hostile_piece, max_size=8), st.lists(st.booleans(), max_size=8))
def test_simulated_bus_answers_a_good_request_after_any_bytes(pieces, gaps):
    bus = DynamixelWire([Servo(servo_id=1), Servo(servo_id=2)])
    now = 0.0
    for k, piece in enumerate(pieces):
        # nothing raises out of the bus; some pieces arrive together, some after a pause
        bus.handle(piece, now)
        now += 0.01 if (gaps[k] if k < len(gaps) else True) else 1e-5
    assume(len({s.id for s in bus.servos}) == len(bus.servos))   # a written ID may collide
    now += 0.01   # a pause longer than the servos' 1.5 ms byte timeout drops a partial frame
    for servo in bus.servos:
        reply = bus.handle(inst.ping(servo.id).encode(), now)
        status = decode_frame(reply)
        expected = StatusPacket(servo.id, ALERT_BIT if servo.alert else 0, servo.ping_reply())
        assert status == expected, f"servo {servo.id} answers a ping after hostile bytes with its model"
        now += 1e-3


# --- loaders --------------------------------------------------------------------------------------

hostile_value = st.one_of(
    st.integers(-2**70, 2**70), st.floats(), st.text(max_size=12), st.booleans(),
    st.sampled_from([0, -1, 1e300, -1e300, 1e-300, float("nan"), float("inf"), "", "auto", [], {}]),
    st.lists(st.floats(), max_size=4), st.dictionaries(st.text(max_size=5), st.integers(), max_size=3),
)


def paths(tree, prefix=()):
    """Every key path into nested dicts and lists."""
    out = [prefix] if prefix else []
    items = tree.items() if isinstance(tree, dict) else enumerate(tree) if isinstance(tree, list) else ()
    for key, value in items:
        out += paths(value, prefix + (key,))
    return out


def mutate(data, tree):
    """tree with one to three places replaced by a hostile value or removed."""
    tree = json.loads(json.dumps(tree))
    for _ in range(data.draw(st.integers(1, 3), label="changes")):
        where = data.draw(st.sampled_from(paths(tree)), label="path")
        parent = tree
        for key in where[:-1]:
            parent = parent[key]
        if data.draw(st.booleans(), label="remove") and isinstance(parent, dict):
            del parent[where[-1]]
        else:
            parent[where[-1]] = data.draw(hostile_value, label="value")
        if not paths(tree):
            break
    return tree


def toml_text(tree) -> str:
    """A small TOML writer for the mutated files: every table inline, one key a line."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return "{" + ", ".join(f"{json.dumps(k)} = {value(x)}" for k, x in v.items()) + "}"
    return "".join(f"{json.dumps(k)} = {value(v)}\n" for k, v in tree.items())


def _toml(path: Path) -> dict:
    return tomllib.loads(path.read_text())


MODEL = _toml(builtin_models()["human_arm"])
REPLICA = _toml(builtin_configs()["replica"])
FOREHAND = _toml(builtin_motions()["tennis_forehand"])
ARM = load_model("human_arm")


def test_the_toml_writer_gives_the_files_back():
    for tree in (MODEL, REPLICA, FOREHAND):
        assert tomllib.loads(toml_text(tree)) == tree, "toml_text writes what tomllib reads back"


@settings(PROPERTY, max_examples=150)
@given(st.data())
@pytest.mark.slow
def test_configuration_is_valid_or_one_config_error(data):
    tree = mutate(data, REPLICA)
    try:
        config = config_from_dict(tree, origin="hostile.toml", base=builtin_configs()["replica"].parent)
    except ConfigError as err:
        assert one_line(err), f"configuration error in more than one line: {err!r}"
        return
    assert isinstance(config, RobotConfig)
    for joint in config.joints:
        for name in ("zero_offset", "gear_ratio", "torque_constant", "current_unit"):
            value = getattr(joint, name, 0.0)
            assert math.isfinite(value), f"accepted configuration has {name} = {value}"


@settings(PROPERTY, max_examples=150)
@given(st.data())
def test_model_file_is_valid_or_one_model_error_and_its_dynamics_are_finite_or_raise(data):
    tree = mutate(data, MODEL)
    try:
        model = model_from_dict(tree, origin="hostile.toml")
    except ModelError as err:
        assert one_line(err), f"model error in more than one line: {err!r}"
        return
    assert isinstance(model, Model)
    check_core(model, data)


@pytest.mark.parametrize("key, value", [("pos", [1.0669111456987818e+293, 0.0, 0.0]),
                                        ("radius", 3.2711701842277253e+154)])
def test_a_solid_too_large_for_its_inertia_is_one_model_error(key, value):
    """Found by the property above: a solid's position or size that is a finite number on its own
    but overflows the body's inertia (squared) raised numpy's overflow warning, not a ModelError."""
    import copy
    tree = copy.deepcopy(MODEL)
    solids = [s for body in tree["body"] for s in (lambda x: x if isinstance(x, list) else [x])(body.get("solid", []))]
    next(s for s in solids if "radius" in s)[key] = value
    with pytest.raises(ModelError, match="not finite") as refused:
        model_from_dict(tree, origin="hostile.toml")
    assert one_line(refused.value)


@settings(PROPERTY, max_examples=100)
@given(st.data())
def test_motion_file_is_valid_or_one_trajectory_error(tmp_path, data):
    path = tmp_path / "hostile_motion.toml"
    path.write_text(toml_text(mutate(data, FOREHAND)))
    try:
        motion = load_motion(path, ARM)
    except TrajectoryError as err:
        assert one_line(err), f"motion error in more than one line: {err!r}"
        return
    assert np.all(np.isfinite(motion.q)) and np.all(np.diff(motion.t) > 0), "a valid motion is finite, t increasing"


csv_cell = st.one_of(st.floats().map(repr), st.integers().map(str), st.text(max_size=6),
                     st.sampled_from(["", "nan", "inf", "1e308", "-1e308", "0_5", "1,5", " 1", "\ufeff0"]))


@settings(PROPERTY, max_examples=150)
@given(st.lists(st.lists(csv_cell, min_size=1, max_size=9), max_size=8), st.booleans())
def test_trajectory_csv_is_valid_or_one_trajectory_error(tmp_path, rows, header):
    names = ARM.dof_names
    text = "\n".join(",".join(r) for r in rows)
    if header:
        text = ",".join(("t",) + tuple(names)) + "\n" + text
    path = tmp_path / "hostile.csv"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        traj = read_trajectory_csv(path, names)
    except TrajectoryError as err:
        assert one_line(err), f"CSV error in more than one line: {err!r}"
        return
    assert isinstance(traj, Trajectory)
    assert np.all(np.isfinite(traj.q)) and np.all(np.diff(traj.t) > 0), "a valid trajectory is finite"


@settings(PROPERTY, max_examples=60)
@given(st.binary(max_size=400), st.sampled_from(["model.toml", "model.urdf", "config.toml", "motion.toml"]))
def test_any_bytes_in_a_file_are_one_line_of_error(tmp_path, data, name):
    path = tmp_path / name
    path.write_bytes(data)
    loader, error = {"model": (load_model, ModelError), "config": (load_config, ConfigError),
                     "motion": (lambda p: load_motion(p, ARM), TrajectoryError)}[name.split(".")[0]]
    try:
        loader(path)
    except error as err:
        assert one_line(err), f"{name}: error in more than one line: {err!r}"


@settings(PROPERTY, max_examples=80)
@given(st.data())
def test_urdf_is_valid_or_one_model_error(tmp_path, data):
    source = tmp_path / "arm.urdf"
    if not source.exists():
        write_urdf(ARM, source)
    text = source.read_text()
    # replace a few attribute values or element names with hostile text
    import re
    spots = [m.span(1) for m in re.finditer(r'="([^"]*)"', text)] + [m.span(1) for m in re.finditer(r"<(\w+)", text)]
    for _ in range(data.draw(st.integers(1, 3), label="changes")):
        start, end = data.draw(st.sampled_from(spots), label="spot")
        new = data.draw(st.one_of(st.sampled_from(["nan", "inf", "-1", "0", "1e308", "", "a b c", "joint",
                                                   "link", "1 2", "1 2 3 4"]),
                                  st.floats().map(repr), st.text("abc012 .-", max_size=8)), label="value")
        text = text[:start] + new + text[end:]
        spots = [m.span(1) for m in re.finditer(r'="([^"]*)"', text)]
        if not spots:
            break
    path = tmp_path / "hostile.urdf"
    path.write_text(text)
    try:
        model = load_model(path)
    except ModelError as err:
        assert one_line(err), f"URDF error in more than one line: {err!r}"
        return
    check_core(model, data)


# --- the core through the binding -----------------------------------------------------------------

magnitudes = st.one_of(st.floats(-10, 10), st.floats(-1e200, 1e200), st.sampled_from([1e154, -1e154, 1e308, 0.0]))


def check_core(model: Model, data) -> None:
    """Inverse and direct dynamics and one RK4 step: finite, or FloatingPointError (the core
    zeroed a non-finite value and counted it; the binding raises) — never a NaN or an infinity."""
    n = model.nv if hasattr(model, "nv") else len(model.dof_names)
    nq = model.nq if hasattr(model, "nq") else n
    q = np.array(data.draw(st.lists(magnitudes, min_size=nq, max_size=nq), label="q"))
    qd = np.array(data.draw(st.lists(magnitudes, min_size=n, max_size=n), label="qd"))
    qdd = np.array(data.draw(st.lists(magnitudes, min_size=n, max_size=n), label="qdd"))
    for name, call in (("inverse_dynamics", lambda: model.inverse_dynamics(q, qd, qdd)),
                       ("forward_dynamics", lambda: model.forward_dynamics(q, qd, qdd)),
                       ("step", lambda: np.concatenate(model.step(q, qd, qdd, 1e-3)))):
        try:
            out = call()
        except FloatingPointError as err:
            assert one_line(err), f"{name}: the non-finite result's error is not one line"
            continue
        assert np.all(np.isfinite(out)), f"{name} gave a non-finite value without raising: {out}"


@settings(PROPERTY, max_examples=150)
@given(st.sampled_from(sorted(builtin_models())), st.data())
@pytest.mark.slow
def test_core_is_finite_or_raises_on_any_state(name, data):
    check_core(servodyn.load_model(name), data)
