"""`make bench`, identification: how long `servodyn identify`'s estimation takes on a 30 s log at
1 kHz (filtering, differentiation, decimation, the batched regressor, base parameters, OLS and
WLS), and what the core's regressor costs per sample beside one RNEA (a ratio, both batched in one
C call over the same states). Each is the median of `--reps` runs.

Goal: the 30 s log identified in ≤ 1 s. The log is made with the core's direct dynamics on the
replica with a payload, friction, armature and torque-constant scales, its sensors quantised
(servodyn.identification.synthetic), not timed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ...hal.config import load_config
from ...identification import design_excitation, identify, measured_torque, prepare
from ...identification.synthetic import Plant, simulate_log
from .loop import publish
from .validate import timed

ROOT = Path(__file__).resolve().parents[2]
GOALS = {"identify_s": 1.0}
DURATION = 30.0
BATCH = 1500


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.identify",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5, help="runs of each (default 5)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    config = load_config("replica")
    model = config.model
    joints = [{j.dof: j for j in config.joints}[d] for d in model.dof_names]
    print(f"servodyn identification: a {DURATION:g} s log at 1 kHz of the replica (made first, not timed)", flush=True)
    lower = np.array([j.position_limits[0] for j in joints])
    upper = np.array([j.position_limits[1] for j in joints])
    speed = np.array([j.velocity_limit for j in joints])
    excitation, _ = design_excitation(model, lower, upper, speed, DURATION, iterations=4)
    n = model.nv
    plant = Plant(payload_kg=0.3, coulomb=np.full(n, 0.1), viscous=np.full(n, 0.1), armature=model.armature * 1.2,
                  torque_scale=np.full(n, 1.1))
    log = simulate_log(model, joints, excitation.evaluate, DURATION, plant)

    def run():
        prepared = prepare(log["t"], log["q"], measured_torque(log["current"], joints))
        return identify(model, joints, [prepared])
    whole, estimate = timed(run, args.reps)
    # the regressor against one RNEA per sample, over the same 1 500 states (a 30 s log's decimated
    # samples), 20 calls a run: Y is 490 numbers a sample where the RNEA gives 7, so a batch much
    # larger measures the memory it fills rather than the arithmetic
    rng = np.random.default_rng(1)
    q, qd, qdd = rng.uniform(-1, 1, size=(3, BATCH, n))
    regressor, _ = timed(lambda: [model.regressor(q, qd, qdd) for _ in range(20)], args.reps)
    rnea, _ = timed(lambda: [model.inverse_dynamics(q, qd, qdd) for _ in range(20)], args.reps)
    regressor, rnea = regressor / 20, rnea / 20
    rows = {"identify_s": whole, "log_samples": len(log["t"]), "equations": estimate.rows,
            "regressor_us_per_sample": regressor / len(q) * 1e6, "rnea_us_per_sample": rnea / len(q) * 1e6,
            "regressor_over_rnea": regressor / rnea}
    lines = [
        "| what | time | goal |", "|---|---:|---|",
        f"| identify a {DURATION:g} s log at 1 kHz ({rows['log_samples']} samples, {rows['equations']} equations) "
        f"| {whole:.3f} s | ≤ {GOALS['identify_s']:g} s: {'met' if whole <= GOALS['identify_s'] else 'NOT met'} |",
        f"| regressor ({n} x {10 * model.nbody}) per sample, batched | {rows['regressor_us_per_sample']:.2f} µs | |",
        f"| RNEA per sample, batched | {rows['rnea_us_per_sample']:.2f} µs | |",
        "", f"regressor / RNEA: {rows['regressor_over_rnea']:.1f}x"]
    publish(Path(args.out), "identify", "\n".join(lines), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
