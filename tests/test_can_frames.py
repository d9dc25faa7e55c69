"""The CAN motor frame codec: the C codec (hal/can/c/canmotor.c, built here with the system C
compiler and called through ctypes) against the Python codec (hal/can/frames.py) byte for byte,
both against the mini-cheetah firmware's own packing (float_to_uint, evaluated as the firmware
does in float32 and as host drivers do in double), every range boundary, clamping (never a
wrap), quantization, the special frames, Damiao's feedback layout and register frames."""

import ctypes
import functools
import math
import random
import re
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from servodyn.hal.can import dialects, frames
from servodyn.hal.can.motors import DM_J4310, DM_J4340, MOTORS

from helpers import run_cli

ROOT = Path(__file__).resolve().parent.parent
CODEC = ROOT / "hal" / "can" / "c"
# the ranges of a motor of each kind and a wide one (the codec is range-generic; every catalogue
# motor's ranges seed the fuzz target, fuzz/can/seeds.py)
RANGES = [MOTORS[name].ranges for name in ("DM-J4340", "DM-J4310", "AK80-9")] + [frames.Ranges(12.5, 65.0, 200.0)]
# Damiao's feedback layout (DM_CAN.py), built by hand: motor 3 enabled, p code 0x8000, v code 0x800,
# t code 0x7FF, 35 and 41 degC
DAMIAO_VENDOR_FEEDBACK = bytes([0x13, 0x80, 0x00, 0x80, 0x07, 0xFF, 35, 41])


@functools.cache
def _structs(real):
    """The codec's structures with cm_real = real (ctypes.c_double, or c_float for -DSD_SINGLE)."""
    class Ranges(ctypes.Structure):
        _fields_ = [(n, real) for n in ("p_max", "v_max", "t_max", "kp_max", "kd_max")]

    class Command(ctypes.Structure):
        _fields_ = [(n, real) for n in ("p", "v", "kp", "kd", "t")]

    class Reply(ctypes.Structure):
        _fields_ = [("id", ctypes.c_uint8), ("status", ctypes.c_uint8), ("p", real), ("v", real), ("t", real),
                    ("temperature", ctypes.c_int8), ("temperature2", ctypes.c_int8), ("voltage", ctypes.c_uint8)]
    return Ranges, Command, Reply


CRanges, CCommand, CReply = _structs(ctypes.c_double)
FRanges, FCommand, FReply = _structs(ctypes.c_float)


class CRegister(ctypes.Structure):
    _fields_ = [("can_id", ctypes.c_uint16), ("cmd", ctypes.c_uint8), ("rid", ctypes.c_uint8),
                ("value", ctypes.c_uint32)]


def build_codec(directory, single=False):
    """canmotor.c as a shared library, cm_real = double, or float with -DSD_SINGLE (the firmware's
    build, with its warnings: no silent promotion to double)."""
    cc = shutil.which("cc")
    if cc is None:
        pytest.fail("no C compiler: `cc` is not on PATH (make test installs one)", pytrace=False)
    lib = directory / ("libcanmotor32.so" if single else "libcanmotor.so")
    command = [cc, "-shared", "-fPIC", "-O2", "-std=c11", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off",
               *(["-DSD_SINGLE", "-Wdouble-promotion", "-Wfloat-conversion"] if single else []),
               f"-I{CODEC}", "-o", str(lib), str(CODEC / "canmotor.c")]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        pytest.fail(f"building the C codec failed: {' '.join(command)}\n{done.stderr}", pytrace=False)
    so = ctypes.CDLL(str(lib))
    real = ctypes.c_float if single else ctypes.c_double
    ranges, command_t, reply = _structs(real)
    u8p, P = ctypes.POINTER(ctypes.c_uint8), ctypes.POINTER
    so.cm_pack_command.argtypes = [P(ranges), P(command_t), u8p, P(ctypes.c_uint)]
    so.cm_unpack_command.argtypes = [P(ranges), u8p, ctypes.c_size_t, P(command_t)]
    for kind in ("mit_reply", "damiao_feedback", "cubemars_reply"):
        getattr(so, f"cm_pack_{kind}").argtypes = [P(ranges), P(reply), u8p]
        getattr(so, f"cm_unpack_{kind}").argtypes = [P(ranges), u8p, ctypes.c_size_t, P(reply)]
    so.cm_special.argtypes = [u8p, ctypes.c_size_t]
    so.cm_pack_special.argtypes = [u8p, ctypes.c_uint8]
    so.cm_pack_register.argtypes = [P(CRegister), u8p]
    so.cm_unpack_register.argtypes = [u8p, ctypes.c_size_t, P(CRegister)]
    so.cm_to_uint.restype = ctypes.c_uint32
    so.cm_to_uint.argtypes = [real, real, real, ctypes.c_uint]
    so.cm_to_float.restype = real
    so.cm_to_float.argtypes = [ctypes.c_uint32, real, real, ctypes.c_uint]
    return so


@pytest.fixture(scope="module")
def cm(tmp_path_factory):
    return build_codec(tmp_path_factory.mktemp("canmotor"))


@pytest.fixture(scope="module")
def cm32(tmp_path_factory):
    return build_codec(tmp_path_factory.mktemp("canmotor32"), single=True)


def _cr(r):
    return CRanges(r.p_max, r.v_max, r.t_max, r.kp_max, r.kd_max)


def _buf(data=b"", n=8):
    return (ctypes.c_uint8 * n)(*data)


def c_pack(cm, r, p, v, kp, kd, t):
    out, clamped = _buf(), ctypes.c_uint()
    code = cm.cm_pack_command(_cr(r), CCommand(p, v, kp, kd, t), out, ctypes.byref(clamped))
    return code, bytes(out), clamped.value


def float_to_uint_f32(x, lo, hi, bits):
    """The firmware's float_to_uint, in float32 as on the motor's STM32 (no clamp)."""
    f = np.float32
    return int(np.trunc((f(x) - f(lo)) * f((1 << bits) - 1) / (f(hi) - f(lo))))


def reference_pack(r, p, v, kp, kd, t, dtype=float):
    """bgkatz's pack_cmd after clamping, in double (host drivers) or float32 (the firmware)."""
    conv = (lambda x, lo, hi, b: int((x - lo) * float((1 << b) - 1) / (hi - lo))) if dtype is float \
        else float_to_uint_f32
    pi, vi = conv(p, -r.p_max, r.p_max, 16), conv(v, -r.v_max, r.v_max, 12)
    kpi, kdi, ti = conv(kp, 0, r.kp_max, 12), conv(kd, 0, r.kd_max, 12), conv(t, -r.t_max, r.t_max, 12)
    return bytes([pi >> 8, pi & 0xFF, vi >> 4, ((vi & 0xF) << 4) | (kpi >> 8), kpi & 0xFF, kdi >> 4,
                  ((kdi & 0xF) << 4) | (ti >> 8), ti & 0xFF])


def boundary_values(lo, hi, bits):
    """Both ends, just inside and outside, zero, and every code's edge for a few codes."""
    step = (hi - lo) / ((1 << bits) - 1)
    out = [lo, hi, lo - step, hi + step, lo - 1e9, hi + 1e9, 0.0 if lo < 0 else lo,
           math.nextafter(lo, -math.inf), math.nextafter(hi, math.inf), math.nextafter(lo, math.inf),
           math.nextafter(hi, -math.inf), lo + step, hi - step]
    for k in (1, 2, 2047, 2048, (1 << bits) - 2):
        edge = lo + k * step
        out += [edge, math.nextafter(edge, -math.inf), math.nextafter(edge, math.inf)]
    return out


def random_commands(r, n, seed):
    rng = random.Random(seed)
    for _ in range(n):
        yield (rng.uniform(-1.2, 1.2) * r.p_max, rng.uniform(-1.2, 1.2) * r.v_max,
               rng.uniform(-0.1, 1.1) * r.kp_max, rng.uniform(-0.1, 1.1) * r.kd_max,
               rng.uniform(-1.2, 1.2) * r.t_max)


def test_c_and_python_pack_the_same_bytes_over_boundaries_and_random_values(cm):
    count = 0
    for r in RANGES:
        cases = all_cases(r)
        for case in cases:
            code, c_bytes, c_clamped = c_pack(cm, r, *case)
            py_bytes, py_clamped = frames.pack_command(r, *case)
            assert code == 0 and c_bytes == py_bytes and c_clamped == py_clamped, \
                f"C and Python codecs disagree on {case} at {r}: {c_bytes.hex()} vs {py_bytes.hex()}"
            count += 1
    assert count > 12000, "the comparison covered the random and boundary cases"


def test_packing_matches_the_firmware_reference_inside_the_ranges(cm):
    """Inside the ranges the codec is bgkatz's float_to_uint exactly (double, as a host driver
    computes it); the firmware's float32 arithmetic differs by at most one code, on a few values."""
    float32_off = total = 0
    for r in RANGES:
        for case in random_commands(r, 3000, seed=7):
            inside = (max(-r.p_max, min(r.p_max, case[0])), max(-r.v_max, min(r.v_max, case[1])),
                      max(0, min(r.kp_max, case[2])), max(0, min(r.kd_max, case[3])),
                      max(-r.t_max, min(r.t_max, case[4])))
            packed = frames.pack_command(r, *inside)[0]
            assert packed == reference_pack(r, *inside), f"{inside}: not the firmware's packing"
            f32 = reference_pack(r, *inside, dtype=np.float32)
            float32_off += packed != f32
            total += 1
            if packed != f32:
                ours = frames.unpack_command(r, packed)
                theirs = frames.unpack_command(r, f32)
                for name, step in (("p", 2 * r.p_max / 65535), ("v", 2 * r.v_max / 4095), ("kp", r.kp_max / 4095),
                                   ("kd", r.kd_max / 4095), ("t", 2 * r.t_max / 4095)):
                    assert abs(getattr(ours, name) - getattr(theirs, name)) <= step * 1.0001, \
                        f"{inside}: float32 firmware packing more than one code away in {name}"
    assert float32_off < 0.05 * total, f"float32 and double packing differ on {float32_off} of {total} commands"


def all_cases(r, n=3000, seed=None):
    """n random commands around the ranges, then each field over its boundary values."""
    cases = list(random_commands(r, n, seed=int(r.t_max) if seed is None else seed))
    for k, (lo, hi, bits) in enumerate(fields_of(r)):
        for x in boundary_values(lo, hi, bits):
            base = [0.0, 0.0, 1.0, 0.1, 0.0]
            base[k] = x
            cases.append(tuple(base))
    return cases


def fields_of(r):
    """(lo, hi, bits) of p, v, kp, kd, t."""
    return ((-r.p_max, r.p_max, 16), (-r.v_max, r.v_max, 12), (0.0, r.kp_max, 12), (0.0, r.kd_max, 12),
            (-r.t_max, r.t_max, 12))


def clamp_in(case, r, dtype):
    """The case clamped into the ranges in dtype (float: Python's double; np.float32: as the float build
    clamps, after its caller's conversion to float), and the CLAMP_* bits."""
    inside, bits = [], 0
    for k, (x, (lo, hi, _)) in enumerate(zip(case, fields_of(r))):
        x, lo, hi = dtype(x), dtype(lo), dtype(hi)
        bits |= (x < lo or x > hi) << k
        inside.append(min(max(x, lo), hi))
    return tuple(inside), bits


def uint_to_float_f32(u, lo, hi, bits):
    """The firmware's uint_to_float in float32."""
    f = np.float32
    return f(u) * (f(hi) - f(lo)) / f((1 << bits) - 1) + f(lo)


def test_each_build_packs_as_the_firmware_reference_in_its_precision(cm, cm32):
    """The double build is bgkatz's float_to_uint computed in double, the float build (-DSD_SINGLE,
    the firmware's) the same computed in float32, both exactly, over random values and every range
    boundary. The two precisions are both the reference; they differ by one code on a few values
    (on many of the boundary cases, which sit on code edges by design)."""
    random_total = random_differ = boundary_total = boundary_differ = 0
    for r in RANGES:
        cr32 = FRanges(r.p_max, r.v_max, r.t_max, r.kp_max, r.kd_max)
        for k, case in enumerate(all_cases(r, n=3000)):
            code, c_bytes, c_clamped = c_pack(cm, r, *case)
            inside, bits = clamp_in(case, r, float)
            assert code == 0 and c_bytes == reference_pack(r, *inside) and c_clamped == bits, \
                f"double build: {case} at {r} packed {c_bytes.hex()}, reference {reference_pack(r, *inside).hex()}"
            out, clamped = _buf(), ctypes.c_uint()
            assert cm32.cm_pack_command(cr32, FCommand(*case), out, ctypes.byref(clamped)) == 0, case
            inside32, bits32 = clamp_in(case, r, np.float32)
            f32 = reference_pack(r, *inside32, dtype=np.float32)
            assert bytes(out) == f32 and clamped.value == bits32, \
                f"float build: {case} at {r} packed {bytes(out).hex()}, float32 reference {f32.hex()}"
            if f32 != c_bytes:
                ours, theirs = frames.unpack_command(r, c_bytes), frames.unpack_command(r, f32)
                for name, (lo, hi, nbits) in zip(("p", "v", "kp", "kd", "t"), fields_of(r)):
                    assert abs(getattr(ours, name) - getattr(theirs, name)) <= (hi - lo) / ((1 << nbits) - 1) * 1.0001, \
                        f"{case}: float and double builds more than one code apart in {name}"
            if k < 3000:
                random_total, random_differ = random_total + 1, random_differ + (f32 != c_bytes)
            else:
                boundary_total, boundary_differ = boundary_total + 1, boundary_differ + (f32 != c_bytes)
    assert random_total == 12000 and boundary_total > 500, "the random and boundary cases"
    # measured: 18 of 12,000 random commands, 116 of 560 boundary cases
    assert 0 < random_differ < 0.005 * random_total, \
        f"float32 and double differ on {random_differ} of {random_total} random commands (expected a few)"
    assert boundary_differ > 0, "the boundary cases on code edges tell float32 from double"


def test_float_build_decodes_every_code_as_the_firmware_in_float32(cm32):
    """uint_to_float in float32 for every p code and every 12-bit code, each range; in range and finite."""
    for r in RANGES:
        cr32 = FRanges(r.p_max, r.v_max, r.t_max, r.kp_max, r.kd_max)
        got = FCommand()
        p, small = np.arange(65536), np.arange(65536) & 0xFFF
        want = [uint_to_float_f32(codes, lo, hi, bits) for codes, (lo, hi, bits) in
                zip((p, small, small, small, small), fields_of(r))]
        # every code on the first range; on the others every 13th p code, which still meets all 4096 12-bit codes
        for k in range(0, 65536, 1 if r is RANGES[0] else 13):
            u = int(small[k])
            data = bytes((k >> 8, k & 0xFF, u >> 4, ((u & 0xF) << 4) | (u >> 8), u & 0xFF, u >> 4,
                          ((u & 0xF) << 4) | (u >> 8), u & 0xFF))
            if frames.special(data):
                continue
            assert cm32.cm_unpack_command(cr32, _buf(data), 8, ctypes.byref(got)) == 0, data.hex()
            for name, values in zip(("p", "v", "kp", "kd", "t"), want):
                assert np.float32(getattr(got, name)) == values[k], \
                    f"float build decodes {name} code {k if name == 'p' else u} as {getattr(got, name)}, " \
                    f"float32 uint_to_float gives {values[k]} ({r})"
        top = FCommand()
        assert cm32.cm_unpack_command(cr32, _buf(b"\xff" * 7 + b"\xf0"), 8, ctypes.byref(top)) == 0
        assert np.float32(top.p) == np.float32(r.p_max), "the top code decodes to the range's end"


@pytest.mark.parametrize("kind", ["mit_reply", "damiao_feedback", "cubemars_reply"])
def test_float_build_packs_replies_as_the_firmware_in_float32(cm32, kind):
    """A simulated motor in float: the state fields of each reply from float_to_uint in float32."""
    r = DM_J4340.ranges
    cr32 = FRanges(r.p_max, r.v_max, r.t_max, r.kp_max, r.kd_max)
    rng = random.Random(kind)
    for _ in range(1000):
        p, v, t = rng.uniform(-13, 13), rng.uniform(-9, 9), rng.uniform(-30, 30)
        out = _buf()
        assert getattr(cm32, f"cm_pack_{kind}")(cr32, FReply(3, 1, p, v, t, 40, 41, 0), out) == 0
        (p32, v32, _, _, t32), _ = clamp_in((p, v, 0, 0, t), r, np.float32)
        pu, vu = float_to_uint_f32(p32, -r.p_max, r.p_max, 16), float_to_uint_f32(v32, -r.v_max, r.v_max, 12)
        tu = float_to_uint_f32(t32, -r.t_max, r.t_max, 12)
        assert bytes(out[1:6]) == bytes((pu >> 8, pu & 0xFF, vu >> 4, ((vu & 0xF) << 4) | (tu >> 8), tu & 0xFF)), \
            f"{kind}: ({p}, {v}, {t}) packed {bytes(out[1:6]).hex()}"


def test_every_out_of_range_value_clamps_and_never_wraps(cm):
    r = DM_J4310.ranges
    for k, (name, hi) in enumerate((("p", r.p_max), ("v", r.v_max), ("kp", r.kp_max), ("kd", r.kd_max),
                                    ("t", r.t_max))):
        for sign, expect in ((1, hi), (-1, -hi if name in ("p", "v", "t") else 0.0)):
            case = [0.0, 0.0, 0.0, 0.0, 0.0]
            case[k] = sign * hi * 3 if name not in ("kp", "kd") or sign > 0 else -1.0
            packed, clamped = frames.pack_command(r, *case)
            back = getattr(frames.unpack_command(r, packed), name)
            assert clamped == 1 << k, f"{name}={case[k]}: clamp bit {1 << k} expected, got {clamped}"
            assert back == pytest.approx(expect, abs=1e-12), f"{name}={case[k]} decoded to {back}, not {expect}"
            # the raw firmware conversion would wrap: (3X + X) * 4095 / 2X = 8190 -> 0xFFE in 12 bits
    raw = float_to_uint_f32(3 * r.t_max, -r.t_max, r.t_max, 12)
    assert raw & 0xFFF != 4095, "an unclamped float_to_uint wraps (the reason the codec clamps first)"


def test_quantization_and_zero_torque(cm):
    """12-bit torque: step 2 TMAX / 4095; zero decodes to -TMAX/4095 (not zero)."""
    for motor, zero in ((DM_J4310, -10.0 / 4095), (DM_J4340, -28.0 / 4095)):
        r = motor.ranges
        packed, _ = frames.pack_command(r, 0.0, 0.0, 0.0, 0.0, 0.0)
        decoded = frames.unpack_command(r, packed)
        assert decoded.t == pytest.approx(zero, rel=1e-12), f"{motor.name}: zero torque decodes to {decoded.t}"
        assert r.torque_step == pytest.approx(2 * r.t_max / 4095), "the torque step"
        rng = np.random.default_rng(3)
        for t in rng.uniform(-r.t_max, r.t_max, 500):
            back = frames.unpack_command(r, frames.pack_command(r, 0, 0, 0, 0, float(t))[0]).t
            assert -r.torque_step * (1 + 1e-9) < back - t <= 1e-12, \
                f"{motor.name}: {t} N m sent as {back} (truncation: at most one step below)"
    assert frames.unpack_command(DM_J4310.ranges, frames.pack_command(DM_J4310.ranges, 0, 0, 0, 0, 0)[0]).t \
        == pytest.approx(-2.442e-3, abs=1e-6), "the notes' figure: -2.4 mN m at TMAX 10"


def test_non_finite_values_and_bad_ranges_are_refused(cm):
    r = DM_J4310.ranges
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(frames.FrameError):
            frames.pack_command(r, bad, 0, 0, 0, 0)
        assert c_pack(cm, r, 0, 0, 0, 0, bad)[0] == -2, "C refuses a non-finite value (CM_EVALUE)"
    bad_ranges = CRanges(12.5, 0.0, 10.0, 500.0, 5.0)
    out = _buf()
    assert cm.cm_pack_command(bad_ranges, CCommand(0, 0, 0, 0, 0), out, None) == -2, "a zero range is refused"
    with pytest.raises(frames.FrameError):
        frames.Ranges(12.5, 0.0, 10.0)


@pytest.mark.parametrize("kind", ["mit_reply", "damiao_feedback", "cubemars_reply"])
def test_replies_round_trip_in_c_and_python(cm, kind):
    r = DM_J4340.ranges
    rng = random.Random(kind)
    n = {"mit_reply": 6, "damiao_feedback": 8, "cubemars_reply": 8}[kind]
    for _ in range(2000):
        y = frames.Reply(id=rng.randrange(1, 16), p=rng.uniform(-13, 13), v=rng.uniform(-9, 9),
                         t=rng.uniform(-30, 30), status=rng.choice([0, 1, 8, 0xC, 0xD]) if kind != "mit_reply" else 0,
                         temperature=rng.randrange(-20, 120) if kind != "mit_reply" else 0,
                         temperature2=rng.randrange(-20, 120) if kind == "damiao_feedback" else 0)
        py = getattr(frames, f"pack_{kind}")(r, y)
        out = _buf(n=8)
        assert getattr(cm, f"cm_pack_{kind}")(_cr(r), CReply(y.id, y.status, y.p, y.v, y.t, y.temperature,
                                                              y.temperature2, 0), out) == 0
        assert bytes(out[:n]) == py, f"{kind}: C and Python differ for {y}"
        back = getattr(frames, f"unpack_{kind}")(r, py)
        got = CReply()
        assert getattr(cm, f"cm_unpack_{kind}")(_cr(r), _buf(py), n, ctypes.byref(got)) == 0
        for name in ("id", "status", "p", "v", "t", "temperature", "temperature2"):
            assert getattr(got, name) == getattr(back, name), f"{kind}: C decodes {name} differently"
        assert abs(back.p - max(-12.5, min(12.5, y.p))) <= 25 / 65535, f"{kind}: p within one code"
        assert abs(back.t - max(-28, min(28, y.t))) <= 56 / 4095, f"{kind}: t within one code"
        assert (back.status, back.temperature) == (y.status, y.temperature), f"{kind}: status and temperature"
    for wrong in (5, 9):
        with pytest.raises(frames.FrameError):
            getattr(frames, f"unpack_{kind}")(r, bytes(wrong))
        assert getattr(cm, f"cm_unpack_{kind}")(_cr(r), _buf(n=9), wrong, ctypes.byref(CReply())) == -1


def test_damiao_feedback_layout_from_the_vendor_library():
    """Damiao's layout (DM_CAN.py): D0 = status<<4 | id, p 16 bits, v 12 | t 12, T_mos, T_coil."""
    r = DM_J4310.ranges
    data = DAMIAO_VENDOR_FEEDBACK
    y = frames.unpack_damiao_feedback(r, data)
    assert (y.id, y.status, y.temperature, y.temperature2) == (3, 1, 35, 41), "byte 0 nibbles and temperatures"
    assert y.p == pytest.approx(0x8000 * 25 / 65535 - 12.5), "p from bytes 1-2"
    assert y.v == pytest.approx(0x800 * 60 / 4095 - 30), "v from byte 3 and the high nibble of byte 4"
    assert y.t == pytest.approx(0x7FF * 20 / 4095 - 10), "t from the low nibble of byte 4 and byte 5"
    assert dialects.DIALECTS["damiao"].faults(frames.unpack_damiao_feedback(r, b"\xc3" + data[1:]), True) \
        == ("coil over-temperature",), "status C names the coil over-temperature"


def test_mit_reply_six_and_seven_bytes():
    r = frames.Ranges(12.5, 65.0, 18.0)
    six = frames.pack_mit_reply(r, frames.Reply(2, 1.0, -3.0, 4.0))
    assert len(six) == 6 and six[0] == 2, "bgkatz's 6-byte reply starts with the motor id"
    y = frames.unpack_mit_reply(r, six + b"\x30")
    assert y.voltage == 0x30 and y.p == pytest.approx(1.0, abs=25 / 65535), "the 7th byte is the voltage"


def test_special_frames(cm):
    for code in (0xFC, 0xFD, 0xFE, 0xFB):
        data = frames.pack_special(code)
        c = _buf()
        cm.cm_pack_special(c, code)
        assert bytes(c) == data == b"\xff" * 7 + bytes([code]), f"special 0x{code:X}"
        assert frames.special(data) == code == cm.cm_special(_buf(data), 8), "recognised by both codecs"
        with pytest.raises(frames.FrameError):
            frames.unpack_command(DM_J4310.ranges, data)
        assert cm.cm_unpack_command(_cr(DM_J4310.ranges), _buf(data), 8, ctypes.byref(CCommand())) == -3
    # FF..FF FA is an ordinary command (all codes near the top), not a special frame
    assert frames.special(b"\xff" * 7 + b"\xfa") == 0 == cm.cm_special(_buf(b"\xff" * 7 + b"\xfa"), 8)
    with pytest.raises(frames.FrameError):
        frames.pack_special(0xFA)


def test_register_frames(cm):
    g = frames.Register(can_id=0x105, cmd=frames.REG_WRITE, rid=dialects.REG_TIMEOUT, value=2000)
    data = frames.pack_register(g)
    assert data == bytes([0x05, 0x01, 0x55, 9, 0xD0, 0x07, 0, 0]), "id LE, cmd, rid, value LE"
    c = _buf()
    cm.cm_pack_register(CRegister(0x105, 0x55, 9, 2000), c)
    assert bytes(c) == data, "C packs the same register frame"
    back = CRegister()
    assert cm.cm_unpack_register(_buf(data), 8, ctypes.byref(back)) == 0
    assert (back.can_id, back.cmd, back.rid, back.value) == (0x105, 0x55, 9, 2000)
    assert frames.unpack_register(data) == g
    pmax = frames.Register(1, frames.REG_READ, dialects.REG_PMAX, frames.float_bits(12.5))
    assert frames.unpack_register(frames.pack_register(pmax)).as_float == 12.5, "a float32 register"
    assert struct.unpack("<f", frames.pack_register(pmax)[4:])[0] == 12.5
    with pytest.raises(frames.FrameError):
        frames.unpack_register(bytes([1, 0, 0x44, 9, 0, 0, 0, 0]))
    assert cm.cm_unpack_register(_buf(bytes([1, 0, 0x44, 9, 0, 0, 0, 0])), 8, ctypes.byref(back)) == -3


def test_the_firmware_check_vectors_are_the_float32_reference():
    """firmware/mcu/canmotor_check.c runs the float codec under QEMU against a table of commands and
    bytes: the bytes are the float32 reference's, and in the first vector every field differs from
    the double packing, so the Cortex-M4F build is shown to compute in float32."""
    source = (ROOT / "firmware" / "mcu" / "canmotor_check.c").read_text()
    ranges = re.search(r"cm_j4340 = \{([^}]*)\}", source).group(1)
    r = frames.Ranges(*(float(x) for x in re.findall(r"CM_R\(([^)]*)\)", ranges)))
    assert r == DM_J4340.ranges, f"the check's ranges {r} are a DM-J4340's"
    table = source[source.index("BEGIN canmotor vectors"):source.index("END canmotor vectors")]
    vectors = re.findall(r"\{\{([^}]*)\},\s*\{([^}]*)\},\s*(\d+)\}", table)
    assert len(vectors) >= 2, "the table has its vectors"
    for k, (values, data, clamped) in enumerate(vectors):
        case = [float(x) for x in re.findall(r"CM_R\(([^)]*)\)", values)]
        data = bytes(int(x, 16) for x in data.split(","))
        inside32, bits32 = clamp_in(case, r, np.float32)
        assert data == reference_pack(r, *inside32, dtype=np.float32) and int(clamped) == bits32, \
            f"vector {k} {case}: {data.hex()} is not the float32 reference"
        if k == 0:
            double = reference_pack(r, *clamp_in(case, r, float)[0])
            ours, theirs = frames.unpack_command(r, data), frames.unpack_command(r, double)
            assert all(getattr(ours, n) != getattr(theirs, n) for n in ("p", "v", "kp", "kd", "t")), \
                f"vector 0 should tell float32 from double in every field: {data.hex()} vs {double.hex()}"


def test_ranges_outside_the_codec_bounds_are_refused_in_both_builds_and_in_python(cm, cm32):
    """Regression (found by the fuzz target): a range near the float maximum made the span inf, so
    float_to_uint was inf / inf and NaN was cast to unsigned; a denormal range lost the codes. Each
    range end must lie in [CM_RANGE_MIN, CM_RANGE_MAX] (canmotor.h, the same in frames.py)."""
    header = (CODEC / "canmotor.h").read_text()
    bounds = [float(re.search(rf"#define CM_RANGE_{k} CM_R\(([^)]*)\)", header).group(1)) for k in ("MIN", "MAX")]
    assert bounds == [frames.RANGE_MIN, frames.RANGE_MAX], f"C bounds {bounds}, Python's differ"
    for bad in (3.39e38, 1.7e308, 2 * frames.RANGE_MAX, frames.RANGE_MIN / 2, 2.4e-322, 0.0, -1.0, math.nan, math.inf):
        for field in range(5):
            values = [12.5, 8.0, 28.0, 500.0, 5.0]
            values[field] = bad
            assert c_pack(cm, frames.Ranges(12.5, 8.0, 28.0), 0, 0, 0, 0, 0)[0] == 0
            out = _buf()
            assert cm.cm_pack_command(CRanges(*values), CCommand(0, 0, 0, 0, 0), out, None) == -2, \
                f"double build accepts range {bad} in field {field}"
            assert cm32.cm_pack_command(FRanges(*values), FCommand(0, 0, 0, 0, 0), out, None) == -2, \
                f"float build accepts range {bad} in field {field}"
            assert cm.cm_unpack_damiao_feedback(CRanges(*values), _buf(DAMIAO_VENDOR_FEEDBACK), 8,
                                                ctypes.byref(CReply())) == -2, f"decoding with range {bad}"
            with pytest.raises(frames.FrameError, match="must be a number from 1e-06 to 1e"):
                frames.Ranges(*values)
    for edge in (frames.RANGE_MIN, frames.RANGE_MAX):
        r = frames.Ranges(edge, edge, edge, edge, edge)
        for value in (edge, -edge, edge / 3, 0.0):
            code, c_bytes, _ = c_pack(cm, r, value, value, abs(value), abs(value), value)
            assert code == 0 and c_bytes == frames.pack_command(r, value, value, abs(value), abs(value), value)[0]
            back = frames.unpack_command(r, c_bytes)
            assert abs(back.p - value) <= 2 * edge / 65535 * 1.0001, f"range {edge}: p {value} came back {back.p}"


def test_a_configuration_with_a_range_outside_the_codec_bounds_is_one_line(tmp_path):
    """`p_max = 1e300` in a configuration reached the codec and raised a ValueError mid-swing."""
    import tomllib
    from servodyn.hal.config import builtin_configs
    text = builtin_configs()["replica_can"].read_text()
    data = tomllib.loads(text)
    first = next(k for k, line in enumerate(text.splitlines()) if line.strip() == "[[joint]]")
    lines = text.splitlines()
    lines.insert(first + 1, "p_max = 1e300")
    bad = tmp_path / "huge_range.toml"
    bad.write_text("\n".join(lines) + "\n")
    assert data["joint"], "the configuration has joints"
    run = run_cli("validate", bad, "forehand", "--out", tmp_path / "out")
    assert run.returncode == 2, f"exit {run.returncode}: {run.stderr}"
    assert "Traceback" not in run.stderr and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "'p_max' 1e+300 is outside the MIT frame codec's ranges" in run.stderr, run.stderr
