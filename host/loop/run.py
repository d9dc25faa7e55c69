"""A run of a configuration: plan, home, play, stop, summarize — the swing as a library object.

    run = Run(config, RunOptions(motion="tennis_forehand", realtime=True), serve=sim.serve.serve)
    summary = run.play(Path("out/swing"))          # swing_log.csv and summary.json written there

`Run(config, options)` plans before anything opens: the motion sampled at the control period and
its time scale (`RobotConfig.time_scale_for`), the validator's verdict against every servo limit
(a failing motion raises MotionRefused, unless `force` on a simulated bus), and the port of each
bus (`hal.ports.bus_ports`). `play(out)` opens the buses — simulated ones through `serve`, given by
the caller (the loop never imports the simulator) — homes the arm, plays the motion one read and
one write a tick (`follow`), and on a servo error, a non-finite torque, an overrun, SIGINT or
SIGTERM stops safely (torque off on every servo, the log kept up to the last tick). The log
streams to OUT/swing_log.csv (on disk at least every 100 ms: a SIGKILL loses at most that); a
previous run's summary and figure are removed first, so none looks current. Figures and the
printed table are servodyn.report's.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..control import ControlConfig, ControlFault, Controller
from ..control.motion import motion_path
from ..control.schedule import plan_run
from ..control.timing import HOME_DURATION, MAX_PLAYED_DURATION, TIME_STEP
from ..control.trajectory import MotionPath, Trajectory
from ..errors import InputError, ServodynError, exit_code
from ..hal.backend import joint_sensors
from ..hal.config import RobotConfig, load_config
from ..hal.contact_spec import check_contacts
from ..hal.errors import ServoError
from ..hal.ports import PTY_REPLY_TIMEOUT, bus_ports, is_pseudo_terminal
from ..hal.realtime import one_cpu
from ..hal.robot import Robot
from ..hal.safety import REACTIONS
from ..hal.served_clock import served_clock
from ..validation import MotionRefused, judge
from . import Interrupted, Overrun, RunLog, follow, summarize, write_summary
from .native import check_native, native_swing
from .link_controllers import parse_controller
from .native_link import Declined, check_link, link_swing
from .contact import contact_observer
from .reaction import plan_reaction
from .safety import ContactStop, Guards, SafetyStop, stop_reason

MOTION_FAULTS = ("nan_motion",)    # faults of the played motion, not of the bus
STALE = ("summary.json", "swing_tracking.png")     # a previous run's results, removed before this one


class RunError(InputError):
    """A run's options that cannot be played (a hold of no length, --hold with --native)."""


@dataclass(frozen=True)
class RunOptions:
    """What a run plays and how; every field has the swing's default.

    motion: a built-in motion, a keyframe file or a trajectory CSV (None: the configuration's,
    `[swing] motion`), played `time_scale` times slower (None: the configuration's for its own
    motion, else 1). port: None (each bus's configured port;
    "auto" means simulated), a path, or "BUS=PATH" items (hal.ports.bus_ports). fault_at = (time,
    servo id) or (time, servo id, fault): on the simulated bus that servo stops answering then
    ("silent", the default), raises Hardware Error Status bits ("overload", ... or the bits as an
    int), any other fault of SimulatedRobot.inject_fault, or "nan_motion" (the motion's position
    of that joint becomes NaN from then on). native: the firmware's loop as a Linux process plays
    it instead of the Python loop. controller: "python" (the Python loop) or "native" (the general
    firmware application as a Linux process, over the host link: loop.native_link). home_duration: s of the homing move. overrun_tolerance: s the
    real-time loop may fall behind before it stops (None: OVERRUN_TOLERANCE). hold: s to hold the
    pose the arm is in under the controller instead of the motion. dry_run: read the arm with
    torque off and log the planned homing with the torques the controller would send, sending none.
    contacts, obstacles: hal.contact_spec's Push (its start from the motion's start) and Plane or
    Sphere, applied by the simulated plant (a simulated bus started by the run only)."""
    motion: str | None = None
    time_scale: float | None = None
    feedforward: bool = True
    realtime: bool = False
    force: bool = False
    native: bool = False
    controller: str = "python"
    port: str | tuple | list | None = None
    fault_at: tuple | None = None
    home_duration: float = HOME_DURATION
    overrun_tolerance: float | None = None
    hold: float | None = None
    dry_run: bool = False
    contacts: tuple = ()
    obstacles: tuple = ()

    @property
    def mode(self) -> str:
        return "feedforward_pd" if self.feedforward else "pd"


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


class _DryRunDone(ServodynError):
    """The dry run's homing is logged: the run ends there (not an error)."""


class Run:
    """One run of `config` with frozen `options` (module docstring). serve(config, mode) starts
    the simulated buses when the configuration's are simulated (servodyn.sim.serve.serve); say
    takes every progress line; confirm(question) is asked, with each joint's homing distance,
    before torque goes on at a real arm (None: not asked); observer is called by the loop with
    every tick's state; log: the RunLog to fill (default a new one). arm(config, obstacles): a
    simulated arm's bus port, for a controller that serves it itself (QEMU's;
    servodyn.sim.serve.simulated_arm)."""

    def __init__(self, config: str | RobotConfig, options: RunOptions = RunOptions(), *, serve=None, say=print,
                 confirm=None, observer=None, log: RunLog | None = None, arm=None):
        self.config = config if isinstance(config, RobotConfig) else load_config(config)
        self.options, self.serve, self.say, self.confirm, self.observer = options, serve, say, confirm, observer
        self.arm = arm
        self.log = log
        o = options
        self.motion = o.motion or self.config.swing_motion
        self.scale = o.time_scale if o.time_scale is not None else self.config.time_scale_for(self.motion)
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise RunError(f"a time scale is a positive number, not {self.scale}")
        if o.hold is not None and not (math.isfinite(o.hold) and 0 < o.hold <= MAX_PLAYED_DURATION):
            # checked before the hold's samples are made: 1e308 s would be terabytes
            raise RunError(f"a hold lasts a positive number of seconds up to {MAX_PLAYED_DURATION:g} (the longest "
                           f"a run plays), not {o.hold:g}")
        self.path = motion_path(self.motion, self.config.model)
        self.verdict = judge(self.config, self.path, self.scale) if o.hold is None else None
        self.ports = bus_ports(self.config, o.port)
        self.kind = next(iter(self.config.buses.values())).kind
        self.simulated = not self.ports or self.kind == "loopback"
        self._check_verdict()
        check_contacts(self.config.model, o.contacts, o.obstacles, self.simulated and self.kind != "loopback",
                       native=o.native)
        self.period = self.config.control_period
        self.swing = self.path.at_scale(self.scale, self.period)
        if o.native:
            if o.hold is not None or o.dry_run:
                raise RunError("--hold and --dry-run run in the Python loop, not with --native")
            check_native(self.config, self.motion, self.scale, o.mode, o.fault_at)
        self.controller = parse_controller(o.controller)
        if self.controller.kind != "python":
            if o.hold is not None or o.dry_run or o.native:
                raise RunError(f"--hold, --dry-run and --native run without --controller {self.controller}")
            check_link(self.config, self.controller, self.motion, o.mode, o.fault_at, o.contacts)
        self.realtime, self.paced = o.realtime, None
        if self.controller.kind == "qemu" and o.realtime:
            raise RunError(f"--controller {self.controller} runs in lock-step with the simulated arm: QEMU's "
                           "emulated clock is not the wall clock (drop --realtime)")
        if self.controller.kind == "port":
            self.realtime = True      # a board keeps its own period on its own clock
        if not self.simulated and not o.realtime and any(not is_pseudo_terminal(p) for p in self.ports.values()):
            # lock-step means "as fast as the bus answers": on real servos that would play the motion
            # faster than it was validated for, so a real bus always keeps the period on the wall clock
            self.realtime = True
            self.paced = f"real servos: the loop keeps its {self.period * 1e3:g} ms period on the wall clock (real time)"

    def _check_verdict(self) -> None:
        verdict = self.verdict
        if verdict is None or verdict.passed:
            return
        first = verdict.violations[0]["message"]
        if not (self.options.force and self.simulated):
            found = [v["message"] for v in verdict.violations]
            more = f"{len(found)} violations, --verbose lists them; " if len(found) > 1 else ""
            raise MotionRefused(
                f"'{self.path.name}' at time scale {self.scale:g} would leave a servo's limits: {first} ({more}"
                f"servodyn validate {self.config.name} {self.motion} --fit finds a time scale that passes"
                f"{'; --force plays it anyway on the simulated bus' if self.simulated else ''})", found)
        self.say(f"forced past the validator: {first}")

    # ------------------------------------------------------------------------------------ the buses

    def _match_clock(self) -> None:
        """A bus on a pseudo-terminal is a simulator in another process (`servodyn sim`): the loop
        keeps its plant's clock (hal.served_clock), lock-step only when every such bus says it
        serves lock-step; real time otherwise, which is right against either clock."""
        ptys = {name: path for name, path in self.ports.items() if is_pseudo_terminal(path)}
        if self.simulated or self.realtime or not ptys:
            return
        clocks = {name: served_clock(self.config, name, path) for name, path in ptys.items()}
        if all(clock == "lockstep" for clock in clocks.values()):
            return
        name = next(n for n, clock in clocks.items() if clock != "lockstep")
        said = "serves in real time" if clocks[name] == "realtime" else "does not say which clock it serves on"
        if self.config.buses[name].kind == "can":
            raise RunError(f"bus '{name}' on {ptys[name]} {said}, and a swing paced by the wall clock cannot keep its "
                           f"{self.period * 1e3:g} ms period through an SLCAN pseudo-terminal: serve it with "
                           f"`servodyn sim --config {self.config.argument} --lockstep`")
        self.realtime = True
        self.paced = (f"bus '{name}' on {ptys[name]}: the simulator there {said}: the loop keeps its "
                      f"{self.period * 1e3:g} ms period on the wall clock (real time) to match it")

    def _buses(self):
        """(the simulated buses or None, each bus's backend options)."""
        if self.simulated and self.kind != "loopback":
            if self.serve is None:
                raise RunError(f"'{self.config.name}' has no port: its buses are simulated, and this run was "
                               "given no simulator")
            clock = "real time" if self.realtime else "lock-step"
            # the native controller reaches a CAN bus through an SLCAN adapter: the simulator serves one
            slcan = {"can": "slcan"} if self.controller.kind == "native" else {}
            server = self.serve(self.config, "realtime" if self.realtime else "lockstep",
                                obstacles=self.options.obstacles, **slcan)
            for line in server.describe(self.config, clock):
                self.say(line)
            return server, server.buses
        return None, {name: self._real_bus(name, path) for name, path in self.ports.items()}

    def _real_bus(self, name: str, path: str) -> dict:
        """A bus on `path`: a pseudo-terminal is `servodyn sim` in another process (no adapter is a
        pty), which gets the simulated bus's patience, said in one line."""
        if not is_pseudo_terminal(path):
            return {"port": path}
        kind = self.config.buses[name].kind
        self.say(f"bus '{name}': {path} is a pseudo-terminal, a simulated bus: replies may take up to "
                 f"{PTY_REPLY_TIMEOUT[kind]:g} s (a loaded machine holds them back)")
        return {"port": path, "reply_timeout": PTY_REPLY_TIMEOUT[kind]}

    # ------------------------------------------------------------------------------------ the run

    def play(self, out: Path) -> dict:
        """Open, home, play, stop; write OUT/swing_log.csv and OUT/summary.json; the summary."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)    # an unusable output folder fails before anything moves
        for stale in STALE:
            (out / stale).unlink(missing_ok=True)
        # real time on the simulated Dynamixel bus: the loop, the simulator's process and the kernel's
        # tty work that carries their bytes share one CPU for the run (hal.realtime.one_cpu); the
        # CAN buses are simulated in this process, with no tty between them and the loop
        self._match_clock()
        if self.controller.kind in ("qemu", "port"):      # the simulated arm is QEMU's; a board's buses are its own
            self.cpu = None
            return link_swing(self.controller, None, None, self, out)
        with ExitStack() as placed:
            on_pty = self.simulated and all(b.kind == "dynamixel" for b in self.config.buses.values())
            self.cpu = placed.enter_context(one_cpu(say=self.say)) if self.realtime and on_pty else None
            server, per_bus = self._buses()
            if self.options.native:
                return native_swing(server, per_bus[next(iter(self.config.buses))]["port"], self, out)
            if self.controller.kind == "native":
                return link_swing(self.controller, server, per_bus, self, out)
            return self._play(server, per_bus, out)

    def _play(self, server, per_bus: dict, out: Path) -> dict:
        o, config, say = self.options, self.config, self.say
        self.plant_swing_start = 0.0             # the swing's start on the simulated plant's clock, once known
        bus = Robot(config, options=per_bus)     # every bus of the configuration, one tick
        try:
            bus.open()        # a port that does not open ends here: nothing ran, so no log and no summary
        except BaseException:
            if server is not None:
                server.stop()
            raise
        if self.paced:
            say(self.paced)
        swing, verdict, path, home_duration = self.swing, self.verdict, self.path, o.home_duration
        try:
            start_pose = bus.read_state().q
            if o.hold is not None:
                swing, verdict, path = hold_motion(config, start_pose, o.hold, self.period)
                home_duration = 2 * self.period
            # a person at a real arm is asked (the simulator's pseudo-terminals are no real port)
            real = not self.simulated and any(not is_pseudo_terminal(p) for p in self.ports.values())
            if real or o.dry_run:
                self._homing_distances(start_pose, swing.q[0], ask=real)
                if real:
                    start_pose = None      # a person took their time: where the arm is now, read again
        except BaseException:
            bus.stop()
            if server is not None:
                server.stop()
            raise
        friction = config.friction if o.feedforward else {}      # compensated with the feed-forward
        # a dry run logs the planned torques, the feed-forward's: a PD on an arm that torque off leaves
        # where it is would integrate an error it cannot close
        mode = "feedforward" if o.dry_run and o.feedforward else o.mode
        controller = Controller(config.model, ControlConfig(mode=mode, small_time_step=self.period, **friction),
                                q_start=swing.q[0])
        log = RunLog(config.model.dof_names) if self.log is None else self.log
        log.stream(out / "swing_log.csv")
        error, planned_ticks, swing_start, home_ticks = None, len(swing.t), 0.0, 0
        stopping = {"now": False}
        restore_signals = _signals_stop_the_run(stopping)
        realtime, tolerance, observer = self.realtime, o.overrun_tolerance, self.observer
        guards, segment, reaction = None, None, None
        try:
            home, played = plan_run(config.model, swing, bus.read_state().q if start_pose is None else start_pose,
                                    home_duration, joint_sensors(config))
            if o.dry_run:
                say(f"dry run: torque off; the homing's {home.traj.t[-1]:g} s read and logged with its planned "
                    "torques (none is sent)")
                follow(DryRun(bus), controller, home, log, realtime, observer=observer, tolerance=tolerance)
                planned_ticks = len(home.traj.t)
                raise _DryRunDone
            guards = Guards(config, self.period, self.contact_observer())
            bus.enable_torque(True)     # arms the Bus Watchdog: from here the bus must not go quiet
            say(f"homing to the swing's start pose over {home.traj.t[-1]:g} s ...")
            home_ticks = len(home.traj.t)
            # homing's deadlines are the run's too (the native loop's count has them); its ticks are
            # on the motion's clock before 0
            segment = home
            log.missed += follow(bus, controller, home, realtime=realtime, observer=observer, tolerance=tolerance,
                                 guard=guards.at_offset(-home_ticks * self.period))
            say(f"{path.name}: {swing.t[-1]:.1f} s (time scale {self.scale:g}, validated against the "
                f"servos' limits), {o.mode.replace('_', ' + ')}, inverse dynamics every "
                f"{TIME_STEP * 1e3:g} ms, {1 / self.period:g} Hz target")
            # the plant's time when the swing begins: in lock-step one period per homing tick (asking
            # the simulator would race it: it may not have taken the last homing write yet, a sync
            # write gets no reply); in real time, the plant clock now
            swing_start = (server.status()["time"] if realtime else len(home.traj.t) * self.period) \
                if server is not None else 0.0
            segment = played
            self.plant_swing_start = swing_start     # in real time, moved on to the first tick (_fault_injector)
            follow(bus, controller, played, log, realtime, on_tick=self._fault_injector(server, played),
                   observer=observer, tolerance=tolerance, guard=guards.at_offset(0.0),
                   progress=lambda t, f, err: say(f"  t = {t:5.2f} s  {100 * f:5.1f} %  "
                                                  f"largest error {np.degrees(err):6.3f} deg"))
        except _DryRunDone:
            stopping["now"] = True
        except SafetyStop as stop:
            error = stop
            reaction = self._react(stop, guards, segment, bus, log)
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
            # the contact the simulator applied, row by row, its times on the plant's clock (sim/contact.py)
            self.contact_log = {"swing_start": self.plant_swing_start, **server.contact_log()} \
                if sim and sim.get("contact") else None
            if server is not None:
                server.stop()
            log.close()
        summary = summarize(log, planned_ticks, self.period, realtime, error)
        summary.update(error_class=type(error).__name__ if error else None, exit_code=exit_code(error),
                       stop_reason=stop_reason(error, summary["completed"]))
        if isinstance(error, SafetyStop):
            summary[error.stop_reason] = self._stop_detail(error, guards, sim, self.plant_swing_start)
            summary["reaction"] = {"kind": reaction.kind, "gave_way": reaction.gave_way} if reaction else None
        summary.update(motion=path.name, mode=o.mode, time_scale=self.scale, validated=verdict.passed,
                       loop="python", bus=bus.stats.as_dict(bus.dof_names), home_ticks=home_ticks, cpu=self.cpu,
                       dry_run=o.dry_run, hold_s=o.hold)
        if isinstance(error, Interrupted):
            summary["signal"] = signal.Signals(error.signum).name
        if sim is not None:
            # what the simulated servos saw: plant time at the stop and every torque switched off
            summary["sim_time_at_stop_s"] = sim["time"] - swing_start     # on the swing's clock
            summary["torque_off"] = sim["torque_off"]
            if sim.get("contact"):       # what the simulator applied, its times on the swing's clock
                summary["sim_contact"] = {**sim["contact"], "onset_t_s": None if sim["contact"]["onset_time"] is None
                                          else sim["contact"]["onset_time"] - self.plant_swing_start}
        self.log = log
        try:
            write_summary(out, summary)
        finally:
            restore_signals()          # until the summary is written a signal is ignored, not fatal
        return summary

    def contact_observer(self):
        """The run's contact observer (servodyn.loop.contact), or None when `[safety] contact` is off."""
        return contact_observer(self.config) if self.config.guards.contact else None

    def _react(self, stop: SafetyStop, guards: Guards, segment, bus, log):
        """The configured reaction to a guard's stop (servodyn.loop.reaction), said, then played;
        a servo's fault during it ends it (the stop's torque off follows either way)."""
        t_seg, q_now = guards.last
        k = int(round((t_seg - segment.traj.t[0]) / self.period))
        kind = self.config.guards.reaction
        self.say(f"stopped: {stop} — {kind.replace('_', ' ')}: {REACTIONS[kind]}"
                 + (f", for {self.config.guards.reaction_time:g} s, then torque off" if kind != "torque_off" else ""))
        t_stop = stop.detail.get("t_s", stop.detail.get("detected_t_s"))
        reaction = plan_reaction(self.config, stop, segment, k, q_now, t_stop + self.period, self.options.feedforward)
        try:
            reaction.play(bus, log, self.realtime, self.config, observer=self.observer,
                          contact=guards.observer)
        except (ServoError, FloatingPointError, ControlFault, Overrun, Interrupted) as err:
            reaction.gave_way = f"{type(err).__name__}: {err}"
        if reaction.gave_way:
            self.say(f"the {kind.replace('_', ' ')} gave way ({reaction.gave_way}) — torque off on every servo")
        return reaction

    @staticmethod
    def _stop_detail(stop: SafetyStop, guards: Guards, sim: dict | None, swing_start: float) -> dict:
        """summary.json's entry for a guard's stop; a contact's with the observer's last word on the
        link and the force (refined while the reaction ran) and, where the simulator applied one,
        when it began (on the motion's clock)."""
        if not isinstance(stop, ContactStop):
            return stop.detail
        found = guards.observer.detection
        applied = (sim or {}).get("contact") or {}
        onset = applied.get("onset_time")
        return {**({} if onset is None else {"applied_t_s": onset - swing_start}), "detected_t_s": found.t_s,
                "link": found.link, "force_estimate_n": found.force_estimate_n, "force_n": list(found.force_n),
                "joint": found.joint, "settled": found.settled}

    def _homing_distances(self, q_now, q_start, ask: bool) -> None:
        """Say how far each joint will move to the start pose; ask `confirm` at a real arm."""
        names = self.config.model.dof_names
        delta = np.degrees(np.asarray(q_start) - np.asarray(q_now))
        largest = int(np.argmax(np.abs(delta)))
        self.say(f"homing moves each joint from where it is to the start pose (largest: "
                 f"{names[largest]}, {abs(delta[largest]):.1f}°):")
        for name, a, b, d in zip(names, q_now, q_start, delta):
            self.say(f"  {name:<24} {np.degrees(a):8.1f}° -> {np.degrees(b):8.1f}°  ({d:+7.1f}°)")
        if ask and self.confirm is not None and not self.options.dry_run \
                and not self.confirm("torque on and move the arm?"):
            raise Declined("nothing moved: the move was not confirmed (--yes skips the question)")

    def _fault_injector(self, server, played):
        """on_tick for follow(), made just before the swing: --contact's pushes scheduled from the
        swing's start on the simulated plant's clock (in real time swing_start plus the wall-clock time
        since it was read); fault_at's fault before its tick, on the simulated bus or, for a motion
        fault, in the played motion."""
        fault_at, o = self.options.fault_at, self.options
        if (fault_at is None and not (o.contacts or o.obstacles)) or server is None:
            return None
        fault_tick = int(round(fault_at[0] / self.period)) if fault_at is not None else None
        fault = fault_at[2] if fault_at is not None and len(fault_at) > 2 else "silent"
        made = time.perf_counter()        # just after swing_start was read

        def inject(k):
            if k == 0 and o.contacts:
                # before the first tick, whose schedule starts when this returns (follow): in real
                # time the plant has moved on since swing_start was read, by the wall clock
                if self.realtime:
                    self.plant_swing_start += time.perf_counter() - made
                for push in o.contacts:      # a push's start counts from the swing's
                    server.schedule_push(push, self.plant_swing_start)
            if k != fault_tick:
                return
            if fault == "nan_motion":
                dof = next(j.dof for j in self.config.joints if j.id == fault_at[1])
                played.traj.q[k:, self.config.model.dof_names.index(dof)] = np.nan
            else:
                server.inject_fault(fault_at[1], fault)
        return inject


def hold_motion(config, q, seconds: float, period: float):
    """Hold pose q for `seconds`: the trajectory, its validator's verdict (gravity at that pose),
    and its path."""
    traj = Trajectory.still(q, max(2, int(round(seconds / period)) + 1), period)
    path = MotionPath.of_trajectory("hold", traj)
    verdict = judge(config, path, 1.0)
    if not verdict.passed:
        raise MotionRefused(f"holding the present pose would leave a servo's limits: "
                            f"{verdict.violations[0]['message']}", [v["message"] for v in verdict.violations])
    return path.at_scale(1.0, period), verdict, path


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
