"""The native loop: the firmware's application as a Linux process (`build/fw/native/servodyn-fw`,
built by `make fw` from firmware/app on firmware/posix/board_posix.c), driving a serial port —
a USB adapter's or the simulated bus's pseudo-terminal.

`run_native` runs it and reads back what it wrote: its report line (as under QEMU, tools/hil.py's
parse_report) and its per-tick log (one record of native doubles a tick: tick, start (s), wall
time (s), CPU time (s), then q_d, q, qd, tau, current per joint), turned into the host loop's
RunLog so `servodyn swing --native` summarizes and writes it as the Python loop's run.
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ..control.timing import HOME_DURATION, SMALL_TIME_STEP
from ..loop import RunLog
from .hil import FirmwareError, parse_report

ROOT = Path(__file__).resolve().parent.parent
NATIVE = ROOT / "build" / "fw" / "native" / "servodyn-fw"
BUILT_FOR = "replica"          # FW_CONFIG of firmware/app/rules.mk: the generated tables' configuration
HEAD = 4                       # tick, start, wall, cpu


def run_native(port: str, dof_names, realtime: bool = False, args: str = "", exe: Path | None = None,
               timeout: float = 600.0, reply_timeout: float | None = None, say=print) -> tuple[dict, RunLog]:
    """Run the native loop on `port`; (its report, the log of the swing's ticks). reply_timeout:
    s it waits for a reply before a servo is taken for silent (None: the board's 250 ms). The report has
    the fault and its code, `exit_code`, `home_ticks` and the lines it wrote to standard error
    (`notes`: e.g. that SCHED_FIFO was not allowed)."""
    exe = Path(exe) if exe else NATIVE
    if not exe.is_file():
        raise FirmwareError(f"no native loop at {exe} (build it with `make fw`)")
    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "ticks.bin"
        command = [str(exe), port, f"log={log_path}"] + (["realtime"] if realtime else []) + args.split()
        if reply_timeout is not None:
            command.append(f"reply_ms={round(reply_timeout * 1e3)}")
        try:
            proc = subprocess.run(command, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise FirmwareError(f"the native loop did not end within {timeout:g} s") from None
        rows = np.fromfile(log_path, dtype=np.float64) if log_path.exists() else np.zeros(0)
    report = parse_report(proc.stdout)
    report["exit_code"] = proc.returncode
    report["notes"] = [line for line in proc.stderr.splitlines() if line.strip()]
    for note in report["notes"]:
        say(note)
    if "result" not in report:
        raise FirmwareError(f"the native loop gave no report (exit {proc.returncode}): "
                            f"{(proc.stdout + proc.stderr).strip()[-300:]}")
    n = len(dof_names)
    rows = rows[: rows.size - rows.size % (HEAD + 5 * n)].reshape(-1, HEAD + 5 * n)
    home_ticks = int(round(HOME_DURATION / SMALL_TIME_STEP)) + 1       # as codegen's fw_plan_
    report["home_ticks"] = home_ticks
    log = RunLog(tuple(dof_names))
    swing = rows[rows[:, 0] >= home_ticks]
    part = lambda p: swing[:, HEAD + p * n:HEAD + (p + 1) * n]
    log.t = list((swing[:, 0] - home_ticks) * SMALL_TIME_STEP)
    log.q_d, log.q, log.qd, log.tau, log.current = (list(part(p)) for p in range(5))
    log.temperature = list(np.full((len(swing), n), np.nan))      # the native loop reads none
    log.tick_start, log.tick_seconds = list(swing[:, 1]), list(swing[:, 2])
    log.cpu_seconds = log.process_cpu_seconds = list(swing[:, 3])    # one thread: the process's own
    log.missed = int(report.get("missed", 0))
    return report, log


def fault_message(report: dict) -> str | None:
    """The native loop's stop in one line, or None when it played its plan."""
    if report.get("fault", "none") == "none":
        return None
    servo = report.get("servo", -1)
    return (f"native loop: fault {report['fault']} (code {report.get('code')}) at tick {report.get('fault_tick')}"
            + (f", servo {servo}" if servo not in (None, -1) else "")
            + (f"; {report.get('missed')} deadlines missed, {report.get('lost')} periods behind"
               if report["fault"] == "overrun" else ""))
