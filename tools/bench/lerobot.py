"""`make bench`, LeRobot datasets: how long `servodyn validate so101 --lerobot DIR --jobs 2` takes on a
dataset of 50 episodes × 30 s at 30 fps (the command itself, in a process of its own: reading the
parquet files, smoothing, every check of every episode and each one's fit time scale).

Goal on the 2-core machine: ≤ 5 s on 2 jobs. The episodes are the SO-101's own pick (so101_pick)
played back to back for 30 s, each episode at its own speed (1 to 1.6 times slower, so some pass and
some fail) with its own shoulder_pan offset, recorded as LeRobot records: degrees about the
calibration's midpoint rounded to the servo's step, the gripper 0..100.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ...control.motion import load_motion
from ...hal.config import load_config
from ...validation.lerobot_motion import LEROBOT_DEGREE, RESOLUTION
from ...validation.lerobot_write import write_dataset
from .loop import publish

ROOT = Path(__file__).resolve().parents[2]
GOAL_S = 5.0
EPISODES, SECONDS, FPS, JOBS = 50, 30.0, 30.0, 2


def dataset(root: Path, episodes: int = EPISODES, seconds: float = SECONDS, fps: float = FPS, seed: int = 0) -> Path:
    """The benchmark's dataset at root (see the module's docstring)."""
    config = load_config("so101")
    motion = load_motion("so101_pick", config.model)
    rng = np.random.default_rng(seed)
    lower, upper = config.joints[-1].position_limits
    t = np.arange(int(round(seconds * fps)) + 1) / fps
    rows = []
    for e in range(episodes):
        slower = rng.uniform(1.0, 1.6)
        q = motion.at(np.minimum((t / slower) % (motion.duration + 0.5), motion.duration))[0]
        q[:, 0] += rng.uniform(-0.3, 0.3)
        steps = np.round(q * RESOLUTION / (2 * math.pi))            # the servo's encoder steps
        values = steps * (2 * math.pi / RESOLUTION) / LEROBOT_DEGREE  # LeRobot's degrees about the midpoint
        values[:, -1] = (q[:, -1] - lower) / (upper - lower) * 100     # the gripper 0..100
        rows.append((e, values))
    return write_dataset(root, rows, fps)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.lerobot", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    parser.add_argument("--jobs", type=int, default=JOBS, help=f"processes (default {JOBS})")
    args = parser.parse_args(argv)
    print(f"servodyn validate --lerobot: {EPISODES} episodes x {SECONDS:g} s at {FPS:g} fps, {args.jobs} jobs",
          flush=True)
    with tempfile.TemporaryDirectory(prefix="servodyn-lerobot-") as tmp:
        root = dataset(Path(tmp) / "dataset")
        load = os.getloadavg()[0]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "servodyn.tools.cli", "validate", "so101", "--lerobot", str(root),
                               "--jobs", str(args.jobs), "--out", str(Path(tmp) / "out")],
                              capture_output=True, text=True)
        seconds = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        if done.returncode not in (0, 1):
            print(done.stdout + done.stderr)
            return 1
        report = json.loads((Path(tmp) / "out" / "report.json").read_text())
    passed = sum(e["passed"] for e in report["episodes"])
    rows = {"seconds": seconds, "episodes": len(report["episodes"]), "passed": passed, "jobs": args.jobs,
            "cpu_s": cpu, "load_1min_before": load, "goal_s": GOAL_S}
    lines = ["| what | time | goal |", "|---|---:|---|",
             f"| validate {EPISODES} episodes × {SECONDS:g} s at {FPS:g} fps ({passed} pass), {args.jobs} jobs, the "
             f"whole command | {seconds:.2f} s | ≤ {GOAL_S:g} s: {'met' if seconds <= GOAL_S else 'NOT met'} |",
             f"| its CPU time, every process (user + system) | {cpu:.2f} s | |",
             "", f"load average (1 min) before the run: {load:.2f} on {os.cpu_count()} cores (a busy machine "
             "stretches the time, not the CPU time)"]
    publish(Path(args.out), "lerobot", "\n".join(lines), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
