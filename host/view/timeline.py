"""What the page shows, without a browser: the subject (a configuration or a model), and a
`Timeline` of samples on one clock — the planned arm, the measured one of a logged run, the joint
torques and each torque's share of its servo's limit — from a motion, a trajectory or a run's log."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..control.motion import Motion
from ..control.timing import SMALL_TIME_STEP
from ..errors import ServodynError
from ..hal.config import builtin_configs, load_config
from ..hal.errors import ConfigError
from ..loop.log import RunLogError, read_run_log
from ..model import ModelError, builtin_models, load_model
from ..model.files import read_toml
from ..validation import Limits, check, torque_speed_ratio


class ViewError(ServodynError, ValueError):
    """Bad input to the view: one line."""


@dataclass
class Timeline:
    """Samples on one clock: the planned arm, the measured one (a logged run), the joint torques
    and each torque's share of its servo's limit."""
    t: np.ndarray                    # (N,) s
    planned: np.ndarray              # (N, nq) rad
    tau: np.ndarray                  # (N, nv) N m
    share: np.ndarray                # (N, nv) of the servo's limit (or of the motion's peak)
    measured: np.ndarray | None = None
    share_of: str = "the servo's torque-speed limit"

    def index(self, t: float) -> int:
        return int(np.clip(np.searchsorted(self.t, t), 0, len(self.t) - 1))


def load_subject(spec: str | None):
    """(config or None, model) from a configuration or a model, by name or file."""
    spec = spec or "replica"
    is_model = spec not in builtin_configs() and spec in builtin_models() or str(spec).lower().endswith(".urdf")
    if not is_model and str(spec).lower().endswith(".toml") and spec not in builtin_configs():
        try:
            is_model = "body" in read_toml(Path(spec), ModelError)
        except FileNotFoundError:
            raise ViewError(f"{spec}: no such file") from None
    if not is_model and spec not in builtin_configs() and not Path(spec).exists():
        raise ViewError(f"{spec}: no such file, and not a built-in configuration ({', '.join(builtin_configs())}) "
                        f"or model ({', '.join(builtin_models())})")
    try:
        if is_model:
            return None, load_model(spec)
        config = load_config(spec)
        return config, config.model
    except (ModelError, ConfigError) as err:
        raise ViewError(str(err)) from None


def limits_of(config):
    if config is None:
        return None
    return Limits.of(config, config.supply.voltage)


def _own_peak_share(tau: np.ndarray) -> np.ndarray:
    peak = np.abs(tau).max(axis=0)
    return np.abs(tau) / np.where(peak > 0, peak, 1.0)


def motion_timeline(model, config, motion: Motion, time_scale: float):
    """The motion sampled every control period at the time scale, its torques (one batched RNEA)
    and, with a configuration, the validator's verdict: (timeline, result or None, limits)."""
    period = SMALL_TIME_STEP if config is None else config.control_period
    return trajectory_timeline(model, config, motion.path.at_scale(time_scale, period))


def trajectory_timeline(model, config, traj):
    """(timeline, the validator's result or None, limits or None) of a sampled trajectory."""
    limits = limits_of(config)
    if limits is None:
        tau = model.inverse_dynamics(traj.q, traj.qd, traj.qdd)
        return Timeline(traj.t, traj.q, tau, _own_peak_share(tau), share_of="the motion's peak"), None, None
    result = check(model, limits, traj)
    return Timeline(traj.t, traj.q, result.tau, result.ratios["torque_speed"]), result, limits


def log_timeline(model, config, folder: Path) -> Timeline:
    """A logged run (DIR/swing_log.csv, as servodyn swing writes it)."""
    try:
        log = read_run_log(folder, model, need=("q_d", "q", "qd", "tau"))
    except RunLogError as err:
        raise ViewError(str(err)) from None
    t, tau, qd = log.t, log.tau, log.qd
    limits = limits_of(config)
    if limits is None:
        share, share_of = _own_peak_share(tau), "the run's peak"
    else:
        share, share_of = torque_speed_ratio(limits, tau, qd)[0], "the servo's torque-speed limit"
    return Timeline(t, log.q_d, tau, share, measured=log.q, share_of=share_of)


def share_rgb(share: float) -> tuple[int, int, int]:
    """Green at no load, yellow at half the limit, red at and past it."""
    s = float(np.clip(share, 0.0, 1.0))
    if s < 0.5:
        return (int(60 + 390 * s), 200, 60)
    return (255, int(200 - 340 * (s - 0.5)), 40)
