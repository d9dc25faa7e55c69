"""The firmware under QEMU, hardware in the loop with the simulated bus (`servodyn firmware`, the soak).

The emulator's side (its command line, serial sockets and the bus served on them) is
servodyn.loop.qemu; this module runs whole firmware runs and compares them with the host.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .control.motion import DEFAULT_MOTION, load_motion
from .control.timing import HOME_DURATION
from .hal.config import load_config
from .hal.link import messages as ms
from .loop.link_load import plan as link_plan
from .loop.link_session import LinkSession
from .loop.agreement import agreement, replay
from .loop.link_controllers import NativeController
from .loop.native import FirmwareError, parse_report
from .loop.native_link import LOCKSTEP_TIMEOUT_MS, QEMU_ANSWER_TIMEOUT, STOP_TIMEOUT, drive
from .loop.qemu import (BOARDS, SYSTICK_HZ, FirmwareLink, QemuController, Record, connect, free_ports,
                        default_elf, image, qemu_command, to_instructions)
from .sim.robot import SimulatedRobot
from .sim.transport.pty import PtyServer


def run_qemu(board: str = "an386", elf: Path | None = None, config: str = "replica",
             icount_shift: int = 3, args: str = "", on_tick=None, tamper=None, timeout: float = 300.0,
             q0=None, extra: tuple = ()) -> tuple[dict, Record, object]:
    """Run the image against a fresh simulated arm; (report, record, arm). The report's "clock" is
    the board's clock line (board.h's board_clock_report), when the clock started."""
    elf = image(board, elf)
    if shutil.which("qemu-system-arm") is None:
        raise FirmwareError("qemu-system-arm not found (`make toolchain` installs it)")
    arm = SimulatedRobot(load_config(config), q0=q0).port()     # its one Dynamixel bus
    link = FirmwareLink(arm, on_tick, tamper)
    port, sync_port = free_ports(2)
    proc = subprocess.Popen(qemu_command(board, elf, port, icount_shift, args, sync_port, extra),
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout
    try:
        sock = connect(proc, port, deadline)      # QEMU opens UART1's socket once UART0's is taken
        with sock, connect(proc, sync_port, deadline) as sync:
            link.serve(sock, deadline, sync)
        out, err = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        raise FirmwareError("QEMU did not exit after the firmware's run") from None
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    report = parse_report(out + "\n" + err)      # semihosting writes to QEMU's stderr
    if "result" not in report:
        raise FirmwareError(f"the firmware gave no report (QEMU exit {proc.returncode}): "
                            f"{(out + err).strip()[-300:]}")
    report["exit_code"] = proc.returncode
    clock = [line for line in (out + "\n" + err).splitlines() if line.startswith("servodyn-board: clock ")]
    if clock:
        report["clock"] = {k: int(v) for k, v in (w.split("=", 1) for w in clock[-1].split()[2:])}
    return report, link.record, arm


def run_qemu_link(board: str = "an386", elf: Path | None = None, config: str = "replica",
                  icount_shift: int = 3, telemetry_every: int = 10, host_timeout_ms: int = 60000,
                  timeout: float = 600.0, args: str = "") -> tuple[dict, Record, object, object]:
    """The general application's image (fw_link.c; the host link on -serial #2) under QEMU against a
    fresh simulated arm: the host loads `config`, streams its motion's knots, homes and plays, then
    switches torque off, which ends the run (once=1). (report, record, session, plan): the report's
    worst_work is the worst tick with torque on in clock counts, the link's work included."""
    loaded = load_config(config)
    baud = next(iter(loaded.buses.values())).baud
    controller = QemuController(board, SimulatedRobot(loaded).port(), baud, icount_shift, args, timeout, elf=elf)
    deadline = controller.deadline
    try:
        session = LinkSession(controller.fd)
        session.sender.timeout = QEMU_ANSWER_TIMEOUT
        p = link_plan(loaded, host_timeout_ms=host_timeout_ms)
        session.hello()
        session.command("telemetry", telemetry_every)
        session.load(p.messages)
        session.stream(p)
        session.command("home", p.home_ms)
        session.command("play")
        while session.last is None or not (session.last.flags & ms.TM_DONE or session.last.fault):
            if time.monotonic() > deadline:
                raise FirmwareError(f"the run did not end within {timeout:g} s: {session.last}")
            session.pump(0.005)
            session.stream(p)
        session.command("torque_off")
        output = controller.finish(max(1.0, deadline - time.monotonic()))
    finally:
        controller.close()
    report = parse_report(output)
    if "result" not in report:
        raise FirmwareError(f"the firmware gave no report (QEMU exit {controller.proc.returncode}): "
                            f"{output.strip()[-300:]}")
    report["exit_code"] = controller.proc.returncode
    return report, controller.record, session, p


LOCKSTEP_REPLY_MS = 5000     # a lock-stepped simulator on a busy machine may be this late; a silent servo is later


@dataclass
class LinkRun:
    """A motion played by the general application over the host link against a simulated arm whose
    every bus exchange is recorded (run_link)."""
    session: object            # servodyn.loop.link_session.LinkSession: its telemetry
    plan: object               # servodyn.loop.link_load.LinkPlan: what was loaded and streamed
    record: Record             # what crossed the bus
    error: str | None          # None: the motion played to its end
    report: dict               # the controller's report line (worst tick, stack, ...)


def run_link(kind: str = "native", config: str = "replica", motion: str | None = None,
             time_scale: float | None = None, board: str = "an386") -> LinkRun:
    """`config`'s `motion` (default its own) played in lock-step by the general application: kind
    "native" (the Linux process, the simulated bus on a pseudo-terminal) or "qemu" (BOARD's image)."""
    loaded = load_config(config)
    p = link_plan(loaded, motion or loaded.swing_motion, LOCKSTEP_TIMEOUT_MS, time_scale=time_scale)
    baud = next(iter(loaded.buses.values())).baud
    arm = SimulatedRobot(loaded).port()
    server = None
    if kind == "native":
        bus = FirmwareLink(arm)
        server = PtyServer(arm, "lockstep")
        server.start()
        controller = NativeController([server.path, f"baud={baud}", f"reply_ms={LOCKSTEP_REPLY_MS}"], realtime=False)
        record = bus.record
    else:
        controller = QemuController(board, arm, baud)
        record = controller.record
    try:
        session, error, _ = drive(controller, p, p.home_ms, realtime=False, qemu=kind == "qemu")
        output = controller.finish(STOP_TIMEOUT)
    finally:
        controller.close()
        if server is not None:
            server.stop()
    return LinkRun(session, p, record, error, parse_report(output))


def link_agreement(config_name: str, run: LinkRun) -> dict:
    """run's commands against the host's double controller (servodyn.loop.agreement)."""
    return agreement(config_name, run.plan, run.record)


def summarize(report: dict, record: Record, config_name: str, icount_shift: int, board: str) -> dict:
    counts = report["counts"]
    instructions = {name: {"max": round(to_instructions(c["max"], board, icount_shift)),
                           "mean": round(to_instructions(c["mean_milli"] / 1000, board, icount_shift))}
                    for name, c in counts.items() if c.get("n")}
    twin = replay(config_name, record)
    n = min(len(record.goals), len(twin["goals"]))
    diff = np.abs(np.array(record.goals[:n]) - twin["goals"][:n]) if n else np.zeros((0, 1))
    swing = twin["phase"][:n] == "swing"
    error = (twin["q_d"][:n] - twin["q"][:n])[swing]
    summary = {
        "board": board, "machine": BOARDS[board][0], "cpu": BOARDS[board][1],
        "result": report["result"], "fault": report["fault"], "fault_code": report.get("code"),
        "fault_servo": report.get("servo"), "fault_tick": report.get("fault_tick"),
        "exit_code": report.get("exit_code"), "ticks": report.get("ticks"),
        "swing_ticks": int(swing.sum()), "limited_ticks": report.get("limited"),
        "goal_writes": len(record.goals), "torque_off_sent": record.torque_off,
        "goal_max_diff_units": int(diff.max()) if diff.size else 0,
        "goal_diff_counts": {str(v): int((diff.max(axis=1) == v).sum()) for v in np.unique(diff.max(axis=1))}
        if diff.size else {},
        "tracking_rms_rad": float(np.sqrt(np.mean(error**2))) if error.size else None,
        "tracking_max_rad": float(np.abs(error).max()) if error.size else None,
        "icount_shift": icount_shift, "instructions_per_tick": instructions,
        "period_counts": report.get("period"), "stack_used_bytes": report.get("stack"),
    }
    return summary


PROGRESS_EVERY = 1.0      # s of wall time between two progress lines of a firmware run


def _with_progress(on_tick, config: str, say):
    """on_tick for FirmwareLink that also says, about once a second, how far the run is: the
    ticks the firmware has commanded out of its homing and swing (the run takes a minute)."""
    loaded = load_config(config)
    motion = load_motion(DEFAULT_MOTION, loaded.model)
    planned = round((HOME_DURATION + motion.duration * loaded.time_scale_for(DEFAULT_MOTION)) / loaded.control_period)
    last = [time.monotonic()]

    def tick_and_say(k, arm):
        if on_tick is not None:
            on_tick(k, arm)
        now = time.monotonic()
        if now - last[0] >= PROGRESS_EVERY:
            last[0] = now
            say(f"  tick {k + 1} of about {planned} ({min(100.0, 100 * (k + 1) / planned):.0f} %)")
    return tick_and_say


def run_firmware(board: str = "an386", elf=None, config: str = "replica", out: Path = Path("out/firmware"),
                 icount_shift: int = 3, args: str = "", on_tick=None, say=print) -> dict:
    elf = image(board, elf)        # checked before anything is said or started
    say(f"QEMU {BOARDS[board][0]} ({BOARDS[board][1]}), -icount shift={icount_shift}: the firmware drives "
        f"the simulated '{config}' bus in lock-step ...")
    began = time.perf_counter()
    report, record, arm = run_qemu(board, elf, config, icount_shift, args, _with_progress(on_tick, config, say))
    summary = summarize(report, record, config, icount_shift, board)
    summary["wall_s"] = round(time.perf_counter() - began, 2)
    summary["torque_off"] = [not s.torque_enabled for s in arm.servos]
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    ins = summary["instructions_per_tick"]
    say(f"  {summary['result']}: {summary['ticks']} ticks in {summary['wall_s']:.1f} s, fault {summary['fault']}, "
        f"{summary['limited_ticks']} ticks limiting")
    if summary["tracking_max_rad"] is not None:
        say(f"  swing tracking: rms {np.degrees(summary['tracking_rms_rad']):.3f} deg, "
            f"max {np.degrees(summary['tracking_max_rad']):.3f} deg")
    say(f"  goals vs the host's double controller on the same measurements: largest difference "
        f"{summary['goal_max_diff_units']} unit(s) over {summary['goal_writes']} writes")
    if "tick" in ins:
        say("  instructions per tick (worst / mean): " + ", ".join(
            f"{k} {v['max']}/{v['mean']}" for k, v in ins.items()))
    say(f"  stack used {summary['stack_used_bytes']} B; wrote {out / 'summary.json'}")
    return summary
