"""`make bench`, the control loop: the swing on the simulated Dynamixel bus, timed.

What the test suite must not assert (it depends on the machine and its neighbours) is measured
here: the loop's rate and period jitter, in lock-step (as fast as the bus answers) and in real
time (paced at small_time_step against the 1 kHz target), and the loop thread's CPU per tick.
Each configuration runs `--reps` times; the table gives the median and the range. Writes
out/bench/loop.json and out/bench/loop.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..control.timing import SMALL_TIME_STEP
from .swing import run_swing

ROOT = Path(__file__).resolve().parents[1]
RUNS = (("lock-step", dict(realtime=False)), ("real time", dict(realtime=True)))
FIGURES = (("loop_hz", "loop (Hz)", "{:.0f}"), ("period_median_ms", "period median (ms)", "{:.3f}"),
           ("jitter_p99_ms", "jitter p99 (ms)", "{:.3f}"), ("cpu_median_ms", "CPU/tick median (ms)", "{:.3f}"),
           ("cpu_p99_ms", "CPU/tick p99 (ms)", "{:.3f}"), ("tracking_max_deg", "tracking max (deg)", "{:.3f}"))


def measure(reps: int) -> dict:
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, options in RUNS:
            rows = []
            for r in range(reps):
                print(f"  {name}, run {r + 1} of {reps} ...", flush=True)
                s = run_swing(out=Path(tmp) / f"{name}{r}", say=lambda *a, **k: None, **options)
                if not s["completed"]:
                    sys.exit(f"bench: the {name} swing did not complete: {s.get('error')}")
                rows.append({"loop_hz": s["loop_hz"], "period_median_ms": s["period_median_ms"],
                             "jitter_p99_ms": s["jitter_p99_ms"], "cpu_median_ms": s["cpu_ms_per_tick"]["median"],
                             "cpu_p99_ms": s["cpu_ms_per_tick"]["p99"],
                             "tracking_max_deg": float(np.degrees(s["tracking_max_rad"]))})
            results[name] = rows
    return results


def table(results: dict) -> str:
    lines = ["| run | " + " | ".join(label for _, label, _ in FIGURES) + " |",
             "|---|" + "---:|" * len(FIGURES)]
    for name, rows in results.items():
        cells = []
        for key, _, fmt in FIGURES:
            values = sorted(row[key] for row in rows)
            median = float(np.median(values))
            cells.append(fmt.format(median) + (f" ({fmt.format(values[0])}–{fmt.format(values[-1])})"
                                               if len(values) > 1 else ""))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    target = 1 / SMALL_TIME_STEP
    realtime = float(np.median([row["loop_hz"] for row in results["real time"]]))
    lines += ["", f"real time against the {target:.0f} Hz target: {realtime / target:.2f} "
                  f"({'met' if realtime >= 0.99 * target else 'NOT met'})"]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench_loop", description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=3, help="runs of each configuration (default 3)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    print(f"servodyn control loop: the replica's swing on the simulated bus, {os.cpu_count()} cpus", flush=True)
    results = measure(args.reps)
    publish(Path(args.out), "loop", table(results), results)
    return 0


def publish(out: Path, stem: str, text: str, data) -> None:
    """Print a bench section's table and write it as OUT/STEM.md with its numbers in OUT/STEM.json."""
    print("\n" + text)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(text + "\n")
    (out / f"{stem}.json").write_text(json.dumps(data, indent=1) + "\n")
    print(f"\nwrote {out / (stem + '.md')}, {out / (stem + '.json')}")


if __name__ == "__main__":
    sys.exit(main())
