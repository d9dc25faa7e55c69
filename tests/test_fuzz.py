"""The fuzz targets' seed corpora in the repository are the e-manual's packets, framed for each
target as fuzz/dynamixel/seeds.py says (the targets themselves run in `make fuzz` and, as a smoke,
in `make test`)."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SEEDS = ROOT / "fuzz" / "dynamixel" / "seeds.py"


def _seeds():
    spec = importlib.util.spec_from_file_location("fuzz_seeds", SEEDS)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_seed_corpora_are_the_emanual_packets():
    expected = _seeds().corpus()
    for target, files in expected.items():
        folder = ROOT / "fuzz" / "dynamixel" / "corpus" / target
        present = {p.name: p.read_bytes() for p in folder.iterdir()}
        assert present == files, (f"fuzz/dynamixel/corpus/{target} differs from what seeds.py builds "
                                  f"from the e-manual vectors: run python fuzz/dynamixel/seeds.py")
    assert sum(len(f) for f in expected.values()) >= 40, "every e-manual packet seeds a target"
