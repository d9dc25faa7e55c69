"""`servodyn swing`: the tennis forehand on servos — real ones on a serial port, or (the default)
the simulated Dynamixel bus, which speaks the same protocol to the same driver.

Each tick reads the joints (one sync read), runs the C core's controller step (inverse dynamics
every time_step, a joint PD every tick) and writes the joint torques as motor currents (one sync
write). A servo error stops the run safely: torque off on every servo, the log written up to
the failing tick.
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .control import ControlConfig, Controller
from .hal.bus import JointCommand, ServoError, make_bus
from .hal.config import load_config
from .motion import load_motion
from .trajectory import Trajectory

SMALL_TIME_STEP = 1e-3
TIME_STEP = 1e-2
HOME_DURATION = 2.0     # s to move from wherever the arm is to the swing's start pose
SIM_REPLY_TIMEOUT = 0.25   # s to wait for a read reply from the embedded simulated bus


@dataclass
class SwingLog:
    """Per tick: time, desired and measured state, commanded torque, measured current."""
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

    def add(self, t, q_d, state, tau, seconds, start=None, cpu=None, process_cpu=None) -> None:
        self.t.append(t)
        self.q_d.append(np.array(q_d))
        self.q.append(state.q)
        self.qd.append(state.qd)
        self.tau.append(np.array(tau))
        self.current.append(state.current)
        self.tick_seconds.append(seconds)
        self.tick_start.append(start)
        self.cpu_seconds.append(cpu)
        self.process_cpu_seconds.append(process_cpu)

    def write_csv(self, path: Path) -> None:
        names = self.dof_names
        header = ["t"] + [f"{p}_{d}" for p in ("q_d", "q", "qd", "tau", "current") for d in names]
        with open(path, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(header)
            for k in range(len(self.t)):
                row = [self.t[k], *self.q_d[k], *self.q[k], *self.qd[k], *self.tau[k], *self.current[k]]
                writer.writerow([f"{v:.9g}" for v in row])


def homing(q_from, q_to, duration: float, dt: float) -> Trajectory:
    """A minimum-jerk move between two poses, at rest at both ends."""
    n = max(2, int(round(duration / dt)) + 1)
    t = np.arange(n) * dt
    s = t / t[-1]
    blend = 10 * s**3 - 15 * s**4 + 6 * s**5
    rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / t[-1]
    accel = (60 * s - 180 * s**2 + 120 * s**3) / t[-1] ** 2
    delta = np.asarray(q_to) - np.asarray(q_from)
    return Trajectory(t=t, q=q_from + np.outer(blend, delta), qd=np.outer(rate, delta),
                      qdd=np.outer(accel, delta), derived=True)


BANDWIDTH = 20.0        # rad/s of each joint's PD on its own inertia, at least
MAX_BANDWIDTH = 100.0   # rad/s: at 1 kHz the discrete loop keeps its damping up to about here
MIN_STIFFNESS = 2.0     # N m/rad: a servo's friction (~0.02 N m) then leaves ~0.01 rad of error


def scheduled_gains(model, q) -> tuple[np.ndarray, np.ndarray]:
    """PD gains for pose q: each joint gets the bandwidth that gives it MIN_STIFFNESS on its own
    effective inertia, kept between BANDWIDTH and MAX_BANDWIDTH. That inertia varies with the pose
    (shoulder rotation's by 100x between a straight and a bent elbow), so fixed gains are either
    unstable bent or too weak straight: the loop re-schedules them every time_step from the
    desired pose. Light distal joints get the higher bandwidth that stiffness against friction needs."""
    # the inertia a joint sees with the others free, 1 / (M^-1)_ii <= M_ii: gains on M_ii would
    # overdrive a light joint whose neighbours move with it
    inertia = 1.0 / np.diag(np.linalg.inv(model.mass_matrix(q)))
    bandwidth = np.clip(np.sqrt(MIN_STIFFNESS / inertia), BANDWIDTH, MAX_BANDWIDTH)
    return inertia * bandwidth**2, 2 * inertia * bandwidth


GAIN_PERIOD = 0.1       # s between two knots of the gain schedule (on the played, scaled clock)


@dataclass(frozen=True)
class GainSchedule:
    """PD gains along a planned motion: scheduled_gains() at knots every GAIN_PERIOD of the
    plan, linear in between, held before the first and after the last knot. The host loop and
    the firmware (whose tables `servodyn codegen` writes from this) use the same schedule, since
    the firmware cannot afford the mass matrix inverse at run time."""
    t: np.ndarray           # (K,) knot times (s)
    kp: np.ndarray          # (K, n) N m/rad
    kd: np.ndarray          # (K, n) N m s/rad

    @classmethod
    def along(cls, model, traj: Trajectory, period: float = GAIN_PERIOD) -> "GainSchedule":
        duration = traj.t[-1] - traj.t[0]
        t = np.linspace(0.0, duration, max(2, int(np.ceil(duration / period - 1e-9)) + 1))
        rows = np.clip(np.rint(t / (traj.t[1] - traj.t[0])).astype(int), 0, len(traj.t) - 1)
        gains = [scheduled_gains(model, traj.q[k]) for k in rows]
        return cls(t=traj.t[rows] - traj.t[0], kp=np.array([g[0] for g in gains]),
                   kd=np.array([g[1] for g in gains]))

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        k = int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2))
        s = float(np.clip((t - self.t[k]) / (self.t[k + 1] - self.t[k]), 0.0, 1.0))
        return (self.kp[k] + s * (self.kp[k + 1] - self.kp[k]),
                self.kd[k] + s * (self.kd[k + 1] - self.kd[k]))


def plan_gains(model, swing: Trajectory) -> tuple[GainSchedule, GainSchedule]:
    """The gain schedules of homing and of the swing. Homing's is planned along the move from the
    model's rest pose (where an arm powers up): the measured start of a run is not known in
    advance, and the firmware cannot compute gains on line."""
    rest_move = homing(model.neutral_q(), swing.q[0], HOME_DURATION, swing.t[1] - swing.t[0])
    return GainSchedule.along(model, rest_move), GainSchedule.along(model, swing)


def run_swing(config_name: str = "replica", port: str | None = None, out: Path = Path("out/swing"),
              feedforward: bool = True, time_scale: float | None = None, realtime: bool = False,
              say=print, fault_at: tuple | None = None) -> dict:
    """Home, swing, log; returns the summary. fault_at = (time, servo id) or (time, servo id,
    fault): on the simulated bus, that servo stops answering then (fault "silent", the default),
    or raises Hardware Error Status bits (fault "overload", "overheating", ... or the bits as an
    int), to show the safe stop."""
    config = load_config(config_name)
    model = config.model
    scale = time_scale or config.swing_time_scale or 1.0
    swing = load_motion("tennis_forehand", model).sample(SMALL_TIME_STEP, time_scale=scale)
    mode = "feedforward_pd" if feedforward else "pd"
    server = arm = None
    if port is None:
        from servodyn.sim.arm import PtyServer, SimulatedArm
        arm = SimulatedArm(config, small_time_step=SMALL_TIME_STEP)
        server = PtyServer(arm, "realtime" if realtime else "lockstep")
        server.start()
        port = server.path
        say(f"simulated bus: {len(arm.servos)} virtual servos of '{config.name}' on {port} "
            f"({'real time' if realtime else 'lock-step'}), the plant integrated by RK4 at "
            f"{SMALL_TIME_STEP * 1e3:g} ms")
    # a pseudo-terminal under CPU load can hold bytes back for over 100 ms (measured here), far
    # beyond a real bus's 34 ms packet timeout: the simulated bus gets a patient reply timeout
    bus = make_bus(config, port=port, **({"reply_timeout": SIM_REPLY_TIMEOUT} if arm is not None else {}))
    controller = Controller(model, ControlConfig(mode=mode, small_time_step=SMALL_TIME_STEP,
                                                 time_step=TIME_STEP, bandwidth=BANDWIDTH),
                            q_start=swing.q[0])
    log = SwingLog(model.dof_names)
    out.mkdir(parents=True, exist_ok=True)
    error = None
    swing_start = 0.0
    try:
        bus.open()
        bus.enable_torque(True)
        start = bus.read_state()
        home = homing(start.q, swing.q[0], HOME_DURATION, SMALL_TIME_STEP)
        say(f"homing to the swing's start pose over {HOME_DURATION:g} s ...")
        home_gains, schedule = plan_gains(model, swing)
        _follow(bus, controller, home, home_gains, None, realtime, say=None)
        say(f"swing: tennis forehand, {swing.t[-1]:.1f} s (time scale {scale:g}: the servos' "
            f"speed limits), {mode.replace('_', ' + ')}, inverse dynamics every "
            f"{TIME_STEP * 1e3:g} ms, {1 / SMALL_TIME_STEP:g} Hz target")
        swing_start = arm.time if arm is not None else 0.0
        if fault_at is not None and arm is not None:
            fault_tick = int(round(fault_at[0] / SMALL_TIME_STEP))
        else:
            fault_tick = None
        inject = _fault_injector(server, fault_at) if fault_tick is not None else None
        _follow(bus, controller, swing, schedule, log, realtime, say=say,
                on_tick=(lambda k: inject() if k == fault_tick else None))
    except ServoError as err:
        error = err
        say(f"servo error: {err} — torque off on every servo")
    finally:
        _safe_stop(bus)
        if server is not None:
            server.stop()
    summary = _report(log, out, swing, scale, mode, error, say, realtime)
    summary["failed_reads"] = getattr(bus, "failed_reads", 0)     # reads retried (whole run)
    if arm is not None:
        # what the simulated servos saw: plant time at the stop and every torque switched off
        summary["sim_time_at_stop_s"] = arm.time - swing_start     # on the swing's clock
        summary["torque_off"] = [not servo.torque_enabled for servo in arm.servos]
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _fault_injector(server, fault_at):
    """What fault_at does to the simulated bus, between two transactions (under the server's lock,
    so the plant's step in flight sees the servo either before or after)."""
    servo_id = fault_at[1]
    fault = fault_at[2] if len(fault_at) > 2 else "silent"
    arm = server.arm
    if fault != "silent":
        from servodyn.sim.dynamixel import HardwareError
        bits = fault if isinstance(fault, int) else HardwareError[str(fault).upper().replace(" ", "_")]
        servo = next(s for s in arm.servos if s.id == servo_id)

    def inject():
        with server._lock:
            if fault == "silent":
                arm.silent.add(servo_id)
            else:
                servo.set_hardware_error(int(bits))
    return inject


def _follow(bus, controller, traj: Trajectory, gains: GainSchedule, log: SwingLog | None,
            realtime: bool, say=None,
            on_tick=None) -> None:
    controller.reset()
    update_ticks = controller.config.update_ticks
    n = len(traj.t)
    period = traj.t[1] - traj.t[0]
    start = time.perf_counter()
    next_report = 0.0
    for k in range(n):
        if on_tick is not None:
            on_tick(k)
        began = time.perf_counter()
        cpu, process_cpu = time.thread_time(), time.process_time()
        if k % update_ticks == 0:
            controller.set_gains(*gains.at(traj.t[k] - traj.t[0]))
        state = bus.read_state()
        tau = controller.step(traj.q[k], traj.qd[k], traj.qdd[k], state.q, state.qd)
        bus.write(JointCommand.torque(tau))
        cpu, process_cpu = time.thread_time() - cpu, time.process_time() - process_cpu
        if log is not None:
            log.add(traj.t[k], traj.q[k], state, tau, time.perf_counter() - began, began, cpu, process_cpu)
        if say is not None and traj.t[k] >= next_report:
            err = np.degrees(np.abs(traj.q[k] - state.q).max())
            say(f"  t = {traj.t[k]:5.2f} s  {100 * k / (n - 1):5.1f} %  largest error {err:6.3f} deg")
            next_report += 1.0
        if realtime:
            delay = start + (k + 1) * period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)


def _safe_stop(bus) -> None:
    """Torque off, whatever state the bus is in; never raises."""
    try:
        if bus.is_open:
            off = getattr(bus, "disable_torque_now", None)
            if off is not None:
                off()
            else:
                bus.enable_torque(False)
    except Exception:
        pass
    try:
        bus.close()
    except Exception:
        pass


def _report(log: SwingLog, out: Path, swing: Trajectory, scale: float, mode: str, error, say,
            realtime: bool = False) -> dict:
    """The summary. The loop rate and the period jitter come from when the ticks began: in real
    time the jitter is each period's distance from the nominal one, in lock-step (which runs as
    fast as it can) from the median period. CPU per tick is the loop thread's CPU time
    (time.thread_time) from the gains update to the end of the write — the HAL read, the control
    step and the HAL write; the process's (time.process_time) also counts the simulated bus when
    it runs in this process."""
    names = log.dof_names
    log.write_csv(out / "swing_log.csv")
    if not log.t:
        summary = {"completed": False, "error": str(error) if error else "no tick ran"}
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return summary
    q_d, q = np.array(log.q_d), np.array(log.q)
    e = q_d - q
    seconds = np.array(log.tick_seconds)
    starts = np.array(log.tick_start, dtype=float)
    if len(starts) > 1 and np.all(np.isfinite(starts)):
        periods = np.diff(starts)
        loop_hz = (len(starts) - 1) / float(starts[-1] - starts[0])
    else:
        periods, loop_hz = seconds, len(seconds) / float(np.sum(seconds))
    nominal = swing.t[1] - swing.t[0]
    jitter = np.abs(periods - (nominal if realtime else np.median(periods)))
    cpu = np.array(log.cpu_seconds, dtype=float)
    process_cpu = np.array(log.process_cpu_seconds, dtype=float)
    summary = {
        "completed": error is None and len(log.t) == len(swing.t),
        "ticks": len(log.t),
        "mode": mode,
        "time_scale": scale,
        "tracking_rms_rad": float(np.sqrt(np.mean(e**2))),
        "tracking_max_rad": float(np.abs(e).max()),
        "tracking_max_by_dof_rad": dict(zip(names, map(float, np.abs(e).max(axis=0)))),
        "loop_hz": loop_hz,
        "jitter_p99_ms": float(np.percentile(jitter, 99) * 1e3),
        "clock": "realtime" if realtime else "lockstep",
        "period_median_ms": float(np.median(periods) * 1e3),
        "tick_median_ms": float(np.median(seconds) * 1e3),
        "cpu_ms_per_tick": {"median": float(np.median(cpu) * 1e3), "p99": float(np.percentile(cpu, 99) * 1e3)},
        "process_cpu_ms_per_tick": {"median": float(np.median(process_cpu) * 1e3),
                                    "p99": float(np.percentile(process_cpu, 99) * 1e3)},
        "peak_torque_nm": dict(zip(names, map(float, np.abs(np.array(log.tau)).max(axis=0)))),
        "error": str(error) if error else None,
        "last_tick_time_s": float(log.t[-1]),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    say(f"\n  {'dof':<24} {'rms (deg)':>10} {'max (deg)':>10}")
    for k, name in enumerate(names):
        say(f"  {name:<24} {np.degrees(np.sqrt(np.mean(e[:, k]**2))):>10.3f} {np.degrees(np.abs(e[:, k]).max()):>10.3f}")
    say(f"\n  loop {loop_hz:.0f} Hz, {summary['clock']} (period median {summary['period_median_ms']:.3f} ms, "
        f"p99 jitter {summary['jitter_p99_ms']:.3f} ms; CPU per tick median "
        f"{summary['cpu_ms_per_tick']['median']:.3f} ms, p99 {summary['cpu_ms_per_tick']['p99']:.3f} ms); tracking rms {np.degrees(summary['tracking_rms_rad']):.3f} deg, "
        f"max {np.degrees(summary['tracking_max_rad']):.3f} deg")
    _plot(out / "swing_tracking.png", np.array(log.t), q_d, q, np.array(log.tau), names)
    say(f"wrote {out / 'swing_log.csv'}, {out / 'summary.json'}, {out / 'swing_tracking.png'}")
    return summary


def _plot(path: Path, t, q_d, q, tau, names) -> None:
    from .plots import _pyplot
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    for k, name in enumerate(names):
        line, = axes[0].plot(t, np.degrees(q[:, k]), label=name)
        axes[0].plot(t, np.degrees(q_d[:, k]), ":", color=line.get_color())
        axes[1].plot(t, np.degrees(q_d[:, k] - q[:, k]), label=name)
        axes[2].plot(t, tau[:, k], label=name)
    axes[0].set_ylabel("angle (deg), dotted: desired")
    axes[1].set_ylabel("tracking error (deg)")
    axes[2].set_ylabel("commanded torque (N m)")
    axes[2].set_xlabel("time (s)")
    axes[0].legend(fontsize=7, ncol=2)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].set_title("tennis forehand on the servo bus")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
