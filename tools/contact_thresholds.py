"""`servodyn contact`: the contact observer's per-joint thresholds from clean runs.

Each motion is played `runs` times on the configuration's buses (the simulated ones unless it has
a port) with the contact guard off; a momentum observer that watches nothing is fed every tick
(servodyn.control.contact) and its residual kept. The thresholds are the margin times the largest
residual of each joint over every run (`thresholds_from_clean`); they are shown, then written to
the configuration's `[safety] contact_threshold_nm` after asking (a built-in configuration's copy
goes to a file of the user's; comments kept: hal.config_patch).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..control.contact import DEFAULT_MARGIN, thresholds_from_clean
from ..errors import ServodynError
from ..hal.config import load_config
from ..hal.config_patch import ConfigPatch
from ..hal.errors import ConfigError
from ..loop.contact import contact_observer
from ..loop.run import RunOptions
from ..report.swing import play


class CalibrationError(ServodynError):
    """A run that was to be clean stopped: thresholds cannot come from it."""
    exit_code = 1


def calibrate(config_arg: str, motions, runs: int, margin: float = DEFAULT_MARGIN, out: Path = Path("out/contact"),
              port=None, write_to: str | None = None, confirm=None, say=print) -> int:
    config = load_config(config_arg)
    quiet = replace(config, safety=replace(config.guards, contact=False))    # the guard must not stop a clean run
    residual_runs, names = [], config.model.dof_names
    for motion in motions or [config.swing_motion]:
        for k in range(runs):
            observer = contact_observer(config, watching=False)
            residual = []

            def feed(t, q_d, state, tau, observer=observer, residual=residual):
                if not residual:
                    observer.reset(state.q, state.qd)
                residual.append(observer.update(t, state.q, state.qd, state.tau).copy())

            say(f"{motion}: clean run {k + 1} of {runs} ...")
            summary = play(quiet, RunOptions(motion=motion, port=port), out / f"{Path(motion).stem}-{k + 1}",
                           say=lambda *a, **kw: None, observer=feed, figure=False)
            if summary["stop_reason"] != "completed":
                raise CalibrationError(f"{motion}: run {k + 1} stopped ({summary['stop_reason']}: {summary['error']}): "
                                       "thresholds come from runs that complete cleanly")
            residual_runs.append(np.array(residual))
            peak = np.abs(residual_runs[-1]).max(axis=0)
            say(f"  largest residual {peak.max():.3f} N m ({names[int(np.argmax(peak))]})")
    thresholds = thresholds_from_clean(residual_runs, margin)
    peaks = np.max([np.abs(r).max(axis=0) for r in residual_runs], axis=0)
    say(f"\n  {'joint':<24} {'largest |r| (N m)':>18} {'threshold (N m)':>16}")
    for name, p, th in zip(names, peaks, thresholds):
        say(f"  {name:<24} {p:>18.3f} {th:>16.3f}")
    say(f"  ({len(residual_runs)} clean runs, margin {margin:g})")
    try:
        patch = ConfigPatch.of(config, write_to)
        patch.set_table("safety", contact_threshold_nm={n: float(v) for n, v in zip(names, thresholds)})
        return patch.offer(confirm or (lambda question: False), say)
    except (ConfigError, OSError) as err:
        raise CalibrationError(str(err)) from None
