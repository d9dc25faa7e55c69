"""The host link's messages (docs/host-link.md), as the firmware's (firmware/link/link.c) byte for byte.

Each message is a layout, a tuple of (field, kind, count), from which its class, its packing and
its unpacking are made: one table a message. Little-endian; `f32` fields are IEEE float32 whatever
the controller's precision; telemetry's are int16 fixed point (`fix_*`, LSBs below), the servo
units (`i16`) exact. TELEMETRY and KNOTS end in a list (joints, knots) after their fixed header.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, make_dataclass

from .frame import MAX_PAYLOAD, OVERHEAD, LinkError

# message types: requests (host -> controller, reliable) below 0x80, the controller's above
HELLO, LOAD_ROBOT, LOAD_BODY, LOAD_JOINT, COMMIT, KNOTS, COMMAND = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
HELLO_REPLY, RESULT, TELEMETRY = 0x81, 0x82, 0x83

# telemetry's fixed point: value = code * LSB; code -32768 is NaN (or not measured), codes clamp at +-32767
LSB = {"fix_q": 2.0 ** -12,        # rad: +-8 rad
       "fix_qd": 2.0 ** -9,        # rad/s: +-64 rad/s
       "fix_tau": 2.0 ** -9}       # N m: +-64 N m
NAN_CODE = -32768
TM_LIMITED, TM_SATURATED, TM_CONTACT, TM_STARVED, TM_DONE, TM_HOST_SILENT = 1, 2, 4, 8, 16, 32
KNOT_GAINS, KNOT_LAST = 1, 2
MAX_TELEMETRY_JOINT = 16

_FORMAT = {"u8": "B", "i8": "b", "u16": "H", "i16": "h", "u32": "I", "f32": "f", "fix_q": "h",
           "fix_qd": "h", "fix_tau": "h", "str12": "12s"}
JOINT_REALS = ("armature", "direction", "zero_offset", "gear_ratio", "rad_per_tick", "radps_per_unit",
               "effort_per_unit", "nm_per_effort", "effort_limit", "q_min", "q_max", "qd_max", "tau_max",
               "friction_coulomb", "friction_viscous", "kp", "kd", "error_lowpass", "following_error",
               "observer_gain", "observer_lowpass", "contact_threshold")

LAYOUTS = {
    HELLO: ("Hello", (("nonce", "u16", 1),)),
    HELLO_REPLY: ("HelloReply", (
        ("nonce", "u16", 1), ("link_version", "u8", 1), ("fw_major", "u8", 1), ("fw_minor", "u8", 1),
        ("fw_patch", "u8", 1), ("board", "str12", 1), ("real_bytes", "u8", 1), ("max_body", "u8", 1),
        ("max_dof", "u8", 1), ("knot_slots", "u16", 1), ("max_payload", "u8", 1), ("window", "u8", 1),
        ("buses", "u8", 1), ("state", "u8", 1))),
    LOAD_ROBOT: ("RobotHead", (
        ("nbody", "u8", 1), ("ndof", "u8", 1), ("free_root", "u8", 1), ("mode", "u8", 1), ("contact", "u8", 1),
        ("contact_debounce", "u8", 1), ("reaction", "u8", 1), ("update_ticks", "u16", 1),
        ("host_timeout_ms", "u16", 1), ("period_us", "u32", 1), ("gravity", "f32", 3),
        ("friction_speed", "f32", 1), ("stall_time", "f32", 1), ("stall_speed", "f32", 1),
        ("stall_share", "f32", 1), ("contact_arm_time", "f32", 1), ("reaction_time", "f32", 1))),
    LOAD_BODY: ("Body", (
        ("index", "u8", 1), ("parent", "i8", 1), ("dofnum", "u8", 1), ("ball", "u8", 1), ("pos", "f32", 3),
        ("rot", "f32", 9), ("mass", "f32", 1), ("com", "f32", 3), ("inertia", "f32", 6))),
    LOAD_JOINT: ("Joint", (
        ("index", "u8", 1), ("bus", "u8", 1), ("id", "u8", 1), ("model_number", "u16", 1), ("dof_rot", "f32", 9),
        *((name, "f32", 1) for name in JOINT_REALS), ("dialect", "u8", 1), ("reply_id", "u16", 1),
        ("mit_range", "f32", 5))),
    COMMIT: ("Commit", ()),
    COMMAND: ("Command", (("command", "u8", 1), ("arg", "u32", 1))),
    RESULT: ("Result", (
        ("seq", "u8", 1), ("type", "u8", 1), ("stage", "u8", 1), ("code", "i8", 1), ("index", "i16", 1),
        ("credits", "u16", 1))),
    TELEMETRY: ("Telemetry", (
        ("tick", "u32", 1), ("work_us", "u16", 1), ("missed", "u16", 1), ("state", "u8", 1), ("fault", "u8", 1),
        ("fault_joint", "u8", 1), ("flags", "u8", 1), ("credits", "u16", 1), ("njoint", "u8", 1))),
    KNOTS: ("Knots", (("first", "u32", 1), ("ndof", "u8", 1), ("count", "u8", 1), ("flags", "u8", 1))),
}
JOINT_TELEMETRY = (("q", "fix_q", 1), ("qd", "fix_qd", 1), ("q_d", "fix_q", 1), ("tau", "fix_tau", 1),
                   ("effort", "i16", 1), ("command", "i16", 1), ("residual", "fix_tau", 1))

# the codes of hal/link (link.h's enums)
COMMANDS = {"keepalive": 0, "home": 1, "play": 2, "hold": 3, "stop": 4, "torque_off": 5, "clear_fault": 6,
            "telemetry": 7}
BUSES = {"none": 0, "dynamixel": 1, "can": 2}
DIALECTS = ("none", "mit", "damiao", "cubemars")      # a CAN motor's (hal/can/dialects.py); none: a Dynamixel servo
STATES = ("idle", "loaded", "homing", "playing", "holding", "torque_off", "fault")
REACTIONS = ("hold", "float", "retract", "torque_off")    # hal/safety.py's REACTIONS, in this order
STAGES = ("link", "model", "control", "observer", "servo")
LINK_CODES = {0: "done", -1: "an unknown request type", -2: "a payload of the wrong length",
              -3: "not now (the controller's state refuses it)", -4: "more knots than the free slots",
              -5: "out of order", -6: "over the controller's compiled sizes", -7: "a body was not sent",
              -8: "a knot not next in the motion, or not after the last one", -9: "an unknown command",
              -10: "a joint was not sent", -11: "a frame of another protocol version"}
SERVO_CODES = {-1: "a bus the controller has not (or none for an actuated joint)", -2: "direction not +1 or -1",
               -3: "a unit scale zero or not finite", -4: "a range or limit that is empty or not positive",
               -5: "a safety value not positive (following error, contact threshold, the table)",
               -6: "two joints on one servo",
               -7: "a CAN motor's dialect, reply id or MIT ranges (the codec's 1e-6 .. 1e6)"}
E_ORDER = -5


def _size(layout) -> int:
    return struct.calcsize("<" + "".join(f"{count}{_FORMAT[kind]}" if kind != "str12" else "12s"
                                         for _, kind, count in layout))


def _fix(value: float, lsb: float) -> tuple[int, bool]:
    """(code, clamped): value / LSB rounded half away from zero into +-32767; NaN as NAN_CODE."""
    if math.isnan(value):
        return NAN_CODE, False
    x = value / lsb
    if x >= 32767 or x <= -32767:
        return (32767 if x > 0 else -32767), abs(x) > 32767
    return (math.floor(x + 0.5) if x >= 0 else -math.floor(0.5 - x)), False


def _unfix(code: int, lsb: float) -> float:
    return math.nan if code == NAN_CODE else code * lsb


def _f32(value: float, name: str) -> float:
    try:
        struct.pack("<f", value)
    except OverflowError:
        raise LinkError(f"host link: {name} = {value!r} is beyond float32") from None
    return value


def _flatten(message, layout, saturated: list) -> list:
    out = []
    for name, kind, count in layout:
        value = getattr(message, name)
        values = [value] if count == 1 else list(value)
        if len(values) != count:
            raise LinkError(f"host link: {name} needs {count} numbers, got {len(values)}")
        for v in values:
            if kind in LSB:
                code, clamped = _fix(float(v), LSB[kind])
                saturated[0] |= clamped
                out.append(code)
            elif kind == "f32":
                out.append(_f32(float(v), name))
            elif kind == "str12":
                out.append(str(v).encode("ascii")[:12])
            else:
                out.append(int(v))
    return out


def _fold(values, layout) -> dict:
    out, at = {}, 0
    for name, kind, count in layout:
        chunk = values[at:at + count]
        at += count
        if kind in LSB:
            chunk = [_unfix(v, LSB[kind]) for v in chunk]
        elif kind == "str12":
            chunk = [chunk[0].rstrip(b"\x00").decode("ascii", "replace")]
        out[name] = chunk[0] if count == 1 else tuple(chunk)
    return out


def _struct(layout) -> struct.Struct:
    return struct.Struct("<" + "".join(_FORMAT[kind] * count if kind != "str12" else "12s"
                                       for _, kind, count in layout))


def _class(name, layout, extra=()):
    fields = [(n, float if kind in LSB or kind == "f32" else int, field(default=0)) for n, kind, count in layout
              if count == 1 and kind != "str12"]
    fields += [(n, tuple, field(default=(0.0,) * count)) for n, kind, count in layout if count > 1]
    fields += [(n, str, field(default="")) for n, kind, _ in layout if kind == "str12"]
    return make_dataclass(name, [*fields, *extra], frozen=True)


CLASSES = {t: _class(name, layout) for t, (name, layout) in LAYOUTS.items() if t not in (TELEMETRY, KNOTS)}
JointTelemetry = _class("JointTelemetry", JOINT_TELEMETRY)
Telemetry = _class("Telemetry", LAYOUTS[TELEMETRY][1], (("joints", tuple, field(default=())),))
Knots = _class("Knots", LAYOUTS[KNOTS][1], (("knots", tuple, field(default=())),))
CLASSES[TELEMETRY], CLASSES[KNOTS] = Telemetry, Knots
TYPES = {cls: t for t, cls in CLASSES.items()}
SIZES = {t: _size(layout) for t, (_, layout) in LAYOUTS.items()}     # fixed part of each payload
_STRUCTS = {t: _struct(layout) for t, (_, layout) in LAYOUTS.items()}
_JOINT_TM = _struct(JOINT_TELEMETRY)
(Hello, HelloReply, RobotHead, Body, Joint, Commit, Command, Result) = (
    CLASSES[t] for t in (HELLO, HELLO_REPLY, LOAD_ROBOT, LOAD_BODY, LOAD_JOINT, COMMIT, COMMAND, RESULT))


@dataclass(frozen=True)
class Knot:
    """One knot of a streamed motion: time (µs from its start), the state there, and the gains."""
    t_us: int
    q: tuple
    qd: tuple
    qdd: tuple
    kp: tuple | None = None
    kd: tuple | None = None


def knot_bytes(ndof: int, gains: bool) -> int:
    return 4 + 4 * ndof * (5 if gains else 3)


def knots(first: int, items, last: bool = False) -> Knots:
    """A KNOTS message of `items` (Knot), with gains when the first has them."""
    items = tuple(items)
    if not items:
        raise LinkError("host link: a KNOTS message needs at least one knot")
    gains = items[0].kp is not None
    return Knots(first=first, ndof=len(items[0].q), count=len(items),
                 flags=(KNOT_GAINS if gains else 0) | (KNOT_LAST if last else 0), knots=items)


def pack(message) -> tuple[int, bytes]:
    """(type, payload) of a message."""
    t = TYPES.get(type(message))
    if t is None:
        raise LinkError(f"host link: {type(message).__name__} is not a message")
    saturated = [False]
    if t == TELEMETRY:
        joints = message.joints
        if len(joints) > MAX_TELEMETRY_JOINT:
            raise LinkError(f"host link: {len(joints)} joints are over a telemetry frame's {MAX_TELEMETRY_JOINT}")
        body = b"".join(_JOINT_TM.pack(*_flatten(j, JOINT_TELEMETRY, saturated)) for j in joints)
        head = _flatten(message, LAYOUTS[t][1], saturated)
        names = [name for name, _, _ in LAYOUTS[t][1]]
        head[names.index("njoint")] = len(joints)
        if saturated[0]:
            head[names.index("flags")] |= TM_SATURATED
        return t, _STRUCTS[t].pack(*head) + body
    if t == KNOTS:
        gains = bool(message.flags & KNOT_GAINS)
        ndof = message.ndof
        layout = (("t_us", "u32", 1), ("q", "f32", ndof), ("qd", "f32", ndof), ("qdd", "f32", ndof),
                  *((("kp", "f32", ndof), ("kd", "f32", ndof)) if gains else ()))
        knot_struct = _struct(layout)
        body = b"".join(knot_struct.pack(*_flatten(k, layout, saturated)) for k in message.knots)
        payload = _STRUCTS[t].pack(message.first, ndof, len(message.knots), message.flags) + body
    else:
        payload = _STRUCTS[t].pack(*_flatten(message, LAYOUTS[t][1], saturated))
    if len(payload) > MAX_PAYLOAD:
        raise LinkError(f"host link: a {LAYOUTS[t][0]} of {len(payload)} bytes is over a frame's {MAX_PAYLOAD}")
    return t, payload


def unpack(type_: int, payload: bytes):
    """The message of a payload; LinkError for an unknown type or a wrong length."""
    if type_ not in LAYOUTS:
        raise LinkError(f"host link: unknown message type 0x{type_:02X}")
    name, layout = LAYOUTS[type_]
    size = SIZES[type_]
    if len(payload) < size:
        raise LinkError(f"host link: a {name} of {len(payload)} bytes, under its {size}")
    head = _fold(_STRUCTS[type_].unpack_from(payload), layout)
    rest = payload[size:]
    if type_ == TELEMETRY:
        n = head["njoint"]
        if n > MAX_TELEMETRY_JOINT or len(rest) != n * _JOINT_TM.size:
            raise LinkError(f"host link: a Telemetry of {len(payload)} bytes for {n} joints")
        joints = tuple(JointTelemetry(**_fold(_JOINT_TM.unpack_from(rest, k * _JOINT_TM.size), JOINT_TELEMETRY))
                       for k in range(n))
        return Telemetry(**head, joints=joints)
    if type_ == KNOTS:
        ndof, count, flags = head["ndof"], head["count"], head["flags"]
        gains = bool(flags & KNOT_GAINS)
        if not ndof or not count or flags & ~(KNOT_GAINS | KNOT_LAST) or len(rest) != count * knot_bytes(ndof, gains):
            raise LinkError(f"host link: a Knots of {len(payload)} bytes for {count} knots of {ndof} dofs")
        layout = (("t_us", "u32", 1), ("q", "f32", ndof), ("qd", "f32", ndof), ("qdd", "f32", ndof),
                  *((("kp", "f32", ndof), ("kd", "f32", ndof)) if gains else ()))
        step = knot_bytes(ndof, gains)
        items = tuple(Knot(**_fold(_struct(layout).unpack_from(rest, k * step), layout)) for k in range(count))
        return Knots(**head, knots=items)
    if rest:
        raise LinkError(f"host link: a {name} of {len(payload)} bytes, over its {size}")
    return CLASSES[type_](**head)


def reason(result) -> str:
    """A RESULT's refusal in words: the stage, its code and what it names."""
    stage = STAGES[result.stage] if result.stage < len(STAGES) else f"stage {result.stage}"
    words = {"link": LINK_CODES, "servo": SERVO_CODES}.get(stage, {}).get(result.code)
    what = f"{stage} check code {result.code}" + (f" ({words})" if words else "")
    named = {"model": "body", "servo": "joint", "link": "item"}.get(stage, "item")
    return what + (f", {named} {result.index}" if result.index >= 0 else "")


def telemetry_wire_bytes(njoint: int) -> int:
    """Bytes on the wire of one tick's telemetry of njoint joints: payload and frame."""
    return SIZES[TELEMETRY] + njoint * _JOINT_TM.size + OVERHEAD


def line_share(njoint: int, rate_hz: float, baud: float, bits_per_byte: int = 10) -> float:
    """The share of a UART's line (8N1: 10 bits a byte) that telemetry at rate_hz takes."""
    return telemetry_wire_bytes(njoint) * bits_per_byte * rate_hz / baud
