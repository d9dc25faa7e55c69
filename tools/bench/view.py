"""`make bench`, the live view: the swing on the simulated Dynamixel bus with and without
`servodyn swing --view`'s feed (the loop's observer keeps each tick's state; the viewer's own thread
draws it, decimated to at most PUBLISH_HZ frames a second). The runs alternate, so both see the same
machine; the table gives the loop's rate in each (median and range of `--reps` runs), their ratio,
and the frames a second the page was sent. Writes out/bench/view.json and out/bench/view.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .loop import ROOT, publish
from ...loop.run import RunOptions
from ...report.swing import play
from ...view import PUBLISH_HZ, live_viewer


def measure(reps: int, realtime: bool) -> dict:
    rows = {"without the view": [], "with the view": []}
    viewer, _ = live_viewer("replica", http_port=0, say=lambda *a, **k: None)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(reps):
                for name in rows:
                    print(f"  {name}, run {r + 1} of {reps} ...", flush=True)
                    feed = viewer.live() if name == "with the view" else None
                    began = time.perf_counter()
                    s = play("replica", RunOptions(realtime=realtime), Path(tmp) / f"{r}{len(name)}",
                             say=lambda *a, **k: None, observer=feed.observe if feed else None)
                    seconds = time.perf_counter() - began
                    if feed is not None:
                        feed.stop()
                    if not s["completed"]:
                        sys.exit(f"bench: the swing {name} did not complete: {s.get('error')}")
                    rows[name].append({"loop_hz": s["loop_hz"], "jitter_p99_ms": s["jitter_p99_ms"],
                                       "frames_per_s": feed.frames / seconds if feed else None})
    finally:
        viewer.close()
    return rows


def table(rows: dict, realtime: bool) -> str:
    def cell(values, fmt):
        values = sorted(values)
        return fmt.format(np.median(values)) + (f" ({fmt.format(values[0])}–{fmt.format(values[-1])})"
                                                if len(values) > 1 else "")
    lines = [f"| {'real time' if realtime else 'lock-step'} | loop (Hz) | jitter p99 (ms) | frames/s drawn |",
             "|---|---:|---:|---:|"]
    for name, runs in rows.items():
        frames = [r["frames_per_s"] for r in runs if r["frames_per_s"] is not None]
        lines.append(f"| {name} | {cell([r['loop_hz'] for r in runs], '{:.0f}')} | "
                     f"{cell([r['jitter_p99_ms'] for r in runs], '{:.3f}')} | "
                     f"{cell(frames, '{:.1f}') if frames else '—'} |")
    without = np.median([r["loop_hz"] for r in rows["without the view"]])
    with_view = np.median([r["loop_hz"] for r in rows["with the view"]])
    lines += ["", f"loop rate with the view / without: {with_view / without:.2f} (the page's thread draws at most "
                  f"{PUBLISH_HZ:g} frames a second; on a shared machine the runs' own spread is of the same order)"]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.view", description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=3, help="runs with and without the view (default 3)")
    parser.add_argument("--realtime", action="store_true", help="pace the loop at 1 kHz (default lock-step)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    print(f"servodyn live view: the replica's swing on the simulated bus with and without the view's feed, "
          f"{os.cpu_count()} cpus", flush=True)
    rows = measure(args.reps, args.realtime)
    publish(Path(args.out), "view", table(rows, args.realtime), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
