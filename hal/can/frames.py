"""The frame codec of MIT-style CAN motors, byte for byte the C codec's (c/canmotor.c, which the
firmware uses; tests/test_can_frames.py compares the two over every range boundary and random values).

A command is one 8-byte frame of big-endian bit fields, p 16 bits, v, kp, kd and t 12 bits each:

    byte  0        1       2        3                  4        5        6                  7
          p[15:8]  p[7:0]  v[11:4]  v[3:0]<<4|kp[11:8] kp[7:0]  kd[11:4] kd[3:0]<<4|t[11:8] t[7:0]

Each value is clamped into its range, then x -> int((x - min) * (2^bits - 1) / (max - min)) as
the mini-cheetah firmware's float_to_uint (which does not clamp: a value outside would wrap).
Decoding u -> u * (max - min) / (2^bits - 1) + min: with a symmetric range ±X, 0 encodes to
2^(bits-1) - 1 and decodes to -X / (2^bits - 1), so a zero torque sent is -TMAX/4095, not 0.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from ..errors import ProtocolError

# the special frames (FF x7, code) to a motor's command id
ENTER, EXIT, SET_ZERO, CLEAR_ERROR = 0xFC, 0xFD, 0xFE, 0xFB
SPECIALS = {ENTER: "enter motor mode", EXIT: "exit motor mode", SET_ZERO: "set zero", CLEAR_ERROR: "clear error"}

# Damiao registers, on one id
REGISTER_ID = 0x7FF
REG_READ, REG_WRITE, REG_STORE, REG_REFRESH = 0x33, 0x55, 0xAA, 0xCC

# every range end within these (canmotor.h's CM_RANGE_MIN, CM_RANGE_MAX): wide enough for any motor,
# narrow enough that no step of the conversions overflows (a span near the float maximum made
# (x - min) * 65535 / span inf / inf, NaN) or sinks into denormals
RANGE_MIN, RANGE_MAX = 1e-6, 1e6

# bits of Command.clamped: which field was clamped into its range
CLAMP_P, CLAMP_V, CLAMP_KP, CLAMP_KD, CLAMP_T = 1, 2, 4, 8, 16


class FrameError(ProtocolError):
    """A CAN frame that is not what its kind says (length, values, layout)."""


@dataclass(frozen=True)
class Ranges:
    """An MIT frame's ranges: p in ±p_max, v in ±v_max, t in ±t_max, kp in [0, kp_max], kd in [0, kd_max]."""
    p_max: float
    v_max: float
    t_max: float
    kp_max: float = 500.0
    kd_max: float = 5.0

    def __post_init__(self):
        for name in ("p_max", "v_max", "t_max", "kp_max", "kd_max"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and RANGE_MIN <= value <= RANGE_MAX):
                raise FrameError(f"range {name} must be a number from {RANGE_MIN:g} to {RANGE_MAX:g}, got {value!r}")

    @property
    def torque_step(self) -> float:
        """N m between two torque codes (12 bits over ±t_max)."""
        return 2 * self.t_max / 4095


@dataclass(frozen=True)
class Command:
    p: float
    v: float
    kp: float
    kd: float
    t: float


@dataclass(frozen=True)
class Reply:
    """A motor's answer. status: Damiao's nibble, CubeMars' error code, 0 on mit; temperature:
    Damiao MOS / CubeMars motor °C; temperature2: Damiao coil °C; voltage: mit's 7th byte."""
    id: int
    p: float
    v: float
    t: float
    status: int = 0
    temperature: int = 0
    temperature2: int = 0
    voltage: int = 0


@dataclass(frozen=True)
class Register:
    can_id: int
    cmd: int
    rid: int
    value: int = 0          # bytes 4..7 little-endian (a float register's IEEE bits)

    @property
    def as_float(self) -> float:
        return struct.unpack("<f", struct.pack("<I", self.value))[0]


def to_uint(x: float, lo: float, hi: float, bits: int) -> int:
    """float_to_uint on a value already inside [lo, hi] (below: 0, above: the top code)."""
    top = (1 << bits) - 1
    if not x > lo:
        return 0
    if x >= hi:
        return top
    return min(top, int((x - lo) * float(top) / (hi - lo)))


def to_float(u: int, lo: float, hi: float, bits: int) -> float:
    return float(u) * (hi - lo) / float((1 << bits) - 1) + lo


def _clamp(x: float, lo: float, hi: float) -> tuple[float, bool]:
    if x < lo:
        return lo, True
    if x > hi:
        return hi, True
    return x, False


def _finite(*values) -> None:
    if not all(math.isfinite(v) for v in values):
        raise FrameError(f"a CAN frame cannot carry a non-finite value: {values}")


def pack_command(r: Ranges, p: float, v: float, kp: float, kd: float, t: float) -> tuple[bytes, int]:
    """The 8 command bytes and the CLAMP_* bits of the fields clamped into their ranges."""
    _finite(p, v, kp, kd, t)
    fields = ((p, -r.p_max, r.p_max, 16), (v, -r.v_max, r.v_max, 12), (kp, 0.0, r.kp_max, 12),
              (kd, 0.0, r.kd_max, 12), (t, -r.t_max, r.t_max, 12))
    codes, clamped = [], 0
    for k, (x, lo, hi, bits) in enumerate(fields):
        x, hit = _clamp(float(x), lo, hi)
        codes.append(to_uint(x, lo, hi, bits))
        clamped |= hit << k
    pu, vu, kpu, kdu, tu = codes
    return bytes((pu >> 8, pu & 0xFF, vu >> 4, ((vu & 0xF) << 4) | (kpu >> 8), kpu & 0xFF,
                  kdu >> 4, ((kdu & 0xF) << 4) | (tu >> 8), tu & 0xFF)), clamped


def unpack_command(r: Ranges, data: bytes) -> Command:
    if len(data) != 8:
        raise FrameError(f"an MIT command has 8 bytes, got {len(data)}")
    if special(data):
        raise FrameError(f"a special frame ({SPECIALS[data[7]]}), not a command")
    return Command(p=to_float((data[0] << 8) | data[1], -r.p_max, r.p_max, 16),
                   v=to_float((data[2] << 4) | (data[3] >> 4), -r.v_max, r.v_max, 12),
                   kp=to_float(((data[3] & 0xF) << 8) | data[4], 0.0, r.kp_max, 12),
                   kd=to_float((data[5] << 4) | (data[6] >> 4), 0.0, r.kd_max, 12),
                   t=to_float(((data[6] & 0xF) << 8) | data[7], -r.t_max, r.t_max, 12))


def pack_special(code: int) -> bytes:
    if code not in SPECIALS:
        raise FrameError(f"0x{code:02X} is not a special frame ({', '.join(f'0x{c:02X}' for c in SPECIALS)})")
    return b"\xff" * 7 + bytes((code,))


def special(data: bytes) -> int:
    """The special frame's code, or 0 if the bytes are not one."""
    if len(data) == 8 and data[:7] == b"\xff" * 7 and data[7] in SPECIALS:
        return data[7]
    return 0


def _state_bytes(r: Ranges, p: float, v: float, t: float) -> bytes:
    _finite(p, v, t)
    pu = to_uint(_clamp(p, -r.p_max, r.p_max)[0], -r.p_max, r.p_max, 16)
    vu = to_uint(_clamp(v, -r.v_max, r.v_max)[0], -r.v_max, r.v_max, 12)
    tu = to_uint(_clamp(t, -r.t_max, r.t_max)[0], -r.t_max, r.t_max, 12)
    return bytes((pu >> 8, pu & 0xFF, vu >> 4, ((vu & 0xF) << 4) | (tu >> 8), tu & 0xFF))


def _state(r: Ranges, data: bytes) -> tuple[float, float, float]:
    return (to_float((data[1] << 8) | data[2], -r.p_max, r.p_max, 16),
            to_float((data[3] << 4) | (data[4] >> 4), -r.v_max, r.v_max, 12),
            to_float(((data[4] & 0xF) << 8) | data[5], -r.t_max, r.t_max, 12))


def pack_mit_reply(r: Ranges, y: Reply) -> bytes:
    return bytes((y.id & 0xFF,)) + _state_bytes(r, y.p, y.v, y.t)


def unpack_mit_reply(r: Ranges, data: bytes) -> Reply:
    if len(data) not in (6, 7):
        raise FrameError(f"an MIT reply has 6 or 7 bytes, got {len(data)}")
    return Reply(data[0], *_state(r, data), voltage=data[6] if len(data) == 7 else 0)


def pack_damiao_feedback(r: Ranges, y: Reply) -> bytes:
    return (bytes((((y.status & 0xF) << 4) | (y.id & 0xF),)) + _state_bytes(r, y.p, y.v, y.t)
            + bytes((y.temperature & 0xFF, y.temperature2 & 0xFF)))


def _int8(byte: int) -> int:
    return byte - 256 if byte > 127 else byte


def unpack_damiao_feedback(r: Ranges, data: bytes) -> Reply:
    if len(data) != 8:
        raise FrameError(f"a Damiao feedback frame has 8 bytes, got {len(data)}")
    return Reply(data[0] & 0xF, *_state(r, data), status=data[0] >> 4, temperature=_int8(data[6]),
                 temperature2=_int8(data[7]))


def pack_cubemars_reply(r: Ranges, y: Reply) -> bytes:
    return bytes((y.id & 0xFF,)) + _state_bytes(r, y.p, y.v, y.t) + bytes((y.temperature & 0xFF, y.status & 0xFF))


def unpack_cubemars_reply(r: Ranges, data: bytes) -> Reply:
    if len(data) != 8:
        raise FrameError(f"a CubeMars reply has 8 bytes, got {len(data)}")
    return Reply(data[0], *_state(r, data), status=data[7], temperature=_int8(data[6]))


def pack_register(g: Register) -> bytes:
    return struct.pack("<HBBI", g.can_id, g.cmd, g.rid, g.value)


def unpack_register(data: bytes) -> Register:
    if len(data) not in (4, 8):
        raise FrameError(f"a Damiao register frame has 8 bytes (4 for a refresh), got {len(data)}")
    if data[2] not in (REG_READ, REG_WRITE, REG_STORE, REG_REFRESH):
        raise FrameError(f"0x{data[2]:02X} is not a register command (0x33 read, 0x55 write, 0xAA store, 0xCC refresh)")
    value = int.from_bytes(data[4:8], "little") if len(data) == 8 else 0
    return Register(data[0] | (data[1] << 8), data[2], data[3], value)


def float_bits(x: float) -> int:
    """A float32 register value as the 4 bytes' integer."""
    return struct.unpack("<I", struct.pack("<f", x))[0]


# Error frames as Linux SocketCAN reports them (linux/can/error.h): the classes in the frame's id,
# the controller's state in data[1]. Each class with what to check; a warning or passive state
# alone (the controller counting errors) is logged and counted, every other class stops a run.
CAN_ERR_TX_TIMEOUT, CAN_ERR_LOSTARB, CAN_ERR_CRTL, CAN_ERR_PROT = 0x001, 0x002, 0x004, 0x008
CAN_ERR_TRX, CAN_ERR_ACK, CAN_ERR_BUSOFF, CAN_ERR_BUSERROR, CAN_ERR_RESTARTED = 0x010, 0x020, 0x040, 0x080, 0x100
ERROR_CLASSES = (
    (CAN_ERR_TX_TIMEOUT, "tx timeout", "a frame could not be sent in time: is the adapter on a bus?"),
    (CAN_ERR_LOSTARB, "lost arbitration", "another node sent on the same id at once: a second master?"),
    (CAN_ERR_CRTL, "controller", "the adapter's controller reports a problem of its own"),
    (CAN_ERR_PROT, "protocol violation", "a bit, form or stuff error: a bitrate that differs, or bad wiring"),
    (CAN_ERR_TRX, "transceiver", "CAN_H or CAN_L shorted or open: check the wiring"),
    (CAN_ERR_ACK, "no ACK", "no node acknowledged: the motors are unpowered, at another bitrate, or the bus lacks "
                            "its 120 ohm terminators"),
    (CAN_ERR_BUSOFF, "bus-off", "the controller left the bus after too many errors: check the bitrate, the "
                                "wiring and the terminators"),
    (CAN_ERR_BUSERROR, "bus error", "noise or a missing terminator"),
    (CAN_ERR_RESTARTED, "restarted", "the controller came back after bus-off"),
)
CONTROLLER_STATES = ((0x01, "rx overflow"), (0x02, "tx overflow"), (0x04, "rx warning"), (0x08, "tx warning"),
                     (0x10, "rx error-passive"), (0x20, "tx error-passive"), (0x40, "back to error-active"))


def error_classes(arbitration_id: int) -> list[tuple[str, str]]:
    """(name, what to check) of each class an error frame's id carries."""
    return [(name, hint) for bit, name, hint in ERROR_CLASSES if arbitration_id & bit]


def error_frame(arbitration_id: int, data: bytes) -> tuple[bool, str]:
    """(whether it stops a run, one line naming each class with what to check) of an error frame."""
    classes = error_classes(arbitration_id)
    states = [name for bit, name in CONTROLLER_STATES if len(data) > 1 and data[1] & bit]
    benign = {"controller", "restarted"}
    stops = any(name not in benign for name, _ in classes) or not classes
    parts = [f"{name} ({hint})" for name, hint in classes if name != "controller"]
    if states or any(name == "controller" for name, _ in classes):
        parts.append(f"controller: {', '.join(states) or 'unspecified'}")
    return stops, "; ".join(parts) or f"error class 0x{arbitration_id:X}"
