"""`servodyn excite`: an exciting trajectory for `servodyn identify` (servodyn.identification's
Fourier series, Swevers et al.), written as a trajectory CSV that `servodyn swing --motion` plays
and `servodyn validate` checks.

The margin is kept twice: the series is shaped inside each joint's configured position limits
less `margin` of its range at both ends and below `speed_fraction` of its velocity limit; then the
validator checks the whole of it on the configuration (torque-speed envelope, current, heat,
supply, bus) and, while it fails, every excursion is scaled down by AMPLITUDE_STEP (the duration
and the rest at both ends stay).

With `heat`, the run a heating identification needs instead (identification.heating): hold a pose
gravity loads, move to one where the arm hangs, rest there while the windings cool, each half a few
of the slowest configured τ_th by default. Safe by the validator's winding model: the whole run
passes `servodyn validate` and, on the configured thermal constants, every winding stays below its
ambient plus HEAT_SHARE of its headroom (temperature limit less ambient) — a real winding reaches its
limit only with twice the configured R_th, and then the servo's own Temperature Limit faults it
and the swing stops, torque off. While it does not, the hold pose is pulled towards the rest pose
by AMPLITUDE_STEP."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..control.trajectory import MotionPath, Trajectory, write_trajectory_csv
from ..errors import ServodynError
from ..hal.config import load_config
from ..hal.errors import ConfigError
from ..hal.thermal import AMBIENT
from ..identification import design_excitation
from ..identification.excitation import HARMONICS, MARGIN, ExcitationError, check_design
from ..identification.heating import HEAT_SHARE, design_heating
from ..outputs import refuse_input_as_output
from ..validation import Limits, check, describe, judge, violations

AMPLITUDE_STEP = 0.85      # the excursions' scale per failed validation
MAX_TRIES = 12             # 0.85^12 ≈ 0.14: a configuration still failing then is refused
SAMPLE_S = 0.005           # s between the CSV's rows (q, qd and qdd exact at each)
HEAT_CHECK_S = 0.02        # s between the samples a heating run is validated at (its move lasts a second
                           # or more; its holds are still): a run of an hour stays a few MB of checks


class ExciteError(ServodynError):
    """A one-line reason the command cannot go on (exit status 2)."""


DEFAULT_DURATION = 30.0    # s of excitation (a heating run's default comes from the thermal constants)


def run(config_name: str, duration: float | None, dofs: list[str] | None, out: Path, harmonics: int = HARMONICS,
        margin: float = MARGIN, iterations: int = 10, seed: int = 0, heat: bool = False, say=print) -> int:
    try:
        config = load_config(config_name)
    except ConfigError as err:
        raise ExciteError(str(err)) from None
    refuse_input_as_output(out, "--out", {"--config": config.path})
    model = config.model
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise ExciteError(f"--duration must be a positive number of seconds, got {duration:g}")
    if not 0 <= margin < 0.5:
        raise ExciteError(f"--margin must be a fraction of each joint's range from 0 to 0.5, got {margin:g}")
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
    if heat:
        return _heating(config, excited, duration, out, margin, seed, say)
    duration = DEFAULT_DURATION if duration is None else duration
    try:
        check_design(duration, harmonics)
    except ExcitationError as err:
        raise ExciteError(f"--duration {duration:g} with --harmonics {harmonics}: {err}") from None
    say(f"designing {duration:g} s of excitation for {len(excited)} joints of '{config.name}' "
        f"({harmonics} harmonics, condition number minimised)...")
    series, condition = design_excitation(
        model, lower, upper, speed, duration, excited=excited, harmonics=harmonics, margin=margin,
        iterations=iterations, seed=seed, progress=lambda i, n, c: say(f"  iteration {i}/{n}: condition number {c:.3g}"))
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


def _heating(config, heated: list[int], duration: float | None, out: Path, margin: float, seed: int, say) -> int:
    """The heating run (identification.heating), validated on the configuration: whole, and every
    winding within HEAT_SHARE of its headroom on the configured thermal constants."""
    model = config.model
    limits = Limits.of(config, config.supply.voltage)
    modelled = [k for k in heated if limits.thermal_resistance[k] > 0]
    if not modelled:
        raise ExciteError(f"'{config.name}': no joint to heat has thermal constants (thermal_resistance_k_w)")
    headroom = limits.temperature - AMBIENT
    try:
        plan = design_heating(model, limits.lower, limits.upper, limits.speed, limits.torque_constant * limits.gear,
                              limits.resistance, limits.thermal_resistance, limits.thermal_time_constant, headroom,
                              duration, heated=modelled, margin=margin, seed=seed)
    except ValueError as err:
        raise ExciteError(f"'{config.name}': {err}") from None
    say(f"designing a heating run of {plan.duration:g} s for {len(modelled)} joints of '{config.name}': hold "
        f"{plan.hold_s:g} s, move {plan.move_s:.3g} s, rest {plan.rest_s:g} s...")
    factor = 1.0
    for _ in range(MAX_TRIES):
        trial = plan.pulled(factor)
        path = MotionPath("heating", trial.duration, trial.evaluate)
        result = check(model, limits, path.at_scale(1.0, HEAT_CHECK_S))
        share = (result.temperature.max(axis=0) - AMBIENT) / headroom
        if result.passed and share.max() <= HEAT_SHARE:
            break
        found = violations(result, model.dof_names)
        hottest = int(np.argmax(share))
        why = describe(found[0], config, limits, 1, 1.0) if found else (
            f"{model.dof_names[hottest]}'s winding reaches {result.temperature[:, hottest].max():.0f} °C, "
            f"over {HEAT_SHARE:.0%} of its headroom")
        say(f"  refused with the hold pose at {factor:.2g} of the way from the rest pose: {why}")
        factor *= AMPLITUDE_STEP
    else:
        raise ExciteError(f"'{config.name}': no heating run passes the validator even with the hold pose at "
                          f"{factor / AMPLITUDE_STEP:.2g} of the way from the rest pose")
    # the samples above are HEAT_CHECK_S apart; the validator's own verdict, at the control period
    judged = judge(config, MotionPath("heating", trial.duration, trial.evaluate))
    if not judged.passed:
        raise ExciteError(f"'{config.name}': the heating run fails servodyn validate: {judged.violations[0]['message']}")
    knots = trial.knots
    q, qd, qdd = trial.evaluate(knots)
    write_trajectory_csv(out, Trajectory(t=knots, q=q, qd=qd, qdd=qdd, derived=False), model.dof_names)
    width = max(len(d) for d in model.dof_names)
    say(f"{trial.duration:g} s: passes servodyn validate on '{config.name}'; on its thermal constants each "
        f"winding stays within {HEAT_SHARE:.0%} of its headroom (a real winding reaches its limit only with about twice "
        "the configured R_th; then the servo's Temperature Limit faults it and the swing stops, torque off)")
    for k in modelled:
        say(f"  {model.dof_names[k]:<{width}}  hold {math.degrees(trial.hold[k]):7.1f} deg, "
            f"{limits.thermal_time_constant[k]:g} s τ_th: {result.temperature[:, k].max():5.1f} °C predicted "
            f"(limit {limits.temperature[k]:g} °C)")
    say(f"wrote {out} (play it: servodyn swing --config {config.argument} --motion {out}; then servodyn identify "
        f"--config {config.argument} RUN/swing_log.csv)")
    return 0
