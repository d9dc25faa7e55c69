"""The fuzz targets' seed corpora in the repository are what their seeds.py builds: the e-manual's
packets for the Dynamixel codec, valid frames of every kind for the CAN codec (plus the inputs that
once crashed it), framed for each target as its seeds.py says (the targets themselves run in `make
fuzz` and, as a smoke, in `make test`)."""

import importlib.util
import struct
from pathlib import Path

import pytest

from servodyn.hal.can import frames
from servodyn.hal.can.motors import MOTORS

ROOT = Path(__file__).resolve().parent.parent
FAMILIES = ("dynamixel", "can", "link")


def _seeds(family):
    spec = importlib.util.spec_from_file_location(f"fuzz_seeds_{family}", ROOT / "fuzz" / family / "seeds.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("family", FAMILIES)
def test_seed_corpora_are_what_seeds_py_builds(family):
    expected = _seeds(family).corpus()
    for target, files in expected.items():
        folder = ROOT / "fuzz" / family / "corpus" / target
        assert folder.is_dir(), f"fuzz/{family}/corpus/{target} is not in the repository (an ignore rule?)"
        present = {p.name: p.read_bytes() for p in folder.iterdir()}
        assert present == files, (f"fuzz/{family}/corpus/{target} differs from what seeds.py builds: "
                                  f"run python fuzz/{family}/seeds.py")
    minimum = {"dynamixel": 40, "can": 50, "link": 15}[family]
    assert sum(len(f) for f in expected.values()) >= minimum, f"every reference frame seeds a {family} target"


def _ranges(data):
    """fuzz/can/codec.c's ranges as the seeds write them (mode 0, int16 of 64 x the value)."""
    values = []
    for k in range(5):
        mode, code = struct.unpack_from("<Bh", data, 1 + 3 * k)
        assert mode == 0, "the seeds' ranges are scaled numbers"
        values.append(code / 64)
    return frames.Ranges(*values), data[16:]


def test_can_seeds_are_valid_frames_of_every_kind_for_each_motor():
    """Each decode seed is a frame its kind's Python decoder accepts, with a motor's own ranges; every
    kind is there for every motor; the regression inputs are kept."""
    seeds = _seeds("can")
    corpus = seeds.corpus()["codec"]
    unpack = {"command": frames.unpack_command, "mit_reply": frames.unpack_mit_reply,
              "damiao": frames.unpack_damiao_feedback, "cubemars_reply": frames.unpack_cubemars_reply}
    kinds = set()
    for name, data in corpus.items():
        if name.startswith("regression_"):
            continue
        prefix, kind = name.split("_", 1)
        r, rest = _ranges(data)
        motor = next(m for m in MOTORS.values() if m.name.lower().replace("-", "") == prefix)
        assert r == motor.ranges, f"{name}: the ranges are {motor.name}'s"
        if data[0] == seeds.ENCODE:
            assert len(rest) >= 5 * 3 + 4, f"{name}: five values and the reply's bytes"
            continue
        assert data[0] == seeds.DECODE, name
        if kind.startswith("special"):
            assert frames.special(rest), f"{name}: a special frame"
        elif kind.startswith("register"):
            assert frames.unpack_register(rest).cmd in (frames.REG_READ, frames.REG_WRITE, frames.REG_REFRESH), name
        else:
            decoder = next(f for k, f in unpack.items() if kind.startswith(k))
            decoder(r, rest)   # raises FrameError on a frame that is not of its kind
        kinds.add((prefix, kind))
    per_motor = {kind for _, kind in kinds}
    assert len(per_motor) >= 14 and len(kinds) == len(MOTORS) * len(per_motor), \
        f"every kind of frame for each of the {len(MOTORS)} motors: {sorted(per_motor)}"
    assert {"regression_float_huge_range", "regression_denormal_range"} <= set(corpus), "the crashes replay"
