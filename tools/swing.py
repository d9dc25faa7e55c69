"""`servodyn swing`: the tennis forehand on servos — real ones on a serial port, or (the default)
the simulated Dynamixel bus (when neither --port nor the configuration's port names one), which
speaks the same protocol to the same driver; or, for a loopback configuration, the model alone behind the HAL.

plan → run → summarize → write: the swing is sampled at small_time_step and planned with its
homing move and gain schedules; the loop (servodyn.loop) homes the arm and plays it, one read and
one write a tick; a servo error, a non-finite torque, SIGINT or SIGTERM stops the run safely
(torque off on every servo, the log kept up to the last tick), then the summary is written. The
log streams to OUT/swing_log.csv as the run goes (on disk at least every 100 ms: a SIGKILL loses
at most that); a previous run's summary and figure are removed first, so none looks current.
"""

from __future__ import annotations

import json
import math
import signal
import threading
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from ..control import ControlConfig, ControlFault, Controller
from ..control.motion import motion_path
from ..control.schedule import plan_run
from ..control.timing import HOME_DURATION, TIME_STEP, plant_step
from ..control.trajectory import MotionPath, Trajectory
from ..errors import InputError, ServodynError, exit_code
from ..hal.backend import joint_sensors
from ..hal.config import RobotConfig, load_config
from ..hal.errors import ServoError
from ..hal.ports import is_pseudo_terminal
from ..hal.robot import Robot
from ..loop import CHATTER_CUTOFF_HZ, Interrupted, Overrun, RunLog, follow, summarize
from ..loop.realtime import one_cpu
from ..validation import MotionRefused, judge
from .native import BUILT_FOR, fault_message, run_native
from .plots import tracking_figure
from .simulator import SIM_REPLY_TIMEOUT, SimProcess, serve

DEFAULT_MOTION = "tennis_forehand"

MOTION_FAULTS = ("nan_motion",)    # faults of the played motion, not of the bus


def _signals_stop_the_run(stopping: dict):
    """From now on SIGINT and SIGTERM raise Interrupted in the loop, once: a second one, or one
    that comes while the bus is being stopped (stopping["now"]), is ignored so the stop
    completes. Returns the function that puts the previous handlers back."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def handler(signum, frame):
        if not stopping["now"]:
            stopping["now"] = True
            raise Interrupted(signum)
    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    return lambda: [signal.signal(sig, old) for sig, old in previous.items()]


def run_swing(config_name: str | RobotConfig = "replica", port: str | None = None, out: Path = Path("out/swing"),
              feedforward: bool = True, time_scale: float | None = None, realtime: bool = False,
              say=print, fault_at: tuple | None = None, motion: str = DEFAULT_MOTION,
              force: bool = False, native: bool = False, observer=None, home_duration: float = HOME_DURATION,
              figure: bool = True, overrun_tolerance: float | None = None, log: RunLog | None = None,
              confirm=None, hold: float | None = None, dry_run: bool = False) -> dict:
    """Validate, home, play, log; returns the summary. `motion` is a built-in motion, a keyframe
    file or a trajectory CSV, played `time_scale` times slower (default: the configuration's for
    the forehand, else 1). Before anything moves the validator checks it against every servo
    limit; a failing motion raises MotionRefused with its first violation, unless `force` on the
    simulated bus. fault_at = (time, servo id) or (time, servo id, fault): on the simulated bus,
    that servo stops answering then (fault "silent", the default), or raises Hardware Error Status
    bits ("overload", "overheating", ... or the bits as an int), or any other fault of
    SimulatedRobot.inject_fault, or "nan_motion" (the motion's position of that joint becomes NaN
    from then on), to show the safe stop. native: the firmware's loop plays it as a Linux process
    (tools/native.py) instead of the Python loop, with the same summary. observer: called by the
    loop with every tick's state (servodyn.loop.follow), e.g. the browser view's. home_duration: s
    of the homing move (shorter for the soak, whose motions start where the simulated arm does);
    figure: write the tracking plot. overrun_tolerance: s the real-time loop may fall behind its
    schedule before it stops (default OVERRUN_TOLERANCE). log: the RunLog to fill (default a new
    one), for a caller that reads the run's own states afterwards.

    A first motion a person can trust: confirm(lines) is asked, with each joint's homing distance,
    before torque goes on (None: not asked; the CLI asks on a real port unless --yes), and a False
    answer ends the run before anything moved (Declined). hold: s to hold the pose the arm is in
    under the controller (validated there), instead of the motion. dry_run: read the arm with
    torque off and log the planned homing with the torques the controller would send, sending
    none."""
    config = config_name if isinstance(config_name, RobotConfig) else load_config(config_name)
    model = config.model
    if time_scale is not None:
        scale = time_scale       # as given: 0 is refused by the validator, not replaced
    else:
        scale = (config.swing_time_scale if motion == DEFAULT_MOTION else None) or 1.0
    if not (math.isfinite(scale) and scale > 0):
        raise InputError(f"--time-scale must be a positive number, got {scale}")
    path = motion_path(motion, model)
    verdict = judge(config, path, scale) if hold is None else None
    ports = bus_ports(config, port)
    bus_config = next(iter(config.buses.values()))
    simulated = not ports or bus_config.kind == "loopback"
    if hold is not None and not (math.isfinite(hold) and hold > 0):
        raise InputError(f"--hold must be a positive number of seconds, got {hold:g}")
    if verdict is not None and not verdict.passed:
        first = verdict.violations[0]["message"]
        if not (force and simulated):
            found = [v["message"] for v in verdict.violations]
            more = f"{len(found)} violations, --verbose lists them; " if len(found) > 1 else ""
            raise MotionRefused(f"'{path.name}' at time scale {scale:g} would leave a servo's limits: {first}"
                                f" ({more}servodyn validate {config.name} {motion} --fit finds a time scale that "
                                f"passes{'; --force plays it anyway on the simulated bus' if simulated else ''})", found)
        say(f"forced past the validator: {first}")
    period = config.control_period
    swing = path.at_scale(scale, period)
    mode = "feedforward_pd" if feedforward else "pd"
    paced = None
    if native:
        if hold is not None or dry_run:
            raise InputError("--hold and --dry-run run in the Python loop, not with --native")
        _check_native(config, motion, scale, mode, fault_at)
    if not simulated and not realtime and any(not is_pseudo_terminal(path) for path in ports.values()):
        # lock-step means "as fast as the bus answers": on real servos that would play the motion
        # faster than it was validated for, so a real bus always keeps the period on the wall clock
        realtime = True
        paced = f"real servos: the loop keeps its {period * 1e3:g} ms period on the wall clock (real time)"
    out.mkdir(parents=True, exist_ok=True)    # an unusable output folder fails before anything moves
    for stale in ("summary.json", "swing_tracking.png"):
        (out / stale).unlink(missing_ok=True)

    # real time on the simulated Dynamixel bus: the loop, the simulator's process and the kernel's
    # tty work that carries their bytes share one CPU for the run (loop.realtime.one_cpu); the
    # CAN buses are simulated in this process, with no tty between them and the loop
    placed = ExitStack()
    on_pty = simulated and all(b.kind == "dynamixel" for b in config.buses.values())
    cpu = placed.enter_context(one_cpu(say=say)) if realtime and on_pty else None
    try:
        def buses():
            if simulated and bus_config.kind != "loopback":
                return _simulated_buses(config, realtime, say)
            return None, {name: _real_bus(config.buses[name], path, say) for name, path in ports.items()}

        if native:
            server, per_bus = buses()
            return _native_swing(server, per_bus[bus_config.name]["port"], config, swing, verdict, scale, mode,
                                 realtime, out, say, overrun_tolerance, cpu)
        server, per_bus = buses()
        bus = Robot(config, options=per_bus)     # every bus of the configuration, one tick
        try:
            bus.open()        # a port that does not open ends here: nothing ran, so no log and no summary
        except BaseException:
            if server is not None:
                server.stop()
            raise
        if paced:
            say(paced)
        try:
            start_pose = bus.read_state().q
            if hold is not None:
                swing, verdict, path = _hold_motion(config, start_pose, hold, period)
                home_duration = 2 * period
            # a person at a real arm is asked (the simulator's pseudo-terminals are no real port)
            real = not simulated and any(not is_pseudo_terminal(p) for p in ports.values())
            if real or dry_run:
                _homing_distances(config, start_pose, swing.q[0], say, confirm if real else None, dry_run)
                if real:
                    start_pose = None      # a person took their time: where the arm is now, read again
        except BaseException:
            bus.stop()
            if server is not None:
                server.stop()
            raise
        friction = config.friction if feedforward else {}      # compensated with the feed-forward
        controller = Controller(model, ControlConfig(mode=mode, small_time_step=period, **friction),
                                q_start=swing.q[0])
        log = RunLog(model.dof_names) if log is None else log
        log.stream(out / "swing_log.csv")
        error = None
        planned_ticks = len(swing.t)
        swing_start = 0.0
        home_ticks = 0
        stopping = {"now": False}
        restore_signals = _signals_stop_the_run(stopping)
        try:
            home, played = plan_run(model, swing, bus.read_state().q if start_pose is None else start_pose,
                                    home_duration, joint_sensors(config))
            if dry_run:
                say(f"dry run: torque off; the homing's {home.traj.t[-1]:g} s read and logged with the torques "
                    "the controller would send (none is sent)")
                follow(DryRun(bus), controller, home, log, realtime, observer=observer, tolerance=overrun_tolerance)
                planned_ticks = len(home.traj.t)
                raise _DryRunDone
            bus.enable_torque(True)     # arms the Bus Watchdog: from here the bus must not go quiet
            say(f"homing to the swing's start pose over {home.traj.t[-1]:g} s ...")
            home_ticks = len(home.traj.t)
            # homing's deadlines are the run's too (the native loop's count has them)
            log.missed += follow(bus, controller, home, realtime=realtime, observer=observer, tolerance=overrun_tolerance)
            say(f"{path.name}: {swing.t[-1]:.1f} s (time scale {scale:g}, validated against the "
                f"servos' limits), {mode.replace('_', ' + ')}, inverse dynamics every "
                f"{TIME_STEP * 1e3:g} ms, {1 / period:g} Hz target")
            # the plant's time when the swing begins: in lock-step one period per homing tick (asking
            # the simulator would race it: it may not have taken the last homing write yet, a sync
            # write gets no reply); in real time, the plant clock now
            swing_start = (server.status()["time"] if realtime else len(home.traj.t) * period) \
                if server is not None else 0.0
            follow(bus, controller, played, log, realtime, on_tick=_fault_injector(server, fault_at, played, config),
                   observer=observer, tolerance=overrun_tolerance,
                   progress=lambda t, f, err: say(f"  t = {t:5.2f} s  {100 * f:5.1f} %  "
                                                  f"largest error {np.degrees(err):6.3f} deg"))
        except _DryRunDone:
            stopping["now"] = True
        except (ServoError, FloatingPointError, ControlFault, Interrupted) as err:
            stopping["now"] = True
            error = err
            say(f"{'servo error' if isinstance(err, ServoError) else 'stopped'}: {err} — torque off on every servo")
        except Overrun as err:
            stopping["now"] = True
            error = err
            say(f"{err} — torque off on every servo")
        except BaseException:
            restore_signals()
            raise
        finally:
            stopping["now"] = True
            bus.stop()
            sim = server.status() if server is not None else None
            if server is not None:
                server.stop()
            log.close()
        summary = summarize(log, planned_ticks, period, realtime, error)
        summary.update(error_class=type(error).__name__ if error else None, exit_code=exit_code(error))
        summary.update(motion=path.name, mode=mode, time_scale=scale, validated=verdict.passed,
                       loop="python", bus=bus.stats.as_dict(bus.dof_names), home_ticks=home_ticks, cpu=cpu,
                       dry_run=dry_run, hold_s=hold)
        if isinstance(error, Interrupted):
            summary["signal"] = signal.Signals(error.signum).name
        if sim is not None:
            # what the simulated servos saw: plant time at the stop and every torque switched off
            summary["sim_time_at_stop_s"] = sim["time"] - swing_start     # on the swing's clock
            summary["torque_off"] = sim["torque_off"]
        try:
            _write(out, log, summary, say, figure, config)
        finally:
            restore_signals()          # until the summary is written a signal is ignored, not fatal
        return summary

    finally:
        placed.close()

class Declined(ServodynError):
    """The person at the arm said no before it moved."""
    exit_code = 1


class _DryRunDone(ServodynError):
    """The dry run's homing is logged: the run ends there (not an error)."""


class DryRun:
    """A bus that reads and never drives: torque stays off and every write is dropped (the log
    keeps the torques the controller asked for)."""

    def __init__(self, bus):
        self._bus = bus
        self.dropped = 0

    def read_state(self):
        return self._bus.read_state()

    def write(self, command) -> None:
        self.dropped += 1

    def enable_torque(self, on: bool) -> None:
        pass


def _hold_motion(config, q, seconds: float, period: float):
    """Hold pose q for `seconds`: the trajectory, its validator's verdict (gravity at that pose),
    and its path."""
    n = max(2, int(round(seconds / period)) + 1)
    q = np.asarray(q, dtype=float)
    traj = Trajectory(t=np.arange(n) * period, q=np.tile(q, (n, 1)), qd=np.zeros((n, len(q))),
                      qdd=np.zeros((n, len(q))), derived=False)
    path = MotionPath.of_trajectory("hold", traj)
    verdict = judge(config, path, 1.0)
    if not verdict.passed:
        raise MotionRefused(f"holding the present pose would leave a servo's limits: "
                            f"{verdict.violations[0]['message']}", [v["message"] for v in verdict.violations])
    return path.at_scale(1.0, period), verdict, path


def _homing_distances(config, q_now, q_start, say, confirm, dry_run: bool) -> None:
    """Say how far each joint will move to the start pose; ask `confirm` (None: do not ask)."""
    delta = np.degrees(np.asarray(q_start) - np.asarray(q_now))
    lines = [f"  {name:<24} {np.degrees(a):8.1f}° -> {np.degrees(b):8.1f}°  ({d:+7.1f}°)"
             for name, a, b, d in zip(config.model.dof_names, q_now, q_start, delta)]
    largest = int(np.argmax(np.abs(delta)))
    say(f"homing moves each joint from where it is to the start pose (largest: "
        f"{config.model.dof_names[largest]}, {abs(delta[largest]):.1f}°):")
    for line in lines:
        say(line)
    if confirm is not None and not dry_run and not confirm("torque on and move the arm?"):
        raise Declined("nothing moved: the move was not confirmed (--yes skips the question)")


def _real_bus(bus, path: str, say) -> dict:
    """The options of a bus on `path`: a pseudo-terminal is `servodyn sim` in another process (no
    adapter is a pty), which gets the simulated bus's patience, said in one line."""
    if not is_pseudo_terminal(path):
        return {"port": path}
    say(f"bus '{bus.name}': {path} is a pseudo-terminal, a simulated bus: replies may take up to "
        f"{SIM_REPLY_TIMEOUT[bus.kind]:g} s (a loaded machine holds them back)")
    return {"port": path, "reply_timeout": SIM_REPLY_TIMEOUT[bus.kind]}


def bus_ports(config: RobotConfig, port=None) -> dict[str, str]:
    """The port of each bus the swing drives on real hardware, {} for the simulated buses. `port`:
    None (each bus's configured port; "auto" means simulated), a path (a one-bus configuration), or
    a list of "BUS=PATH" items naming each bus of a configuration with several.
    Either every bus has a real port or none has: ValueError naming what is missing or unknown."""
    given = {}
    for item in [] if port is None else [port] if isinstance(port, str) else port:
        if "=" in item and item.split("=", 1)[0] in config.buses:
            name, path = item.split("=", 1)
        elif len(config.buses) == 1:
            name, path = next(iter(config.buses)), item
        else:
            raise InputError(f"'{config.name}' has {len(config.buses)} buses ({', '.join(config.buses)}): give "
                             f"each its port as --port BUS=PATH, not {item!r}")
        if not path or name in given:
            raise InputError(f"--port {name}=...: {'an empty path' if not path else 'given twice'}")
        given[name] = path
    ports = {name: given.get(name) or (bus.port if bus.port != "auto" else None)
             for name, bus in config.buses.items()}
    missing = [name for name, path in ports.items() if path is None]
    if len(missing) == len(ports):
        return {}
    if missing:
        raise InputError(f"bus '{missing[0]}' of '{config.name}' has no port while "
                         f"{', '.join(repr(n) for n in ports if n not in missing)} has one: give it as --port "
                         f"{missing[0]}=PATH (all buses real, or all simulated)")
    return ports


def _check_native(config: RobotConfig, motion: str, scale: float, mode: str, fault_at) -> None:
    """ValueError unless the native loop's generated tables are this run's."""
    if config.name != BUILT_FOR or motion != DEFAULT_MOTION or scale != config.swing_time_scale:
        raise InputError(f"--native plays what the firmware was generated for ('{BUILT_FOR}', {DEFAULT_MOTION}, "
                         f"its configuration's time scale): not '{config.name}', {motion} at {scale:g}")
    if mode != "feedforward_pd" or fault_at is not None:
        raise InputError("--native runs feed-forward + PD and injects no fault")


def _native_swing(server, port, config, swing, verdict, scale, mode, realtime, out, say,
                  overrun_tolerance: float | None = None, cpu: int | None = None) -> dict:
    """The firmware's loop as a Linux process plays the swing on the port; the same summary (and
    `cpu`: the one CPU of the real-time path, None when not placed, loop.realtime.one_cpu)."""
    say(f"native loop on {port} ({'real time' if realtime else 'lock-step'}) ...")
    try:
        tolerance = "" if overrun_tolerance is None else f"tolerance_us={round(overrun_tolerance * 1e6)}"
        report, log = run_native(port, config.model.dof_names, realtime, args=tolerance, say=say,
                                 reply_timeout=SIM_REPLY_TIMEOUT["dynamixel"] if server is not None else None)
    finally:
        sim = server.status() if server is not None else None
        if server is not None:
            server.stop()
    error = fault_message(report)
    summary = summarize(log, len(swing.t), config.control_period, realtime, error)
    summary.update(motion=verdict.path.name, mode=mode, time_scale=scale, validated=verdict.passed,
                   loop="native", bus={"reads": report.get("ticks"), "writes": report.get("ticks"),
                                       "reads_retried": 0, "limited_ticks": report.get("limited")},
                   native={k: report.get(k) for k in ("result", "fault", "code", "servo", "fault_tick", "ticks",
                                                      "missed", "lost", "exit_code", "notes")},
                   cpu=cpu, home_ticks=report.get("home_ticks"), exit_code=(report.get("exit_code") or 2) if error else 0)    # the firmware's fault code
    if sim is not None:
        # on the swing's clock in lock-step; in real time the plant's clock at the swing's start is
        # the native process's to know, not this one's
        summary["sim_time_at_stop_s"] = None if realtime else sim["time"] - report["home_ticks"] * config.control_period
        summary["torque_off"] = sim["torque_off"]
    if error:
        say(f"{error} — torque off on every servo")
    log.write_csv(out / "swing_log.csv")
    _write(out, log, summary, say, config=config)
    return summary


def _simulated_buses(config, realtime: bool, say):
    """The configuration's buses simulated (servodyn.tools.simulator.serve), and the options that
    point each bus's backend at its simulated bus."""
    server = serve(config, "realtime" if realtime else "lockstep")
    clock = "real time" if realtime else "lock-step"
    if isinstance(server, SimProcess):
        say(f"simulated bus: {server.servos} virtual servos of '{config.name}' on {server.path} ({clock}, its own "
            f"process), the plant integrated by RK4 at {plant_step(config.control_period) * 1e3:g} ms")
    else:
        for name, where in server.where.items():
            say(f"simulated {config.buses[name].kind} bus '{name}': {len(config.joints_on(name))} devices of "
                f"'{config.name}' on {where} ({clock})")
    return server, server.buses


def _fault_injector(server, fault_at, played, config):
    """on_tick for follow(): fault_at's fault before its tick, on the simulated bus or, for a
    motion fault, in the played motion."""
    if fault_at is None or server is None:
        return None
    fault_tick = int(round(fault_at[0] / config.control_period))
    fault = fault_at[2] if len(fault_at) > 2 else "silent"

    def inject(k):
        if k != fault_tick:
            return
        if fault == "nan_motion":
            dof = next(j.dof for j in config.joints if j.id == fault_at[1])
            played.traj.q[k:, config.model.dof_names.index(dof)] = np.nan
        else:
            server.inject_fault(fault_at[1], fault)
    return inject


def _title(summary: dict, config: RobotConfig | None) -> str:
    """The figure's title: what played, where, and under which control (PD only says so)."""
    control = "PD only, no feed-forward" if summary.get("mode") == "pd" else "feed-forward + PD"
    return f"{summary['motion']} on {config.name if config is not None else 'the servo bus'}: {control}"


def _write(out: Path, log: RunLog, summary: dict, say, figure: bool = True, config: RobotConfig | None = None) -> None:
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if not log.t:
        say(f"wrote {out / 'swing_log.csv'}, {out / 'summary.json'}")
        return
    e = np.array(log.q_d) - np.array(log.q)
    buzz = summary.get("chatter_by_dof") or {}
    say(f"\n  {'':<24} {'tracking error':>21}   {'torque above ' + format(CHATTER_CUTOFF_HZ, 'g') + ' Hz':>25}")
    say(f"  {'dof':<24} {'rms (deg)':>10} {'max (deg)':>10}   {'rms/peak (%)':>12} {'p-p (N m)':>12}")
    for k, name in enumerate(log.dof_names):
        noise = (f"{100 * buzz[name]['rms_share']:>12.2f} {buzz[name]['peak_to_peak_nm']:>12.3f}"
                 if name in buzz else f"{'-':>12} {'-':>12}")
        say(f"  {name:<24} {np.degrees(np.sqrt(np.mean(e[:, k]**2))):>10.3f} "
            f"{np.degrees(np.abs(e[:, k]).max()):>10.3f}   {noise}")
    if summary.get("chatter_max") is not None:
        met = (summary["chatter_max"] <= summary["chatter_goal"]
               and summary["tracking_max_rad"] <= summary["tracking_goal_rad"])
        say(f"  goal: chatter <= {100 * summary['chatter_goal']:g} % of each joint's peak torque (worst "
            f"{100 * summary['chatter_max']:.2f} %) with the largest error <= "
            f"{np.degrees(summary['tracking_goal_rad']):g} deg (worst {np.degrees(summary['tracking_max_rad']):.3f} "
            f"deg): {'met' if met else 'not met'}")
    cpu = summary["cpu_ms_per_tick"]
    say(f"\n  loop {summary['loop_hz']:.0f} Hz, {summary['clock']} (period median "
        f"{summary['period_median_ms']:.3f} ms, p99 jitter {summary['jitter_p99_ms']:.3f} ms; CPU per tick "
        f"median {cpu['median']:.3f} ms, p99 {cpu['p99']:.3f} ms); tracking rms "
        f"{np.degrees(summary['tracking_rms_rad']):.3f} deg, max {np.degrees(summary['tracking_max_rad']):.3f} deg")
    if not figure:
        say(f"wrote {out / 'swing_log.csv'}, {out / 'summary.json'}")
        return
    limits = [j.torque_limit for j in config.joints] if config is not None else None
    steps = list(joint_sensors(config).position_step) if config is not None else None
    tracking_figure(out / "swing_tracking.png", np.array(log.t), np.array(log.q_d), np.array(log.q),
                    np.array(log.tau), log.dof_names, _title(summary, config), limits, steps)
    say(f"wrote {out / 'swing_log.csv'}, {out / 'summary.json'}, {out / 'swing_tracking.png'}")
