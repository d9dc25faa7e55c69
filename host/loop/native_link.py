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

import time
from contextlib import nullcontext
from pathlib import Path

from ..control.timing import OVERRUN_TOLERANCE
from ..errors import ExitCode, InputError, ServodynError
from ..hal.link import messages as ms
from ..hal.realtime import LOOP_PRIORITY, collector_paused, realtime_priority
from . import summarize, write_summary
from .agreement import agreement
from .link_controllers import NativeController, PortController
from .link_load import HOST_TIMEOUT_MS, check_config, plan
from .link_log import telemetry_log
from .link_session import ControllerRefused, LinkSession
from .native import FirmwareError, parse_report
from .qemu import QemuController

QUIET = ("servodyn-fw: ", "servodyn-board: ", "qemu-system-arm: -serial")   # the report, QEMU's socket set-up
QEMU_ANSWER_TIMEOUT = 1.0      # s: emulated, lock-stepped ticks are slower than the wall clock's
LOCKSTEP_ANSWER_TIMEOUT = 0.25  # s between retransmissions in lock-step: 2.25 s of silence ends the run
LOCKSTEP_TIMEOUT_MS = 60000    # lock-step runs as fast as the bus answers: the watchdog counts its ticks
KEEPALIVE = 0.02               # s between two frames of the host when it has nothing else to send
STOP_TIMEOUT = 10.0            # s the controller has to end after torque off
SERVED_PATIENCE = 2.0          # s the simulator has to serve the controller's last bytes (its torque off)


class Declined(ServodynError):
    """The person at the arm said no before it moved."""
    exit_code = 1


def check_link(config, choice, motion: str, mode: str, fault_at, contacts=()) -> None:
    """FirmwareError unless the general application that `choice` names can play this run."""
    try:
        check_config(config)
    except InputError as err:
        raise FirmwareError(f"--controller {choice}: {str(err).removeprefix('host link: ')}") from None
    if choice.kind == "qemu" and any(bus.kind != "dynamixel" for bus in config.buses.values()):
        raise FirmwareError(f"--controller {choice}: QEMU models no CAN controller; the board's image under it drives "
                            f"its Dynamixel bus alone, and '{config.name}' has a CAN bus (--controller native plays it "
                            "through an SLCAN adapter)")
    if mode != "feedforward_pd" or fault_at is not None:
        raise FirmwareError(f"--controller {choice} runs feed-forward + PD and injects no fault")
    if contacts:
        raise FirmwareError(f"--controller {choice}: --contact's pushes are timed by the Python loop; the simulated "
                            "plant's --obstacle works on every controller")


def _play(session: LinkSession, p, controller, timeout: float) -> None:
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
        if controller.poll() is not None:
            session.pump(0.05)                 # its last frames
            t = session.last
            if t is not None and t.flags & ms.TM_HOST_SILENT:
                raise FirmwareError(f"the {controller.name} controller held, then switched torque off at tick "
                                    f"{t.tick}: this host fell silent on the host link for over "
                                    f"{p.messages[0].host_timeout_ms} ms")
            state = f"{ms.STATES[t.state]}, flags {t.flags}, tick {t.tick}" if t is not None else "no telemetry"
            raise FirmwareError(f"the {controller.name} controller stopped (exit {controller.poll()}; {state}): "
                                f"{controller.finish(STOP_TIMEOUT).strip()[-300:]}")
        if now > deadline:
            raise FirmwareError(f"the {controller.name} controller's run did not end within {timeout:g} s")


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


def start_controller(choice, buses: dict | None, run):
    """The controller `choice` names (link_controllers.parse_controller) for this run, started;
    `buses`: each bus's options (the native controller's ports)."""
    config = run.config
    if choice.kind == "native":
        tolerance = run.options.overrun_tolerance
        return NativeController(bus_arguments(config, buses), realtime=run.realtime,
                                tolerance_us=round((OVERRUN_TOLERANCE if tolerance is None else tolerance) * 1e6))
    if choice.kind == "qemu":
        if run.arm is None:
            raise FirmwareError(f"--controller {choice}: this run was given no simulated arm to serve QEMU")
        arm = run.arm(config, run.options.obstacles)
        return QemuController(choice.board, arm, next(iter(config.buses.values())).baud)
    return PortController(choice.path)


def drive(controller, p, home_ms: int, realtime: bool, before_home=None, qemu: bool = False):
    """Play plan `p` on a started controller: hello, load, stream, HOME (before_home() first, which
    may raise), PLAY, keep the link fed to the motion's end, torque off. (session, error, exit
    code): error is None for a motion played to its end, else one line (a fault, a link lost)."""
    name = controller.name
    error, code = None, 0
    session = LinkSession(controller.fd)
    if not realtime:    # the controller keeps pace with a simulator that a busy machine may hold back
        session.sender.timeout = QEMU_ANSWER_TIMEOUT if qemu else LOCKSTEP_ANSWER_TIMEOUT
    session.hello()
    session.load(p.messages)
    session.stream(p)
    if before_home is not None:
        before_home()
    session.command("home", home_ms)
    del session.telemetry[:]       # what came before HOME's answer is an earlier state (a board stays on)
    played = session.command("play", check=False)
    if played.code != 0:           # refused: a fault while homing says why, else the refusal does
        session.pump(0.05)
        if session.last is None or not session.last.fault:
            raise ControllerRefused(f"the controller refused play: {ms.reason(played)}")
    else:
        try:
            with collector_paused(), realtime_priority(LOOP_PRIORITY) if realtime else nullcontext():
                # the host keeps the controller's watchdog fed: in real time at the Python loop's priority
                _play(session, p, controller, timeout=600.0 + 10 * len(p.swing.t) * p.period)
        except ServodynError as err:      # the link or the controller lost mid-motion: its log is kept
            error, code = f"{name} controller: {err}", int(getattr(err, "exit_code", ExitCode.BAD_INPUT))
    last = session.last
    if error is None and last.fault:
        joint = f", joint {p.dof_names[last.fault_joint]}" if last.fault_joint < 255 else ""
        error, code = f"{name} controller: fault {ms_fault(last.fault)} (code {last.fault}){joint}", last.fault
    elif error is None and ms.STATES[last.state] == "torque_off":
        error, code = f"{name} controller: torque off before the motion's end (the host link fell silent)", 2
    if error is None or last is not None and ms.STATES[last.state] not in ("fault", "torque_off"):
        try:
            session.command("torque_off")
        except ServodynError:
            pass                   # a controller that no longer answers switches off on its watchdog
    return session, error, code


def link_swing(choice, server, buses: dict | None, run, out: Path) -> dict:
    """The run played by the general application that `choice` names (the Python loop's summary
    keys); `buses`: each bus's options, its port first (the native controller's)."""
    config, say = run.config, run.say
    realtime = run.realtime and choice.kind != "qemu"
    p = plan(config, run.motion, HOST_TIMEOUT_MS if realtime else LOCKSTEP_TIMEOUT_MS, time_scale=run.scale)
    ports = ", ".join(str(b["port"]) for b in (buses or {}).values())
    where = {"native": f"the native controller on {ports}", "qemu": f"the controller under QEMU ({choice})",
             "port": f"the controller on {choice.path}"}[choice.kind]
    say(f"{where} over the host link ({'real time' if realtime else 'lock-step'}) ...")
    controller = None
    sim = None
    try:
        controller = start_controller(choice, buses, run)
        def before_home():
            if choice.kind == "port" or (choice.kind == "native" and server is None):     # a real arm
                say(f"{where} will switch torque on, home the arm to the start pose of {run.verdict.path.name} "
                    f"over {run.options.home_duration:g} s and play it")
                if run.confirm is not None and not run.confirm("torque on and move the arm?"):
                    raise Declined("nothing moved: the move was not confirmed (--yes skips the question)")
        session, error, code = drive(controller, p, round(run.options.home_duration * 1e3), realtime, before_home,
                                     qemu=choice.kind == "qemu")
        notes = controller.finish(STOP_TIMEOUT)
    finally:
        if controller is not None:
            controller.close()
        sim = served_status(server) if server is not None else None
        if server is not None:
            server.stop()
    report = parse_report(notes)
    for note in (line for line in notes.splitlines() if line.strip() and not line.startswith(QUIET)):
        say(note)
    log = telemetry_log(config, session.telemetry)
    summary = summarize(log, len(run.swing.t), config.control_period, realtime, error)
    summary.update(motion=run.verdict.path.name, mode=run.options.mode, time_scale=run.scale,
                   validated=run.verdict.passed, loop="native-link" if choice.kind == "native" else str(choice),
                   controller=str(choice), cpu=run.cpu,
                   bus={"reads": len(log.t), "writes": len(log.t), "reads_retried": 0,
                        "limited_ticks": sum(1 for t in session.telemetry if t.flags & ms.TM_LIMITED)},
                   link={"bytes_in": session.bytes_in, "bytes_out": session.bytes_out,
                         "retransmissions": session.sender.retransmissions,
                         "lost_from_controller": session.sender.lost_from_controller},
                   controller_report={k: v for k, v in report.items() if k != "counts"},
                   exit_code=code if error else 0)
    summary["stop_reason"] = "completed" if error is None and summary["completed"] else (
        ms_fault(code) if error else "incomplete")
    if sim is not None:
        summary["sim_time_at_stop_s"] = None
        summary["torque_off"] = sim["torque_off"]
    elif choice.kind == "qemu":
        summary["torque_off"] = controller.record.torque_off
        # what crossed the simulated bus: each command against the host's double controller
        summary["agreement"] = agreement(config, p, controller.record)
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
