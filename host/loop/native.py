"""The native loop: the firmware's application as a Linux process (`build/fw/native/servodyn-fw`,
built by `make fw` from firmware/app on firmware/posix/board_posix.c), driving a serial port —
a USB adapter's or the simulated bus's pseudo-terminal.

`run_native` runs it and reads back what it wrote: its report line (`parse_report`, the same
lines the firmware writes under QEMU) and its per-tick log (one record of native doubles a tick:
tick, start (s), wall time (s), CPU time (s), then q_d, q, qd, tau, current per joint), turned into
the host loop's RunLog so a run with `native=True` summarizes and writes it as the Python loop's.

A contact (fault 18) is the firmware's own detection: its tick, the joint first over its threshold
(the report's servo, with its |residual| as value_micro) and the last joint over its threshold at
that tick (link_servo), whose child body is the link. The firmware does not estimate the force
(its tick has no room for the link's Jacobian and a least-squares solve): `contact_detail` gives
the host's estimate instead, the Python observer's (servodyn.loop.contact) run over the
measurements the firmware logged up to its last logged tick, one tick before the detection, at
the firmware's link; None when nothing was logged.
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ..control.motion import DEFAULT_MOTION
from ..control.timing import HOME_DURATION, SMALL_TIME_STEP
from ..errors import ServodynError
from . import summarize, write_summary
from .contact import contact_observer
from .log import RunLog

ROOT = Path(__file__).resolve().parents[2]     # the repository: make fw builds under build/
NATIVE = ROOT / "build" / "fw" / "native" / "servodyn-fw"
BUILT_FOR = "replica"          # FW_CONFIG of firmware/app/rules.mk: the generated tables' configuration
HEAD = 4                       # tick, start, wall, cpu


class FirmwareError(ServodynError):
    """The firmware could not be run (no image, no QEMU, no connection, no report)."""
    exit_code = 2


def parse_report(text: str) -> dict:
    """The firmware's report lines (`servodyn-fw: ...`) as numbers."""
    report = {"counts": {}}
    for line in text.splitlines():
        if not line.startswith("servodyn-fw: "):
            continue
        words = line.split()[1:]
        values = {k: int(v) for k, v in (w.split("=", 1) for w in words if "=" in w)}
        if words[0] == "counts":
            report["counts"][words[1]] = values
        else:
            report["result"], report["fault"] = words[0], words[1]
            report.update(values)
    return report


def _rows(rows: np.ndarray, n: int) -> np.ndarray:
    return rows[: rows.size - rows.size % (HEAD + 5 * n)].reshape(-1, HEAD + 5 * n)


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
    rows = _rows(rows, n)
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
    report["rows"] = rows         # every tick logged, homing's too (contact_detail replays them)
    return report, log


GUARD_FAULTS = ("following_error", "stall")      # the firmware's guards, with a joint and a value


def fault_message(report: dict) -> str | None:
    """The native loop's stop in one line, or None when it played its plan."""
    if report.get("fault", "none") == "none":
        return None
    servo = report.get("servo", -1)
    return (f"native loop: fault {report['fault']} (code {report.get('code')}) at tick {report.get('fault_tick')}"
            + (f", servo {servo}" if servo not in (None, -1) else "")
            + (f"; {report.get('missed')} deadlines missed, {report.get('lost')} periods behind"
               if report["fault"] == "overrun" else ""))


def contact_detail(config, report: dict) -> dict:
    """summary.json's `contact` of the firmware's contact fault (module docstring): its time on the
    motion's clock, the joint it names, the link (the child body of the last joint over its
    threshold), the firmware's |residual| (N m) and the host's force estimate (N, or None)."""
    model, period = config.model, config.control_period
    dof_of = {j.id: j.dof for j in config.joints}
    joint = dof_of.get(report.get("servo"))
    link_dof = dof_of.get(report.get("link_servo"), joint)
    link = next((b.name for b in model.bodies if any(d.name == link_dof for d in b.dofs)), None)
    force = None
    rows, n = report.get("rows"), model.nv
    if rows is not None and len(rows) and link is not None:
        observer = contact_observer(config, watching=False)
        nm_per_amp = np.array([j.torque_constant * j.gear_ratio for j in config.joints])
        part = lambda row, p: row[HEAD + p * n:HEAD + (p + 1) * n]
        observer.reset(part(rows[0], 1), part(rows[0], 2))
        for k, row in enumerate(rows):
            observer.update(k * period, part(row, 1), part(row, 2), nm_per_amp * part(row, 4))
        force = float(np.linalg.norm(observer.estimate(part(rows[-1], 1), link=link)[1]))
    return {"detected_t_s": (report["fault_tick"] - report["home_ticks"]) * period, "joint": joint, "link": link,
            "residual_nm": report.get("value_micro", 0) * 1e-6, "force_estimate_n": force}


def check_native(config, motion: str, scale: float, mode: str, fault_at) -> None:
    """FirmwareError unless the native loop's generated tables are this run's."""
    if config.name != BUILT_FOR or motion != DEFAULT_MOTION or scale != config.time_scale_for(DEFAULT_MOTION):
        raise FirmwareError(f"--native plays what the firmware was generated for ('{BUILT_FOR}', {DEFAULT_MOTION}, "
                            f"its configuration's time scale): not '{config.name}', {motion} at {scale:g}")
    if mode != "feedforward_pd" or fault_at is not None:
        raise FirmwareError("--native runs feed-forward + PD and injects no fault")


def native_swing(server, port: str, run, out: Path) -> dict:
    """The firmware's loop as a Linux process plays `run` (a loop.run.Run) on the port; the same
    summary as the Python loop's (and `cpu`: the one CPU of the real-time path, None when not
    placed, hal.realtime.one_cpu)."""
    config, realtime, say = run.config, run.realtime, run.say
    say(f"native loop on {port} ({'real time' if realtime else 'lock-step'}) ...")
    tolerance = run.options.overrun_tolerance
    try:
        args = "" if tolerance is None else f"tolerance_us={round(tolerance * 1e6)}"
        report, log = run_native(port, config.model.dof_names, realtime, args=args, say=say,
                                 reply_timeout=server.buses[next(iter(server.buses))]["reply_timeout"]
                                 if server is not None else None)
    finally:
        sim = server.status() if server is not None else None
        if server is not None:
            server.stop()
    error = fault_message(report)
    summary = summarize(log, len(run.swing.t), config.control_period, realtime, error)
    summary.update(motion=run.verdict.path.name, mode=run.options.mode, time_scale=run.scale,
                   validated=run.verdict.passed, loop="native",
                   bus={"reads": report.get("ticks"), "writes": report.get("ticks"), "reads_retried": 0,
                        "limited_ticks": report.get("limited")},
                   native={k: report.get(k) for k in ("result", "fault", "code", "servo", "link_servo", "fault_tick", "ticks",
                                                      "missed", "lost", "exit_code", "notes")},
                   cpu=run.cpu, home_ticks=report.get("home_ticks"),
                   exit_code=(report.get("exit_code") or 2) if error else 0)    # the firmware's fault code
    fault = report.get("fault", "none")
    summary["stop_reason"] = "completed" if fault == "none" and summary["completed"] else (
        fault if fault != "none" else "incomplete")
    if fault in GUARD_FAULTS:
        # the guard's joint, time on the motion's clock, value and limit, as the Python loop says them
        joint = next(j for j in config.joints if j.id == report.get("servo"))
        limit = (config.guards.following_error[config.model.dof_names.index(joint.dof)] if fault == "following_error"
                 else joint.torque_limit)
        summary[fault] = {"joint": joint.dof, "value": report.get("value_micro", 0) * 1e-6, "limit": limit,
                          "t_s": (report["fault_tick"] - report["home_ticks"]) * config.control_period}
    if fault == "contact":
        summary["contact"] = contact_detail(config, report)
    if sim is not None:
        # on the swing's clock in lock-step; in real time the plant's clock at the swing's start is
        # the native process's to know, not this one's
        summary["sim_time_at_stop_s"] = None if realtime else sim["time"] - report["home_ticks"] * config.control_period
        summary["torque_off"] = sim["torque_off"]
    if error:
        say(f"{error} — torque off on every servo")
    log.write_csv(out / "swing_log.csv")
    run.log = log
    write_summary(out, summary)
    return summary
