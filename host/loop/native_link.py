"""`servodyn swing --controller native`: the general firmware application as a Linux process
(`build/fw/native/servodyn-fw-link`, firmware/app/fw_link.c, `make fw`) plays the run: the host
loads the configuration and streams the motion's knots over the host link (a pseudo-terminal),
commands home and play, and builds the Python loop's log and summary from the telemetry
(servodyn.loop.link_log). Unlike `--native` (the generated firmware: the replica and the forehand
only), any configuration on a Dynamixel bus, a CAN bus or one of each, and any keyframed motion,
plays: the Dynamixel bus on its serial port (the process's PORT), the CAN bus through an SLCAN
adapter on a tty (can=PATH: a CANable's /dev/ttyACM0, or the simulator's, which serves one for
this controller).
"""

from __future__ import annotations

import os
import subprocess
import time
import tty
from contextlib import nullcontext
from pathlib import Path

from ..control.timing import OVERRUN_TOLERANCE
from ..errors import ExitCode
from ..hal.link import messages as ms
from ..hal.realtime import LOOP_PRIORITY, collector_paused, realtime_priority
from . import summarize, write_summary
from .link_load import HOST_TIMEOUT_MS, buses_refused, plan
from .link_log import telemetry_log
from .link_session import LinkSession
from .log import RunLog
from .native import FirmwareError

ROOT = Path(__file__).resolve().parents[2]
NATIVE_LINK = ROOT / "build" / "fw" / "native" / "servodyn-fw-link"
LOCKSTEP_TIMEOUT_MS = 60000    # lock-step runs as fast as the bus answers: the watchdog counts its ticks
KEEPALIVE = 0.02               # s between two frames of the host when it has nothing else to send
STOP_TIMEOUT = 10.0            # s the controller has to end after torque off
SERVED_PATIENCE = 2.0          # s the simulator has to serve the controller's last bytes (its torque off)


def check_link(config, motion: str, mode: str, fault_at) -> None:
    """FirmwareError unless the general application can play this run."""
    why = buses_refused(config)
    if why:
        raise FirmwareError(f"--controller native drives {why}")
    if str(motion).lower().endswith(".csv"):
        raise FirmwareError("--controller native streams a motion's keyframes: give a built-in motion or a keyframe "
                            f"file, not a sampled trajectory ({motion})")
    if mode != "feedforward_pd" or fault_at is not None:
        raise FirmwareError("--controller native runs feed-forward + PD and injects no fault")


def _play(session: LinkSession, p, proc, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    last_sent = time.monotonic()
    while True:
        session.pump(0.002)
        sent = session.sender.sendings
        session.stream(p)
        now = time.monotonic()
        if session.sender.sendings != sent:
            last_sent = now
        elif now - last_sent > KEEPALIVE and session.sender.idle:
            session.sender.send(ms.Command(command=ms.COMMANDS["keepalive"], arg=0))
            last_sent = now
        t = session.last
        if t is not None and (t.flags & ms.TM_DONE or ms.STATES[t.state] in ("fault", "torque_off")):
            return
        if proc.poll() is not None:
            session.pump(0.05)                 # its last frames
            t = session.last
            if t is not None and t.flags & ms.TM_HOST_SILENT:
                raise FirmwareError(f"the native controller held, then switched torque off at tick {t.tick}: this "
                                    f"host fell silent on the host link for over {p.messages[0].host_timeout_ms} ms")
            state = f"{ms.STATES[t.state]}, flags {t.flags}, tick {t.tick}" if t is not None else "no telemetry"
            raise FirmwareError(f"the native controller stopped (exit {proc.returncode}; {state}): "
                                f"{proc.stderr.read().strip()[-300:]}")
        if now > deadline:
            raise FirmwareError(f"the native controller's run did not end within {timeout:g} s")


def bus_arguments(config, buses: dict) -> list[str]:
    """The process's bus arguments: the Dynamixel bus's port and baud, the CAN bus's SLCAN tty and
    bit rate, the longest reply time a simulated bus asks for; `buses`: each bus's options (the run's)."""
    out = []
    for name, bus in config.buses.items():
        port = buses[name]["port"]
        if bus.kind == "can":
            if not str(port).startswith("/dev/"):
                raise FirmwareError(f"--controller native reaches a CAN bus through an SLCAN adapter on a tty "
                                    f"(/dev/ttyACM0, ...); bus '{name}' is on {port}")
            out += [f"can={port}", f"can_bitrate={bus.baud}"]
        else:
            out = [port, *out, f"baud={bus.baud}"]
    replies = [options["reply_timeout"] for options in buses.values() if "reply_timeout" in options]
    if replies:
        out.append(f"reply_ms={round(max(replies) * 1e3)}")
    return out


def link_swing(server, buses: dict, run, out: Path, exe: Path | None = None) -> dict:
    """The run played by the general application on the run's buses (`buses`: each bus's options,
    its port first; the Python loop's summary keys)."""
    config, say = run.config, run.say
    exe = Path(exe) if exe else NATIVE_LINK
    if not exe.is_file():
        raise FirmwareError(f"no native controller at {exe} (build it with `make fw`)")
    p = plan(config, run.motion, HOST_TIMEOUT_MS if run.realtime else LOCKSTEP_TIMEOUT_MS, time_scale=run.scale)
    arguments = bus_arguments(config, buses)
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    command = [str(exe), *arguments, f"link={os.ttyname(slave)}", "once=1"]
    if run.realtime:
        tolerance = run.options.overrun_tolerance
        command += ["realtime", f"tolerance_us={round((OVERRUN_TOLERANCE if tolerance is None else tolerance) * 1e6)}"]
    ports = ", ".join(buses[name]["port"] for name in config.buses)
    say(f"native controller on {ports} over the host link ({'real time' if run.realtime else 'lock-step'}) ...")
    proc = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    session = LinkSession(master)
    error = None
    try:
        session.hello()
        session.load(p.messages)
        session.stream(p)
        session.command("home", round(run.options.home_duration * 1e3))
        session.command("play")
        with collector_paused(), realtime_priority(LOOP_PRIORITY) if run.realtime else nullcontext():
            # the host keeps the controller's watchdog fed: in real time at the Python loop's priority
            _play(session, p, proc, timeout=600.0 + 10 * len(p.swing.t) * config.control_period)
        last = session.last
        if last.fault:
            error = (f"native controller: fault {ms_fault(last.fault)} (code {last.fault})"
                     + (f", joint {config.model.dof_names[last.fault_joint]}" if last.fault_joint < 255 else ""))
        elif ms.STATES[last.state] == "torque_off":
            error = "native controller: torque off before the motion's end (the host link fell silent)"
        if ms.STATES[last.state] not in ("fault", "torque_off"):
            session.command("torque_off")
        proc.wait(timeout=STOP_TIMEOUT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
        os.close(slave)
        sim = served_status(server) if server is not None else None
        if server is not None:
            server.stop()
    for note in (line for line in proc.stderr.read().splitlines() if line.strip()):
        say(note)
    playing = any(ms.STATES[t.state] == "playing" for t in session.telemetry)
    # a run that stopped before the motion (a fault while homing) has an empty log and says why
    log = telemetry_log(config, session.telemetry) if playing or error is None else \
        RunLog(tuple(config.model.dof_names))
    summary = summarize(log, len(run.swing.t), config.control_period, run.realtime, error)
    summary.update(motion=run.verdict.path.name, mode=run.options.mode, time_scale=run.scale,
                   validated=run.verdict.passed, loop="native-link", cpu=run.cpu,
                   bus={"reads": len(log.t), "writes": len(log.t), "reads_retried": 0,
                        "limited_ticks": sum(1 for t in session.telemetry if t.flags & ms.TM_LIMITED)},
                   link={"bytes_in": session.bytes_in, "bytes_out": session.bytes_out,
                         "retransmissions": session.sender.retransmissions,
                         "lost_from_controller": session.sender.lost_from_controller},
                   exit_code=(session.last.fault or 2) if error else 0)
    summary["stop_reason"] = "completed" if error is None and summary["completed"] else (
        ms_fault(session.last.fault) if session.last.fault else "incomplete")
    if sim is not None:
        summary["sim_time_at_stop_s"] = None
        summary["torque_off"] = sim["torque_off"]
    if error:
        say(f"{error} — torque off on every servo")
    log.write_csv(out / "swing_log.csv")
    run.log = log
    write_summary(out, summary)
    return summary


def served_status(server, patience: float = SERVED_PATIENCE) -> dict:
    """The simulator's status once it has served the controller's last bytes: the torque-off
    packet and frames the controller sent before it ended are read by the simulator's threads a
    moment later (every device off, or `patience` s)."""
    deadline = time.monotonic() + patience
    status = server.status()
    while not all(status["torque_off"]) and time.monotonic() < deadline:
        time.sleep(0.01)
        status = server.status()
    return status


def ms_fault(code: int) -> str:
    """A fault code's name (firmware/app/fw_app.h, the host's ExitCode)."""
    try:
        return ExitCode(code).name.lower()
    except ValueError:
        return f"fault {code}"
