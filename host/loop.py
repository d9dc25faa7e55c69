"""The control loop: one tick, a run of ticks against a servo bus, and its log.

A tick (`tick`) is what the host loop, the HIL replay of the firmware and the firmware itself do
every small_time_step: new PD gains from the schedule every `update_ticks`, the controller step
on the measured state (inverse dynamics every time_step, held, plus the PD). `follow` wraps it
between one `read_state()` and one `write()` of a bus — ros2_control's read → update → write —
for each sample of a planned segment, and logs it. `summarize` turns a log into the run's figures.
"""

from __future__ import annotations

import csv
import io
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .control.realtime import LOOP_PRIORITY, collector_paused, realtime_priority
from .control.schedule import Segment
from .control.timing import OVERRUN_TOLERANCE
from .hal.bus import JointCommand

FLUSH_EVERY = 0.1      # s of wall-clock time between two writes of a streamed log to disk


def tick(controller, segment: Segment, k: int, q, qd) -> np.ndarray:
    """The controller's torque for sample k of the segment at the measured (q, qd)."""
    traj = segment.traj
    if k % controller.config.update_ticks == 0:
        controller.set_gains(*segment.gains.at(traj.t[k] - traj.t[0]))
    return controller.step(traj.q[k], traj.qd[k], traj.qdd[k], q, qd)


class Overrun(RuntimeError):
    """A real-time loop fell further behind its period schedule than its tolerance: it cannot
    hold its period, so it stops (the firmware's fault 14, overrun)."""


@dataclass
class RunLog:
    """Per tick: time, desired and measured state, commanded torque, measured current, and when
    the tick began and what CPU it took."""
    dof_names: tuple[str, ...]
    t: list = field(default_factory=list)
    q_d: list = field(default_factory=list)
    q: list = field(default_factory=list)
    qd: list = field(default_factory=list)
    tau: list = field(default_factory=list)
    current: list = field(default_factory=list)
    tick_seconds: list = field(default_factory=list)    # wall time of each tick's work
    tick_start: list = field(default_factory=list)      # s (perf_counter) when each tick began
    cpu_seconds: list = field(default_factory=list)     # CPU time of the loop's thread in each tick
    process_cpu_seconds: list = field(default_factory=list)   # CPU time of the whole process in it
    missed: int = 0             # ticks whose work ended after their period's end (real time)

    def add(self, t, q_d, state, tau, seconds, start, cpu, process_cpu) -> None:
        # t last: a signal's exception (SIGINT, SIGTERM stop the swing) between two appends
        # leaves a row that t does not count, which close() drops (_trim)
        self.q_d.append(np.array(q_d))
        self.q.append(state.q)
        self.qd.append(state.qd)
        self.tau.append(np.array(tau))
        self.current.append(state.current)
        self.tick_seconds.append(seconds)
        self.tick_start.append(start)
        self.cpu_seconds.append(cpu)
        self.process_cpu_seconds.append(process_cpu)
        self.t.append(t)
        if getattr(self, "_file", None) is not None:
            # the row is formatted now, a few µs each tick, so that a flush only writes: formatting
            # 100 ms of rows at once took a real-time loop several periods
            self._format_pending()
            if time.monotonic() - self._flushed_at >= self._flush_every:
                self.flush()

    def write_csv(self, path: Path) -> None:
        self._trim()
        with open(path, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(self._header())
            self._write_rows(writer, 0)

    def stream(self, path: Path, flush_every: float = FLUSH_EVERY) -> None:
        """Write the log to `path` while it grows: the rows logged so far go to the file (and
        to the operating system, which keeps them if the process is killed) whenever
        `flush_every` s of wall-clock time have passed since the last time, and at close(). A
        process killed outright (SIGKILL) loses at most the ticks of its last `flush_every` s,
        and every line on disk is whole.

        A signal's exception (SIGINT, SIGTERM stop the swing) may come between any two steps:
        each row is formatted into a pending line by one list append, so it is pending once or
        not yet; a write to the file is first recorded whole — where it goes, what it writes,
        the state after it — by one assignment, and redone from that place if it was cut
        short, so close() puts every row in the file exactly once."""
        self._file = open(path, "wb")
        self._line_buffer = io.StringIO(newline="")
        self._line_writer = csv.writer(self._line_buffer)
        self._stream = (0, [self._line(self._header())])      # (rows in the file, pending lines)
        self._commit = None
        self._flush_every = flush_every
        self.flush()

    def _line(self, fields) -> str:
        """One CSV line, as csv.writer writes it."""
        self._line_buffer.seek(0)
        self._line_buffer.truncate()
        self._line_writer.writerow(fields)
        return self._line_buffer.getvalue()

    def _format_pending(self) -> None:
        """Every logged row not yet in the file nor pending, formatted into a pending line."""
        self._redo()
        in_file, lines = self._stream
        header = 1        # the header's line comes first, counted as a row of the file
        while in_file + len(lines) - header < len(self.t):
            lines.append(self._line(self._row(in_file + len(lines) - header)))

    def flush(self) -> None:
        """The rows not yet on disk, to the file and the operating system (when streaming)."""
        if getattr(self, "_file", None) is not None:
            self._format_pending()
            in_file, lines = self._stream
            self._commit = (self._file.tell(), "".join(lines).encode(), (in_file + len(lines), []))
            self._redo()
            self._flushed_at = time.monotonic()

    def _redo(self) -> None:
        """The recorded write, from its place (again, if it was cut short), then its state."""
        if self._commit is not None:
            at, data, after = self._commit
            self._file.seek(at)
            self._file.truncate()
            self._file.write(data)
            self._file.flush()
            self._stream = after
            self._commit = None

    def _trim(self) -> None:
        """Every column as long as t: a row whose add() a signal cut short is dropped whole."""
        for column in (self.q_d, self.q, self.qd, self.tau, self.current, self.tick_seconds, self.tick_start,
                       self.cpu_seconds, self.process_cpu_seconds):
            del column[len(self.t):]

    def close(self) -> None:
        self._trim()
        if getattr(self, "_file", None) is not None:
            self.flush()
            self._file.close()
            self._file = None

    def _header(self) -> list[str]:
        return ["t"] + [f"{p}_{d}" for p in ("q_d", "q", "qd", "tau", "current") for d in self.dof_names]

    def _row(self, k: int) -> list[str]:
        """Row k's fields, formatted (as Python floats: exactly the values, as numpy's scalars
        format them, for less)."""
        row = np.concatenate(([self.t[k]], self.q_d[k], self.q[k], self.qd[k], self.tau[k], self.current[k]))
        return [f"{v:.9g}" for v in row.tolist()]

    def _write_rows(self, writer, start: int) -> int:
        """The rows from `start` on; returns the number of rows then written in all."""
        for k in range(start, len(self.t)):
            writer.writerow(self._row(k))
        return len(self.t)


def follow(bus, controller, segment: Segment, log: RunLog | None = None, realtime: bool = False,
           on_tick=None, progress=None, tolerance: float | None = None, observer=None) -> int:
    """Play a segment on the bus, one tick per sample: read, tick, write (and log). In real time
    the loop sleeps to the next period; otherwise it runs as fast as the bus answers.
    on_tick(k) runs before tick k (fault injection); progress(t, fraction, largest error) about
    once a second of the segment's time; observer(t, q_d, state, tau) after every tick (a viewer's
    feed: it must only keep the sample, never block).

    In real time tick k's deadline is the end of its period, start + (k + 1) period: a tick whose
    write ends later missed it (counted in log.missed, and returned). A late tick is followed at
    once by the next (the loop catches up on its schedule); a tick that begins more than
    `tolerance` (default OVERRUN_TOLERANCE) behind its schedule raises Overrun before it reads:
    the caller stops the bus. The garbage collector waits for the end of the segment; in real
    time the loop runs under SCHED_FIFO where it may (control.realtime)."""
    with collector_paused(), realtime_priority(LOOP_PRIORITY) if realtime else nullcontext():
        return _follow(bus, controller, segment, log, realtime, on_tick, progress, tolerance, observer)


def _follow(bus, controller, segment, log, realtime, on_tick, progress, tolerance, observer) -> int:
    tolerance = OVERRUN_TOLERANCE if tolerance is None else tolerance
    controller.reset()
    traj = segment.traj
    n = len(traj.t)
    period = traj.t[1] - traj.t[0]
    start = time.perf_counter()
    next_report = 0.0
    missed = 0
    for k in range(n):
        if on_tick is not None:
            on_tick(k)
        began = time.perf_counter()
        if realtime and began - (start + k * period) > tolerance:
            raise Overrun(f"overrun: tick {k} began {(began - start - k * period) * 1e3:.1f} ms behind its "
                          f"{period * 1e3:g} ms schedule (tolerance {tolerance * 1e3:g} ms; {missed} of {k} "
                          "deadlines missed): the loop cannot hold its period")
        cpu, process_cpu = time.thread_time(), time.process_time()
        state = bus.read_state()
        tau = tick(controller, segment, k, state.q, state.qd)
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
           "peak_torque_nm")


def summarize(log: RunLog, planned_ticks: int, period: float, realtime: bool, error=None) -> dict:
    """The figures of a run. The loop rate and the period jitter come from when the ticks began:
    in real time the jitter is each period's distance from the nominal one, in lock-step (which
    runs as fast as it can) from the median period. CPU per tick is the loop thread's CPU time
    (time.thread_time) from the read to the end of the write; the process's (time.process_time)
    also counts a simulated bus running in this process. These depend on the machine: they are
    reported, and measured in `make bench`, never asserted by a test."""
    clock = {"clock": "realtime" if realtime else "lockstep", "missed_deadlines": log.missed if realtime else None}
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
        "error": str(error) if error else None,
        "last_tick_time_s": float(log.t[-1]),
    }
