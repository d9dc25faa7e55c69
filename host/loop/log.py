"""The run log: what the loop logs each tick, streamed to `swing_log.csv` as the run goes, and read
back (`read_run_log`) by whatever looks at a run afterwards: the view's replay, the validator,
identification. One writer, one reader, one header (`columns`)."""

from __future__ import annotations

import csv
import io
import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ServodynError

FLUSH_EVERY = 0.1      # s of wall-clock time between two writes of a streamed log to disk
PER_DOF = ("q_d", "q", "qd", "tau", "current", "temperature")     # the columns of each dof, after t
# every column but temperature must be a finite number; temperature (°C, the winding's as the servo
# reports it, read at a low rate and held between reads) is nan where the bus does not read it, and
# a log written before it existed reads with it nan
NEEDED = PER_DOF[:-1]


class RunLogError(ServodynError, ValueError):
    """A run log that cannot be read; the message names the file and what is wrong."""


def columns(dof_names) -> list[str]:
    """The log's header: t, then per quantity every dof in model order."""
    return ["t"] + [f"{p}_{d}" for p in PER_DOF for d in dof_names]


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
    temperature: list = field(default_factory=list)     # °C, nan where not read
    tick_seconds: list = field(default_factory=list)    # wall time of each tick's work
    tick_start: list = field(default_factory=list)      # s (perf_counter) when each tick began
    cpu_seconds: list = field(default_factory=list)     # CPU time of the loop's thread in each tick
    process_cpu_seconds: list = field(default_factory=list)   # CPU time of the whole process in it
    missed: int = 0             # ticks whose work ended after their period's end (real time)

    def __post_init__(self):
        self._unread = np.full(len(self.dof_names), math.nan)

    def add(self, t, q_d, state, tau, seconds, start, cpu, process_cpu) -> None:
        # t last: a signal's exception (SIGINT, SIGTERM stop the swing) between two appends
        # leaves a row that t does not count, which close() drops (_trim)
        self.q_d.append(np.array(q_d))
        self.q.append(state.q)
        self.qd.append(state.qd)
        self.tau.append(np.array(tau))
        self.current.append(state.current)
        # a state of a bus that reads no temperature: none, or a record without the field
        temperature = getattr(state, "temperature", None)
        self.temperature.append(self._unread if temperature is None else temperature)
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
        for column in (self.q_d, self.q, self.qd, self.tau, self.current, self.temperature, self.tick_seconds,
                       self.tick_start,
                       self.cpu_seconds, self.process_cpu_seconds):
            del column[len(self.t):]

    def close(self) -> None:
        self._trim()
        if getattr(self, "_file", None) is not None:
            self.flush()
            self._file.close()
            self._file = None

    def _header(self) -> list[str]:
        return columns(self.dof_names)

    def _row(self, k: int) -> list[str]:
        """Row k's fields, formatted (as Python floats: exactly the values, as numpy's scalars
        format them, for less)."""
        row = np.concatenate(([self.t[k]], self.q_d[k], self.q[k], self.qd[k], self.tau[k], self.current[k],
                              self.temperature[k]))
        return [f"{v:.9g}" for v in row.tolist()]

    def _write_rows(self, writer, start: int) -> int:
        """The rows from `start` on; returns the number of rows then written in all."""
        for k in range(start, len(self.t)):
            writer.writerow(self._row(k))
        return len(self.t)


def read_run_log(path: str | Path, model, need=NEEDED) -> RunLog:
    """A run log as `RunLog` wrote it (a folder: its swing_log.csv), its columns for the model's
    dofs as arrays (t: (N,); q_d, q, qd, tau, current, temperature: (N, n)); RunLogError for a file
    that is not one (unreadable, missing the `need` columns of a dof, a value that is not a finite
    number outside the temperature columns, time not increasing, fewer than two rows). A column
    the file does not have reads as nan."""
    file = Path(path) / "swing_log.csv" if Path(path).is_dir() else Path(path)
    dof_names = model.dof_names
    try:
        with open(file, newline="") as f:
            header = next((row for row in csv.reader(f) if row), None)
            if header is None:
                raise RunLogError(f"{file}: empty")
            # numpy's own parser: a 600 s log (600 000 rows) in 4 s where Python's took 20 s
            try:
                with warnings.catch_warnings():          # a log of a header alone is said below
                    warnings.simplefilter("ignore", UserWarning)
                    data = np.loadtxt(f, delimiter=",", dtype=float, ndmin=2)
            except ValueError:
                raise RunLogError(f"{file}: a value that is not a number (or a row of another length)") from None
    except OSError as err:
        raise RunLogError(f"{file}: cannot read the log ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise RunLogError(f"{file}: not a text CSV file") from None
    try:
        where = {p: [header.index(f"{p}_{d}") for d in dof_names] for p in need}
        t_col = header.index("t")
    except ValueError:
        raise RunLogError(f"{file}: not a swing log of model '{model.name}' (needs t and {', '.join(p + '_' for p in need)} "
                          f"columns of {', '.join(dof_names)})") from None
    finite = [k for k, name in enumerate(header) if not name.startswith("temperature_")]
    if data.ndim != 2 or len(data) < 2 or data.shape[1] != len(header) or not np.all(np.isfinite(data[:, finite])):
        raise RunLogError(f"{file}: needs at least two complete rows of finite numbers")
    t = data[:, t_col]
    if np.any(np.diff(t) <= 0):
        raise RunLogError(f"{file}: time must increase")
    log = RunLog(tuple(dof_names))
    log.t = t
    present = {p: [header.index(f"{p}_{d}") for d in dof_names] for p in PER_DOF
               if all(f"{p}_{d}" in header for d in dof_names)}
    for p in PER_DOF:
        setattr(log, p, data[:, present[p]] if p in present else np.full((len(t), len(dof_names)), math.nan))
    return log
