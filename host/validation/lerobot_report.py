"""A LeRobot dataset validated episode by episode, before any of it reaches a motor: each episode made a
motion (lerobot_motion), checked like any motion (`judge`: torque, duty or current, speed, heat over the
episode, ...) at the time scale asked (1: as recorded), and its fastest passing playback found
(`fit_time_scale`). One line per episode and `report.json`:

  {"dataset", "config", "feature", "units", "units_why", "time_scale", "cutoff_hz", "passed",
   "episodes": [{"episode_index", "passed", "worst_check", "worst_joint", "worst_ratio",
                 "fit_time_scale"}, ...]}

(the six keys of an episode are a contract). `worst_check` and `worst_joint` are the check and joint
nearest (or furthest past) what the check allows (ratio / allowed, as the validator's per-joint table
ranks them); `worst_ratio` its peak ratio to the limit; a whole-robot check (supply, bus) has
`worst_joint` null. `fit_time_scale` is the smallest uniform time scale at which every check passes
(< 1: the episode could play faster), null when none up to 64 does (or up to the 600 s a played motion
may last)."""

from __future__ import annotations

import json
import math
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..control.timing import MAX_PLAYED_DURATION
from ..errors import InputError
from ..hal.thermal import AMBIENT
from ..readable import fixed
from .checks import CHECKS, check, judge
from .fit import FIT_GRID
from .lerobot import read_dataset
from .lerobot_motion import CUTOFF_HZ, UNITS, check_cutoff, episode_motion, infer_units, joint_columns

REPORT_KEYS = ("episode_index", "passed", "worst_check", "worst_joint", "worst_ratio", "fit_time_scale")
MAX_JOBS = 256


def worst_of(result, dof_names) -> tuple[str, str | None, float]:
    """The check and joint nearest or furthest past what it allows, and the peak ratio there."""
    best = None
    for name in CHECKS:
        peaks = result.ratios[name].max(axis=0)
        for j, peak in enumerate(peaks):
            score = float(peak) / result.allowed(name)
            if best is None or score > best[0]:
                best = (score, name, dof_names[j] if len(peaks) > 1 else None, float(peak))
    return best[1], best[2], best[3]


FIT_TOLERANCE = 0.01        # an episode's fit time scale to 1 % (validate --fit's motion: 0.1 %)
SEARCH_SAMPLES, FIT_SAMPLES = 2, 4    # samples a frame: the fit's search, then its answer checked


TIMELESS = ("position", "bus")   # checks a time scale does not change


def score(result) -> float:
    """The worst of the checks a time scale changes, its peak over what it allows (≤ 1 passes them):
    the function of the scale the fit's search closes in on."""
    return max(float(result.ratios[name].max(initial=0.0)) / result.allowed(name)
               for name in CHECKS if name not in TIMELESS)


def fit_episode(model, limits, path, judged, margin: float, repeat: int, ambient: float, fps: float):
    """The smallest uniform time scale at which every check passes, to FIT_TOLERANCE, and how it was found.

    A recording's motion is band-limited (lerobot_motion's low-pass), so the checks sample it a few
    times a frame of its own clock rather than every control period: SEARCH_SAMPLES while searching,
    FIT_SAMPLES for the answer, which is raised by the tolerance until it passes (a sinusoid at the
    cutoff sampled 4 times a 30 Hz frame keeps its peak within 0.9 %). The search starts at the speed's
    bound (the speed ratio falls exactly as 1/s: no smaller scale passes) and closes a bracket by
    regula falsi (Illinois) on log(worst ratio) against log(scale), a few checks where fit_time_scale's
    scan and bisection take a dozen. A position or bus check that fails fails at every scale."""
    result, s0 = judged.result, judged.time_scale
    for name in TIMELESS:
        if result.ratios[name].max(initial=0.0) > result.allowed(name):
            return None, f"{name} fails at any time scale"
    first = max(FIT_GRID[0], float(result.ratios["speed"].max(initial=0.0)) * s0 / margin)
    last = min(FIT_GRID[1], MAX_PLAYED_DURATION / max(path.duration, 1e-9))    # what can be checked at all
    if first > last:
        return None, f"no time scale up to {last:.3g} passes"

    def at(scale, samples=SEARCH_SAMPLES):
        return score(check(model, limits, path.at_scale(scale, scale / (samples * fps)), margin, repeat, ambient))
    f0 = score(result)                             # the episode as asked: one end of the bracket already
    if f0 <= 1 and s0 > first:
        lo, f_lo, hi, f_hi = first, at(first), s0, f0
    else:
        lo, f_lo = max(first, s0), (f0 if s0 >= first else at(first))
        hi, f_hi = lo, f_lo
    while f_hi > 1:                                # the bracket: up by FIT_GRID's ratio until one passes
        lo, f_lo = hi, f_hi
        if hi >= last:
            return None, f"no time scale from {first:.3g} to {last:.3g} passes"
        hi = min(last, hi * (FIT_GRID[2] if f_hi < 2 else math.sqrt(f_hi)))   # far over: inertial torques fall as 1/s²
        f_hi = at(hi)
    keep_lo = keep_hi = 1.0                        # Illinois: the end kept twice has its value halved
    if f_lo <= 1:                                  # passes at the speed's bound: none smaller can
        hi = lo
    while hi / lo > 1 + FIT_TOLERANCE:
        x_lo, x_hi = np.log(lo), np.log(hi)
        y_lo, y_hi = np.log(f_lo) * keep_lo, np.log(f_hi) * keep_hi
        x = x_hi - y_hi * (x_hi - x_lo) / (y_hi - y_lo) if y_hi != y_lo else (x_lo + x_hi) / 2
        close = np.log1p(FIT_TOLERANCE) / 2       # a step that would land by an end lands half the tolerance in
        x = min(max(x, x_lo + close), x_hi - close)
        f = at(float(np.exp(x)))
        if f > 1:
            lo, f_lo, keep_lo, keep_hi = float(np.exp(x)), f, 1.0, keep_hi / 2
        else:
            hi, f_hi, keep_hi, keep_lo = float(np.exp(x)), f, 1.0, keep_lo / 2
    scale = hi
    while at(scale, FIT_SAMPLES) > 1:
        scale *= 1 + FIT_TOLERANCE
        if scale > last:
            return None, f"no time scale up to {last:.3g} passes"
    return scale, f"regula falsi to {FIT_TOLERANCE:.0%} from the speed's bound {first:.3g}"


def check_episode(config, path, time_scale: float, fps: float, margin: float = 1.0, repeat: int = 1,
                  ambient: float = AMBIENT) -> dict:
    """One episode's verdict (every check every control period, as `validate` checks any motion): the
    report's six keys (episode_index left to the caller), its duration and first violation's sentence."""
    judged = judge(config, path, time_scale, margin=margin, repeat=repeat, ambient=ambient)
    check_name, joint, ratio = worst_of(judged.result, config.model.dof_names)
    fit, _ = fit_episode(config.model, judged.limits, path, judged, margin, repeat, ambient, fps)
    return {"passed": judged.passed, "worst_check": check_name, "worst_joint": joint, "worst_ratio": ratio,
            "fit_time_scale": fit, "duration_s": path.duration * time_scale,
            "first_violation": judged.violations[0]["message"] if judged.violations else None}


_SHARED: dict = {}       # the parent's configuration, dataset and options, inherited by forked workers


def _one(k: int) -> dict:
    config, dataset, motion, options = (_SHARED[key] for key in ("config", "dataset", "motion", "options"))
    path = episode_motion(dataset.episodes[k], dataset, config, **motion)
    return {"episode_index": dataset.episodes[k].index, **check_episode(config, path, **options)}


def episode_line(row: dict) -> str:
    head = f"{'PASS' if row['passed'] else 'FAIL'} episode {row['episode_index']} ({row['duration_s']:.2f} s)"
    fit = row["fit_time_scale"]
    fit = f"fit time scale {fit:.3f}" if fit is not None else "no time scale up to 64 passes"
    joint = f"{row['worst_joint']} " if row["worst_joint"] else ""
    if row["passed"]:
        return f"{head}: nearest a limit {joint}{row['worst_check']} {fixed(row['worst_ratio'])}; {fit}"
    return f"{head}: {row['first_violation']}; worst {joint}{row['worst_check']} {fixed(row['worst_ratio'])}; {fit}"


def validate_dataset(config, root, *, feature: str = "action", units: str = "auto", episodes=None,
                     time_scale: float = 1.0, cutoff: float = CUTOFF_HZ, margin: float = 1.0,
                     repeat: int = 1, ambient: float = AMBIENT, jobs: int = 1, out: Path | None = None,
                     say=print) -> dict:
    """Every episode asked (default all) validated on `config`, over `jobs` forked processes; a line
    each as they finish in order, the report (written to OUT/report.json when `out`); its `code` is
    0 when every episode passes, 1 when one fails. A malformed dataset raises DatasetError (exit 2)
    before any episode is judged: every episode is read and checked first, then each is made a motion
    (lerobot_motion) and judged in a worker."""
    if not 1 <= jobs <= MAX_JOBS:
        raise InputError(f"--jobs must be from 1 to {MAX_JOBS} processes, got {jobs}")
    if units not in ("auto", *UNITS):
        raise InputError(f"--units must be auto, {' or '.join(UNITS)}, got '{units}'")
    if not (math.isfinite(margin) and margin > 0):
        raise InputError(f"--margin must be a positive fraction of each limit, got {margin}")
    if not math.isfinite(ambient) or ambient >= min(j.servo.temperature_limit for j in config.joints):
        raise InputError(f"--ambient must be a temperature below the servos' limits, got {ambient}")
    start = time.perf_counter()
    dataset = read_dataset(root, feature, episodes)
    where = str(dataset.root / "meta" / "info.json")
    columns = joint_columns(dataset.names, config, where)
    why = "given (--units)"
    if units == "auto":
        units, why = infer_units(dataset, columns, config)
    check_cutoff(cutoff, dataset.fps)       # every fault a dataset can have is found before the long work
    n = len(dataset.episodes)
    frames = sum(len(e.t) for e in dataset.episodes)
    say(f"validate LeRobot dataset {dataset.root} ({dataset.version or 'version unstated'}, {dataset.fps:g} fps): "
        f"{n} episode{'s' * (n != 1)}, {frames} frames of '{feature}' in {units} ({why}), on '{config.name}' at "
        f"time scale {time_scale:g}, low-pass {cutoff:g} Hz forwards and backwards; {min(jobs, n)} job"
        f"{'s' * (min(jobs, n) != 1)}")
    motion = {"columns": columns, "units": units, "cutoff": cutoff}
    if n:       # one episode made a motion here: the low-pass's imports load once, before the workers fork
        episode_motion(dataset.episodes[0], dataset, config, **motion)
    _SHARED.update(config=config, dataset=dataset, motion=motion,
                   options={"time_scale": time_scale, "fps": dataset.fps, "margin": margin, "repeat": repeat,
                            "ambient": ambient})
    rows = []
    if jobs > 1 and n > 1:
        with ProcessPoolExecutor(min(jobs, n), mp_context=multiprocessing.get_context("fork")) as pool:
            for row in pool.map(_one, range(n), chunksize=max(1, n // (4 * jobs))):
                rows.append(row)
                say(episode_line(row))
    else:
        for k in range(n):
            rows.append(_one(k))
            say(episode_line(rows[-1]))
    passed = all(r["passed"] for r in rows)
    report = {"dataset": str(dataset.root), "config": config.name, "feature": feature, "units": units,
              "units_why": why, "time_scale": time_scale, "cutoff_hz": cutoff, "passed": passed,
              "episodes": [{key: r[key] for key in REPORT_KEYS} for r in rows], "code": 0 if passed else 1}
    failed = sum(not r["passed"] for r in rows)
    tail = f"{n - failed} of {n} episodes pass ({time.perf_counter() - start:.1f} s)"
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "report.json").write_text(json.dumps({k: v for k, v in report.items() if k != "code"}, indent=1,
                                                    allow_nan=False) + "\n")
        tail += f"; wrote {out / 'report.json'}"
    say(tail)
    return report
