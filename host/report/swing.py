"""A run reported: the tracking table printed and the tracking figure drawn (`report_run`), and a run
of a configuration on its buses, real or simulated, played and reported in one call (`play`): what
`servodyn swing`, validate's simulation, the soak and the benchmarks share.

    summary = play("replica", RunOptions(time_scale=4), Path("out/swing"))
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..hal.backend import joint_sensors
from ..hal.config import RobotConfig
from ..loop import CHATTER_CUTOFF_HZ, RunLog
from ..loop.run import Run, RunOptions
from ..sim.serve import serve, simulated_arm
from .plots import tracking_figure


def play(config: str | RobotConfig, options: RunOptions, out: Path, *, say=print, confirm=None, observer=None,
         log: RunLog | None = None, figure: bool = True) -> dict:
    """Run `config` with `options` (servodyn.loop.run) — its simulated buses, where it has no port,
    served by servodyn.sim.serve — and report it in OUT; the summary."""
    run = Run(config, options, serve=serve, say=say, confirm=confirm, observer=observer, log=log, arm=simulated_arm)
    summary = run.play(Path(out))
    report_run(Path(out), run.log, summary, run.config, say, figure)
    return summary


def title(summary: dict, config: RobotConfig | None) -> str:
    """The figure's title: what played, where, and under which control (PD only says so); a dry
    run says it sent nothing, a stopped run what stopped it."""
    control = "PD only, no feed-forward" if summary.get("mode") == "pd" else "feed-forward + PD"
    where = config.name if config is not None else "the servo bus"
    if summary.get("dry_run"):
        return f"dry run: torque off — homing to {summary['motion']} on {where}, its planned torques (none sent)"
    stopped = summary.get("stop_reason")
    return (f"{summary['motion']} on {where}: {control}"
            + (f" — stopped: {stopped.replace('_', ' ')}" if stopped not in (None, "completed") else ""))


def report_run(out: Path, log: RunLog, summary: dict, config: RobotConfig | None, say=print,
               figure: bool = True) -> None:
    """The run's table (tracking error and chatter per joint, the goal, the loop's timing) and,
    with `figure`, OUT/swing_tracking.png; then one line naming every file the run wrote."""
    files = [out / "swing_log.csv", out / "summary.json"]
    if log.t:
        say(table(log, summary, [j.torque_limit for j in config.joints] if config is not None else None))
        if figure:
            limits = [j.torque_limit for j in config.joints] if config is not None else None
            steps = list(joint_sensors(config).position_step) if config is not None else None
            tracking_figure(out / "swing_tracking.png", np.array(log.t), np.array(log.q_d), np.array(log.q),
                            np.array(log.tau), log.dof_names, title(summary, config), limits, steps)
            files.append(out / "swing_tracking.png")
    say("wrote " + ", ".join(str(f) for f in files))


def table(log: RunLog, summary: dict, torque_limits=None) -> str:
    """Per joint: the tracking error's rms and max, the torque's part above CHATTER_CUTOFF_HZ; the
    goal and whether it was met (no verdict for a dry run, which sends nothing and so cannot track,
    or for a run a fault stopped); the loop's rate, jitter and CPU time."""
    if summary.get("dry_run"):
        return dry_run_table(log, summary, torque_limits)
    e = np.array(log.q_d) - np.array(log.q)
    buzz = summary.get("chatter_by_dof") or {}
    lines = [f"\n  {'':<24} {'tracking error':>21}   {'torque above ' + format(CHATTER_CUTOFF_HZ, 'g') + ' Hz':>25}",
             f"  {'dof':<24} {'rms (deg)':>10} {'max (deg)':>10}   {'rms/peak (%)':>12} {'p-p (N m)':>12}"]
    for k, name in enumerate(log.dof_names):
        noise = (f"{100 * buzz[name]['rms_share']:>12.2f} {buzz[name]['peak_to_peak_nm']:>12.3f}"
                 if name in buzz else f"{'-':>12} {'-':>12}")
        lines.append(f"  {name:<24} {np.degrees(np.sqrt(np.mean(e[:, k]**2))):>10.3f} "
                     f"{np.degrees(np.abs(e[:, k]).max()):>10.3f}   {noise}")
    stopped = summary.get("stop_reason")
    if stopped not in (None, "completed"):
        lines.append(f"  goal: no verdict: the run stopped ({stopped.replace('_', ' ')}, exit "
                     f"{summary.get('exit_code')})")
    elif summary.get("chatter_max") is not None:
        met = (summary["chatter_max"] <= summary["chatter_goal"]
               and summary["tracking_max_rad"] <= summary["tracking_goal_rad"])
        lines.append(f"  goal: chatter <= {100 * summary['chatter_goal']:g} % of each joint's peak torque (worst "
                     f"{100 * summary['chatter_max']:.2f} %) with the largest error <= "
                     f"{np.degrees(summary['tracking_goal_rad']):g} deg (worst "
                     f"{np.degrees(summary['tracking_max_rad']):.3f} deg): {'met' if met else 'not met'}")
    cpu = summary["cpu_ms_per_tick"]
    lines.append(f"\n  loop {summary['loop_hz']:.0f} Hz, {summary['clock']} (period median "
                 f"{summary['period_median_ms']:.3f} ms, p99 jitter {summary['jitter_p99_ms']:.3f} ms; CPU per tick "
                 f"median {cpu['median']:.3f} ms, p99 {cpu['p99']:.3f} ms); tracking rms "
                 f"{np.degrees(summary['tracking_rms_rad']):.3f} deg, max "
                 f"{np.degrees(summary['tracking_max_rad']):.3f} deg")
    return "\n".join(lines)


def dry_run_table(log: RunLog, summary: dict, torque_limits=None) -> str:
    """A dry run's table: per joint how far the homing moves it and the planned torque (the
    feed-forward's) against its limit; no tracking verdict (nothing was sent, nothing could track)."""
    q_d = np.array(log.q_d)
    peak = np.abs(np.array(log.tau)).max(axis=0)
    limits = np.full(len(peak), np.nan) if torque_limits is None else np.asarray(torque_limits, dtype=float)
    lines = ["\n  dry run: torque off, nothing sent: no tracking verdict",
             f"  {'dof':<24} {'homing (deg)':>12} {'planned peak (N m)':>19} {'limit (N m)':>12} {'share':>7}"]
    for k, name in enumerate(log.dof_names):
        lines.append(f"  {name:<24} {np.degrees(q_d[-1, k] - q_d[0, k]):>+12.1f} {peak[k]:>19.3f} "
                     f"{limits[k]:>12.3f} {100 * peak[k] / limits[k]:>6.0f}%")
    lines.append(f"\n  {summary['ticks']} ticks read at {summary['loop_hz']:.0f} Hz, {summary['clock']}")
    return "\n".join(lines)
