"""`servodyn excite`: an exciting trajectory for `servodyn identify` (servodyn.identification's
Fourier series, Swevers et al.), written as a trajectory CSV that `servodyn swing --motion` plays
and `servodyn validate` checks.

The margin is kept twice: the series is shaped inside each joint's configured position limits
less `margin` of its range at both ends and below `speed_fraction` of its velocity limit; then the
validator checks the whole of it on the configuration (torque-speed envelope, current, heat,
supply, bus) and, while it fails, every excursion is scaled down by AMPLITUDE_STEP (the duration
and the rest at both ends stay)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..control.trajectory import MotionPath, Trajectory, write_trajectory_csv
from ..hal.config import load_config
from ..hal.errors import ConfigError
from ..identification import design_excitation
from ..identification.excitation import HARMONICS, MARGIN
from ..validation import judge

AMPLITUDE_STEP = 0.85      # the excursions' scale per failed validation
MAX_TRIES = 12             # 0.85^12 ≈ 0.14: a configuration still failing then is refused
SAMPLE_S = 0.005           # s between the CSV's rows (q, qd and qdd exact at each)


class ExciteError(Exception):
    """A one-line reason the command cannot go on (exit status 2)."""


def run(config_name: str, duration: float, dofs: list[str] | None, out: Path, harmonics: int = HARMONICS,
        margin: float = MARGIN, iterations: int = 10, seed: int = 0, say=print) -> int:
    try:
        config = load_config(config_name)
    except ConfigError as err:
        raise ExciteError(str(err)) from None
    model = config.model
    if not (math.isfinite(duration) and duration > 0):
        raise ExciteError(f"--duration must be a positive number of seconds, got {duration:g}")
    if not 0 <= margin < 0.5:
        raise ExciteError(f"--margin must be a fraction of each joint's range from 0 to 0.5, got {margin:g}")
    if harmonics < 2:
        raise ExciteError(f"--harmonics must be 2 or more (the last closes the rest at both ends), got {harmonics}")
    by_dof = {j.dof: j for j in config.joints}
    unknown = sorted(set(dofs or ()) - set(model.dof_names))
    if unknown:
        raise ExciteError(f"'{config.name}' has no joint '{unknown[0]}' ({', '.join(model.dof_names)})")
    missing = [d for d in model.dof_names if d not in by_dof]
    if missing:
        raise ExciteError(f"'{config.name}': no [[joint]] for dof {missing[0]}")
    joints = [by_dof[d] for d in model.dof_names]
    excited = [k for k, d in enumerate(model.dof_names) if dofs is None or d in dofs]
    lower = np.array([j.position_limits[0] for j in joints])
    upper = np.array([j.position_limits[1] for j in joints])
    speed = np.array([j.velocity_limit for j in joints])
    say(f"designing {duration:g} s of excitation for {len(excited)} joints of '{config.name}' "
        f"({harmonics} harmonics, condition number minimised)...")
    series, condition = design_excitation(model, lower, upper, speed, duration, excited=excited,
                                          harmonics=harmonics, margin=margin, iterations=iterations, seed=seed)
    factor = 1.0
    for _ in range(MAX_TRIES):
        trial = series.scaled(factor)
        judged = judge(config, MotionPath("excitation", trial.duration, trial.evaluate))
        if judged.passed:
            break
        say(f"  the validator refuses it at {factor:.2g} of its amplitude: {judged.violations[0]['message']}")
        factor *= AMPLITUDE_STEP
    else:
        raise ExciteError(f"'{config.name}': no excitation passes the validator even at {factor / AMPLITUDE_STEP:.2g} "
                          "of its amplitude (a joint too weak to move the arm?)")
    t = np.arange(0.0, trial.duration + SAMPLE_S / 2, SAMPLE_S)
    q, qd, qdd = trial.evaluate(t)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_trajectory_csv(out, Trajectory(t=t, q=q, qd=qd, qdd=qdd, derived=False), model.dof_names)
    periods = int(round(trial.duration * trial.base_hz))
    say(f"{trial.duration:g} s: {periods} period{'s' if periods > 1 else ''} of {1 / trial.base_hz:g} s, "
        f"harmonics up to {harmonics * trial.base_hz:.3g} Hz, condition number {condition:.3g}, "
        f"{factor:.2g} of the designed amplitude; passes servodyn validate on '{config.name}'")
    width = max(len(d) for d in model.dof_names)
    for k in excited:
        say(f"  {model.dof_names[k]:<{width}}  {math.degrees(q[:, k].min()):7.1f} to {math.degrees(q[:, k].max()):6.1f} deg, "
            f"peak {np.abs(qd[:, k]).max():.2f} rad/s")
    say(f"wrote {out} (play it: servodyn swing --config {config.argument} --motion {out})")
    return 0
