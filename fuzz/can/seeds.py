"""The seed corpus of the CAN codec's fuzz target (fuzz/can/corpus/codec/, shared by its double and
float builds), framed as fuzz/can/codec.c reads its input:

    [op][5 ranges][frame]                            op even: the frame goes to every decoder
    [op][5 ranges][p v kp kd t][id status T T2]      op odd: values through every encoder

Each range or value is a mode byte 0 then a little-endian int16 of 64 x the value (12.5 is 800), or
mode 0x80 then a raw IEEE number (8 bytes, a double). The frames are valid ones of every kind, built
by the Python codec (hal/can/frames.py, byte for byte the C codec) with each motor's default ranges:
command, special, mit 6- and 7-byte replies, Damiao's feedback (its vendor layout), CubeMars'
reply, Damiao register frames. The regression_* seeds are the inputs that crashed the target
(fixed since; kept so every run replays them).

Run `python fuzz/can/seeds.py` to write them; tests/test_fuzz.py checks the corpus in the
repository is what this gives."""

import struct
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent / "tests"))

from test_can_frames import DAMIAO_VENDOR_FEEDBACK  # noqa: E402

from servodyn.hal.can import dialects, frames  # noqa: E402
from servodyn.hal.can.motors import MOTORS  # noqa: E402

DECODE, ENCODE = 0, 1

# inputs that crashed the target, as libFuzzer saved them
REGRESSIONS = {
    # float build, encode: v_max 3.39e38 (raw float bits 2a 7f 7f 7f): the span 2 v_max is inf, so
    # (x - min) * 4095 / span was inf / inf, and NaN cast to unsigned (UBSan)
    "regression_float_huge_range": bytes.fromhex("ff4d0e01822a7f7f7f7f7f7f7f7f7f7f7f7f7f7f"),
    # double build, decode: v_max a denormal (2.4e-322): a decoded value packed again was more than
    # one code away
    "regression_denormal_range": bytes.fromhex("0a010200e33000000000000000002f236e2f0a41002f72370a2b0a41002f"),
}


def scaled(x: float) -> bytes:
    code = round(x * 64)
    assert code == x * 64 and -32768 <= code <= 32767, f"{x} is not a 16-bit multiple of 1/64"
    return b"\x00" + struct.pack("<h", code)


def raw(x: float) -> bytes:
    return b"\x80" + struct.pack("<d", x)


def ranges(r: frames.Ranges) -> bytes:
    return b"".join(scaled(getattr(r, k)) for k in ("p_max", "v_max", "t_max", "kp_max", "kd_max"))


def decode_frames(r: frames.Ranges) -> dict[str, bytes]:
    """A valid frame of every kind with these ranges."""
    state = frames.Reply(id=3, p=1.0, v=-2.0, t=3.0, status=1, temperature=35, temperature2=41)
    out = {"command": frames.pack_command(r, 1.0, -2.0, 20.0, 1.5, 3.0)[0],
           "command_zero": frames.pack_command(r, 0.0, 0.0, 0.0, 0.0, 0.0)[0],
           "mit_reply": frames.pack_mit_reply(r, state),
           "mit_reply_voltage": frames.pack_mit_reply(r, state) + bytes([48]),
           "damiao_feedback": frames.pack_damiao_feedback(r, state),
           "damiao_vendor_feedback": DAMIAO_VENDOR_FEEDBACK,
           "cubemars_reply": frames.pack_cubemars_reply(r, frames.Reply(1, 1.0, -2.0, 3.0, status=0, temperature=40)),
           "register_read_pmax": frames.pack_register(frames.Register(0x01, frames.REG_READ, dialects.REG_PMAX)),
           "register_write_timeout": frames.pack_register(frames.Register(0x105, frames.REG_WRITE, dialects.REG_TIMEOUT,
                                                                          2000)),
           "register_refresh": frames.pack_register(frames.Register(0x01, frames.REG_REFRESH, 0))[:4]}
    for code, name in frames.SPECIALS.items():
        out["special_" + name.replace(" ", "_")] = frames.pack_special(code)
    return out


def encode_inputs(r: frames.Ranges) -> dict[str, bytes]:
    """Commands inside, at and past the ranges, and non-finite ones."""
    tail = bytes([3, 1, 35, 41])
    return {"encode_inside": b"".join(scaled(x) for x in (1.0, -2.0, 20.0, 1.5, 3.0)) + tail,
            "encode_ends": b"".join(scaled(x) for x in (r.p_max, -r.v_max, r.kp_max, 0.0, -r.t_max)) + tail,
            "encode_clamped": b"".join(scaled(x) for x in (100.0, -100.0, -5.0, 100.0, 300.0)) + tail,
            "encode_nan": scaled(1.0) + raw(float("nan")) + scaled(20.0) + raw(float("inf")) + raw(-1e308) + tail}


def corpus() -> dict[str, dict[str, bytes]]:
    seeds = dict(REGRESSIONS)
    for motor in MOTORS.values():
        prefix = motor.name.lower().replace("-", "")
        head = ranges(motor.ranges)
        for name, frame in decode_frames(motor.ranges).items():
            seeds[f"{prefix}_{name}"] = bytes([DECODE]) + head + frame
        for name, values in encode_inputs(motor.ranges).items():
            seeds[f"{prefix}_{name}"] = bytes([ENCODE]) + head + values
    return {"codec": seeds}


if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parent))
    from write_corpus import write_corpus
    write_corpus(HERE, corpus())
