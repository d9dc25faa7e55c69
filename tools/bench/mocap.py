"""`make bench`, captured motion: retargeting the 37.6 s CMU clip (01_03, 4511 frames at 120 Hz,
Debian's assimp-testmodels) onto the replica, each the median of `--reps` runs: reading the file,
the segment split with the elbow calibration, the smoothing (outliers, low-pass, spline, lead-in),
and the whole. The reference in the same run is numpy parsing the same numbers from the same text
(np.array(text.split(), float)): the reader's ratio to it says what the BVH structure costs.

Goal on the 2-core machine: the whole retarget (read included) ≤ 1 s.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ...mocap import ArmTarget, find_arms, guess_axes, read_bvh, retarget
from ...mocap.retarget import capture, decompose
from ...model import load_model
from .loop import publish
from .validate import timed

ROOT = Path(__file__).resolve().parents[2]
CLIP = Path("/usr/share/assimp/models/BVH/01_03.bvh")
GOALS = {"retarget_s": 1.0}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.mocap", description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5, help="runs of each (default 5)")
    parser.add_argument("--clip", default=str(CLIP), help=f"the clip (default {CLIP})")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    if not Path(args.clip).exists():
        print(f"bench mocap: {args.clip} is missing (make mocap-clips installs assimp-testmodels)", file=sys.stderr)
        return 2
    target = ArmTarget.of(load_model("replica"))
    text = Path(args.clip).read_text()
    print(f"servodyn mocap: retarget {Path(args.clip).name} onto the replica", flush=True)
    numbers, _ = timed(lambda: np.array(text.split("Frame Time:")[1].split()[1:], dtype=float), args.reps)
    read, clip = timed(lambda: read_bvh(args.clip), args.reps)
    arms = find_arms(clip)
    axes, _ = guess_axes(clip, arms)
    chain = arms["right"]
    split, _ = timed(lambda: decompose(capture(clip, chain, axes, target, slice(1, None)), target), args.reps)
    whole, result = timed(lambda: retarget(read_bvh(args.clip), chain, axes, target), args.reps)
    rows = {"clip": Path(args.clip).name, "frames": clip.frames, "duration_s": clip.duration,
            "numpy_parse_s": numbers, "read_s": read, "read_over_numpy": read / numbers,
            "split_s": split, "retarget_s": whole, "written_samples": len(result.trajectory.t)}
    met = "met" if whole <= GOALS["retarget_s"] else "NOT met"
    lines = ["| what | time | |", "|---|---:|---|",
             f"| numpy parses the {clip.frames} x {clip.motion.shape[1]} numbers (reference) | {numbers:.3f} s | |",
             f"| read the BVH | {read:.3f} s | {read / numbers:.2f}x the reference |",
             f"| segment split + elbow calibration | {split:.3f} s | |",
             f"| whole retarget of the {clip.duration:.1f} s clip, read included | {whole:.3f} s | "
             f"goal ≤ {GOALS['retarget_s']:g} s: {met} |"]
    publish(Path(args.out), "mocap", "\n".join(lines), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
