"""`make bench`, many motions and sizing: `servodyn validate` over many motions at --jobs 1 and 2
(motions per second, as the command runs them: reports and plots written), and `servodyn size` on
the replica's model with the forehand against the whole catalogue (--family any, every supply
voltage the catalogue names).

Goals on the 2-core machine: ≥ 1.8× the motions per second at 2 jobs as at 1 (a ratio in one run,
which the machine's speed does not move); sizing ≤ 5 s.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from ...hal.config import load_config
from ...report.sizing import run_size
from ...report.validation import validate_many
from .loop import publish

ROOT = Path(__file__).resolve().parents[2]
GOALS = {"speedup_2_jobs": 1.8, "size_s": 5.0}
QUIET = dict(say=lambda *a, **k: None)


def motions_per_second(config, motions, jobs: int) -> float:
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        validate_many(config, motions, jobs=jobs, out=Path(folder), **QUIET)
        return len(motions) / (time.perf_counter() - start)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.size", description=__doc__.splitlines()[0])
    parser.add_argument("--motions", type=int, default=8, help="forehands validated per run (default 8)")
    parser.add_argument("--reps", type=int, default=3, help="runs of each, the best kept (default 3)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    config = load_config("replica")
    motions = ["tennis_forehand"] * args.motions
    print(f"servodyn validate, {args.motions} forehands on the replica, --jobs 1 and 2", flush=True)
    rate = {jobs: max(motions_per_second(config, motions, jobs) for _ in range(args.reps)) for jobs in (1, 2)}
    speedup = rate[2] / rate[1]
    scale = config.swing_time_scale
    print(f"servodyn size replica --motion tennis_forehand --time-scale {scale:g} --family any", flush=True)
    sizes = []
    for _ in range(args.reps):
        start = time.perf_counter()
        report = run_size("replica", ["tennis_forehand"], time_scale=scale, family="any", out=None, **QUIET)
        sizes.append(time.perf_counter() - start)
    size_s = min(sizes)
    rows = {"motions": args.motions, "motions_per_s_1_job": rate[1], "motions_per_s_2_jobs": rate[2],
            "speedup_2_jobs": speedup, "size_s": size_s, "size_passed": report["passed"],
            "size_servo_mass_kg": report.get("servo_mass_kg"), "size_voltage": report["supply_voltage"]}
    met = lambda ok: "met" if ok else "NOT met"
    lines = ["| what | figure | goal |", "|---|---:|---|",
             f"| validate, {args.motions} forehands, 1 job | {rate[1]:.2f} motions/s | |",
             f"| validate, {args.motions} forehands, 2 jobs | {rate[2]:.2f} motions/s ({speedup:.2f}×) | "
             f"≥ {GOALS['speedup_2_jobs']:g}×: {met(speedup >= GOALS['speedup_2_jobs'])} |",
             f"| size the replica for the forehand at {scale:g}×, whole catalogue, every voltage | {size_s:.2f} s | "
             f"≤ {GOALS['size_s']:g} s: {met(size_s <= GOALS['size_s'])} |"]
    publish(Path(args.out), "size", "\n".join(lines), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
