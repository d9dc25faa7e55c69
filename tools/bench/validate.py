"""`make bench`, the offline validator: how long validating the forehand takes, and its TOPP-RA
retime beside toppra's own planning time on the same path (each the median of `--reps` runs).

Goals on the 2-core machine: validating the 1.8 s swing at 1 kHz (1801 samples, every check)
≤ 50 ms; the TOPP-RA retime, dense re-check included, ≤ 2 s.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ...control.motion import motion_path
from ...hal.config import load_config
from ...validation import Limits, check, retime
from .loop import publish

ROOT = Path(__file__).resolve().parents[2]
GOALS = {"validate_ms": 50.0, "retime_s": 2.0}


def timed(fn, reps: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(reps):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.validate",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=7, help="runs of each (default 7)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    config = load_config("replica")
    model = config.model
    path = motion_path("tennis_forehand", model)
    limits = Limits.of(config, config.supply.voltage)
    print("servodyn validator: the replica's forehand", flush=True)
    whole, result = timed(lambda: check(model, limits, path.at_scale(1.0)), args.reps)
    rnea, _ = timed(lambda: model.inverse_dynamics(*(lambda t: (t.q, t.qd, t.qdd))(path.at_scale(1.0))), args.reps)
    import toppra  # noqa: F401  (imported before the clock starts)
    plan, (traj, _, info) = timed(lambda: retime(model, limits, path, 1.0, 1, 25.0), max(1, args.reps // 2))
    rows = {
        "validate_ms": whole * 1e3, "samples": len(result.t), "sample_and_rnea_ms": rnea * 1e3,
        "retime_s": plan, "retime_duration_s": info["duration_s"] if traj is not None else None,
        "retime_tries": info["tries"] if traj is not None else None,
        "toppra_s": info["toppra_s"], "toppra_rnea_s": info["rnea_s"],
    }
    lines = [
        "| what | time | goal |", "|---|---:|---|",
        f"| validate the 1.8 s swing, {rows['samples']} samples, every check | {rows['validate_ms']:.1f} ms | "
        f"≤ {GOALS['validate_ms']:g} ms: {'met' if rows['validate_ms'] <= GOALS['validate_ms'] else 'NOT met'} |",
        f"| of which sampling + batched RNEA | {rows['sample_and_rnea_ms']:.1f} ms | |",
        f"| TOPP-RA retime ({rows['retime_tries']} plan(s)) + dense re-check | {rows['retime_s']:.2f} s | "
        f"≤ {GOALS['retime_s']:g} s: {'met' if rows['retime_s'] <= GOALS['retime_s'] else 'NOT met'} |",
        f"| of which toppra's own planning / servodyn's RNEA inside it | {rows['toppra_s']:.3f} s / "
        f"{rows['toppra_rnea_s']:.3f} s | |",
        "", f"retimed swing: {rows['retime_duration_s']:.3f} s (as written 1.800 s)"]
    publish(Path(args.out), "validate", "\n".join(lines), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
