"""LeRobot datasets validated end to end through the CLI (servodyn validate CONFIG --lerobot DIR), malformed
ones refused in one line, and LeRobot calibrations imported (servodyn calibrate --from-lerobot)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from servodyn.hal.config import load_config
from servodyn.control.motion import load_motion
from servodyn.validation.lerobot_write import SO101_NAMES, write_dataset
from helpers import run_cli


def lerobot_values(q: np.ndarray, limits, units: str) -> np.ndarray:
    """Joint angles (rad, the so101 configuration's joints: direction +1, gear 1, zero at the range's
    middle) as LeRobot records them: body joints in degrees ((raw − mid)·360/4095 with raw − mid =
    q·4096/2π) or ±100 over the range; the gripper 0..100 over its range."""
    out = np.empty_like(q)
    for j, (lower, upper) in enumerate(limits):
        middle, half = (lower + upper) / 2, (upper - lower) / 2
        if j == len(limits) - 1:                                  # the gripper: RANGE_0_100
            out[:, j] = ((q[:, j] - lower) / (upper - lower)) * 100
        elif units == "degrees":
            out[:, j] = (q[:, j] * 4096 / (2 * math.pi)) * 360 / 4095
        else:
            out[:, j] = ((q[:, j] - middle) / half) * 100
    return out


