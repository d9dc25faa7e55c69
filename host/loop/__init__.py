"""The control loop: one tick, a run of ticks against a servo bus, and its log.

A tick (`tick`) is what the host loop, the HIL replay of the firmware and the firmware itself do
every small_time_step: new PD gains from the schedule every `update_ticks` (with the low-pass of
the errors they act on), the controller step on the measured state (inverse dynamics every time_step, held, plus the PD). `follow` wraps it
between one `read_state()` and one `write()` of a bus — ros2_control's read → update → write —
for each sample of a planned segment, and logs it (`log.RunLog`, whose reader is beside its
writer). `summarize` turns a log into the run's figures; `realtime` places a real-time loop (its
priority, its CPU, the garbage collector paused).
"""

from __future__ import annotations

import json
import math
import signal
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np

from ..control.schedule import Segment
from ..control.timing import OVERRUN_TOLERANCE
from ..hal.bus import JointCommand
from ..errors import ExitCode, ServodynError
from .log import RunLog, read_run_log
from ..hal.realtime import LOOP_PRIORITY, collector_paused, realtime_priority


def tick(controller, segment: Segment, k: int, q, qd) -> np.ndarray:
    """The controller's torque for sample k of the segment at the measured (q, qd)."""
    traj = segment.traj
    if k % controller.config.update_ticks == 0:
        controller.set_gains(*segment.gains.at(traj.t[k] - traj.t[0]), segment.gains.error_lowpass)
    return controller.step(traj.q[k], traj.qd[k], traj.qdd[k], q, qd)


class Overrun(ServodynError, RuntimeError):
    """A real-time loop fell further behind its period schedule than its tolerance: it cannot
    hold its period, so it stops (the firmware's fault 14, overrun)."""
    exit_code = ExitCode.OVERRUN


class Interrupted(ServodynError):
    """SIGINT or SIGTERM arrived during a run: it stops safely, as after a servo error, and exits
    with the shell's status for that signal."""

    def __init__(self, signum: int):
        self.signum = signum
        self.exit_code = 128 + signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")


def follow(bus, controller, segment: Segment, log: RunLog | None = None, realtime: bool = False,
           on_tick=None, progress=None, tolerance: float | None = None, observer=None, guard=None) -> int:
    """Play a segment on the bus, one tick per sample: read, tick, write (and log). In real time
    the loop sleeps to the next period; otherwise it runs as fast as the bus answers.
    on_tick(k) runs before tick k (fault injection); progress(t, fraction, largest error) about
    once a second of the segment's time; observer(t, q_d, state, tau) after every tick (a viewer's
    feed: it must only keep the sample, never block). guard(t, q_d, state, tau) after the tick's
    torque and before its write (servodyn.loop.safety.Guards): what it raises stops the segment
    with that tick logged and its torque not sent.

    In real time tick k's deadline is the end of its period, start + (k + 1) period: a tick whose
    write ends later missed it (counted in log.missed, and returned). A late tick is followed at
    once by the next (the loop catches up on its schedule); a tick that begins more than
    `tolerance` (default OVERRUN_TOLERANCE) behind its schedule raises Overrun before it reads:
    the caller stops the bus. The garbage collector waits for the end of the segment; in real
    time the loop runs under SCHED_FIFO where it may (hal.realtime)."""
    with collector_paused(), realtime_priority(LOOP_PRIORITY) if realtime else nullcontext():
        return _follow(bus, controller, segment, log, realtime, on_tick, progress, tolerance, observer, guard)


def _follow(bus, controller, segment, log, realtime, on_tick, progress, tolerance, observer, guard) -> int:
    tolerance = OVERRUN_TOLERANCE if tolerance is None else tolerance
    controller.reset()
    traj = segment.traj
    n = len(traj.t)
    period = traj.t[1] - traj.t[0]
    start = None
    next_report = 0.0
    missed = 0
    for k in range(n):
        if on_tick is not None:
            on_tick(k)
        if start is None:      # the schedule starts at the first tick, after what on_tick(0) did
            start = time.perf_counter()
        began = time.perf_counter()
        if realtime and began - (start + k * period) > tolerance:
            raise Overrun(f"overrun: tick {k} began {(began - start - k * period) * 1e3:.1f} ms behind its "
                          f"{period * 1e3:g} ms schedule (tolerance {tolerance * 1e3:g} ms; {missed} of {k} "
                          "deadlines missed): the loop cannot hold its period")
        cpu, process_cpu = time.thread_time(), time.process_time()
        state = bus.read_state()
        tau = tick(controller, segment, k, state.q, state.qd)
        if guard is not None:
            try:
                guard(traj.t[k], traj.q[k], state, tau)
            except BaseException:
                if log is not None:
                    log.add(traj.t[k], traj.q[k], state, tau, time.perf_counter() - began, began, 0.0, 0.0)
                raise
        bus.write(JointCommand.torque(tau))
        cpu, process_cpu = time.thread_time() - cpu, time.process_time() - process_cpu
        if log is not None:
            log.add(traj.t[k], traj.q[k], state, tau, time.perf_counter() - began, began, cpu, process_cpu)
        if observer is not None:
            observer(traj.t[k], traj.q[k], state, tau)
        if progress is not None and traj.t[k] >= next_report:
            progress(traj.t[k], k / (n - 1), float(np.abs(traj.q[k] - state.q).max()))
            next_report += 1.0
        if realtime:
            delay = start + (k + 1) * period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            else:
                missed += 1
                if log is not None:
                    log.missed += 1
    return missed


# the figures of a run that has ticks (summarize): null in the summary of one that has none
FIGURES = ("tracking_rms_rad", "tracking_max_rad", "tracking_max_by_dof_rad", "loop_hz", "jitter_p99_ms",
           "jitter_max_ms", "period_median_ms", "tick_median_ms", "cpu_ms_per_tick", "process_cpu_ms_per_tick",
           "peak_torque_nm", "chatter_by_dof", "chatter_max")

CHATTER_CUTOFF_HZ = 20.0    # a command's part above this is chatter: an arm's motion lives below it
CHATTER_GOAL = 0.02         # that part's rms, as a share of the joint's peak |torque|, a servo can live with
TRACKING_GOAL_RAD = math.radians(0.5)    # the largest tracking error the gains must keep to meanwhile


def chatter(tau, dt: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The chatter of commanded torques tau (ticks x joints, sampled every dt s), per joint: the
    part above CHATTER_CUTOFF_HZ, tau minus its zero-phase low-pass (a second-order Butterworth
    run forward and backward, so the motion itself is not shifted into it), as (its rms over the
    joint's peak |tau|, its peak-to-peak in N m). None for a run too short to filter (under a
    period of the cut-off) or sampled too coarsely to hold it."""
    from scipy.signal import butter, sosfiltfilt
    tau = np.asarray(tau, dtype=float)
    if len(tau) * dt < 1.0 / CHATTER_CUTOFF_HZ or CHATTER_CUTOFF_HZ >= 0.5 / dt:
        return None
    # padded by three periods of the cut-off (reflected about each end), so that the filter's
    # start-up at the ends does not count as chatter
    pad = min(len(tau) - 1, int(round(3.0 / (CHATTER_CUTOFF_HZ * dt))))
    high = tau - sosfiltfilt(butter(2, CHATTER_CUTOFF_HZ, fs=1.0 / dt, output="sos"), tau, axis=0, padlen=pad)
    peak = np.abs(tau).max(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(peak > 0, np.sqrt(np.mean(high**2, axis=0)) / np.where(peak > 0, peak, 1.0), 0.0)
    return share, np.ptp(high, axis=0)


def write_summary(out, summary: dict) -> None:
    """OUT/summary.json: a run's summary (`summarize` and what the run adds)."""
    (Path(out) / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")


def summarize(log: RunLog, planned_ticks: int, period: float, realtime: bool, error=None) -> dict:
    """The figures of a run. The loop rate and the period jitter come from when the ticks began:
    in real time the jitter is each period's distance from the nominal one, in lock-step (which
    runs as fast as it can) from the median period. CPU per tick is the loop thread's CPU time
    (time.thread_time) from the read to the end of the write; the process's (time.process_time)
    also counts a simulated bus running in this process. These depend on the machine: they are
    reported, and measured in `make bench`, never asserted by a test. Chatter (chatter()) and the
    largest tracking error per joint are reported beside their goals (CHATTER_GOAL,
    TRACKING_GOAL_RAD)."""
    clock = {"clock": "realtime" if realtime else "lockstep", "missed_deadlines": log.missed if realtime else None,
             "chatter_goal": CHATTER_GOAL, "tracking_goal_rad": TRACKING_GOAL_RAD}
    if not log.t:        # every key still there, null: a reader of summary.json needs no special case
        return {"completed": False, "ticks": 0, **dict.fromkeys(FIGURES), **clock,
                "error": str(error) if error else "no tick ran", "last_tick_time_s": None}
    names = log.dof_names
    e = np.array(log.q_d) - np.array(log.q)
    seconds = np.array(log.tick_seconds)
    starts = np.array(log.tick_start, dtype=float)
    if len(starts) > 1:
        periods = np.diff(starts)
        loop_hz = (len(starts) - 1) / float(starts[-1] - starts[0])
    else:
        periods, loop_hz = seconds, len(seconds) / float(np.sum(seconds))
    jitter = np.abs(periods - (period if realtime else np.median(periods)))
    cpu = np.array(log.cpu_seconds, dtype=float)
    process_cpu = np.array(log.process_cpu_seconds, dtype=float)
    buzz = chatter(log.tau, period)
    return {
        "completed": error is None and len(log.t) == planned_ticks,
        "ticks": len(log.t),
        "tracking_rms_rad": float(np.sqrt(np.mean(e**2))),
        "tracking_max_rad": float(np.abs(e).max()),
        "tracking_max_by_dof_rad": dict(zip(names, map(float, np.abs(e).max(axis=0)))),
        "loop_hz": loop_hz,
        "jitter_p99_ms": float(np.percentile(jitter, 99) * 1e3),
        "jitter_max_ms": float(jitter.max() * 1e3),
        **clock,
        "period_median_ms": float(np.median(periods) * 1e3),
        "tick_median_ms": float(np.median(seconds) * 1e3),
        "cpu_ms_per_tick": {"median": float(np.median(cpu) * 1e3), "p99": float(np.percentile(cpu, 99) * 1e3)},
        "process_cpu_ms_per_tick": {"median": float(np.median(process_cpu) * 1e3),
                                    "p99": float(np.percentile(process_cpu, 99) * 1e3)},
        "peak_torque_nm": dict(zip(names, map(float, np.abs(np.array(log.tau)).max(axis=0)))),
        # the commanded torque's part above CHATTER_CUTOFF_HZ (chatter()): rms over peak, and N m
        "chatter_by_dof": None if buzz is None else {
            name: {"rms_share": float(share), "peak_to_peak_nm": float(p2p)} for name, share, p2p in zip(names, *buzz)},
        "chatter_max": None if buzz is None else float(buzz[0].max()),
        "error": str(error) if error else None,
        "last_tick_time_s": float(log.t[-1]),
    }
