"""`servodyn view`: the arm in 3-D in a browser (viser: a Python-served three.js page).

The arm is drawn from its own solids — the paper's primitives and, on the replicas, the servos'
housings (model.shapes) — each body posed by the model's forward kinematics (`user_poses`, the
model file's frames). What the page shows:

  play     a motion (keyframes, a trajectory CSV) or a logged run (swing_log.csv): the planned arm
           as a ghost, the measured arm solid; angle, tracking error and torque plots that follow
           the time cursor; at each joint a ball coloured by its torque's share of the servo's
           limit (the validator's torque-speed envelope; without a configuration, of the
           motion's own peak)
  shape    a keyframe motion's keyframes edited with the page's controls (the angle of each dof,
           the keyframe's time): the arm, the torque profile (the motion's inverse dynamics in one
           batched call into the C core) and the validator's verdict follow at once; saved as a
           keyframe file
  live     `servodyn swing --view`: the loop hands each tick's state to `LiveFeed.observe`, which
           only keeps the latest; a thread of the viewer's own draws it at PUBLISH_HZ
"""

from __future__ import annotations

import collections
import errno
import math
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..control.motion import Motion, builtin_motions, check_limits, load_motion, motion_path, save_motion
from ..control.timing import SMALL_TIME_STEP
from ..control.trajectory import TrajectoryError
from ..hal.config import builtin_configs, load_config
from ..hal.errors import ConfigError
from ..loop.log import RunLogError, read_run_log
from ..mocap import BvhError, RetargetError, SkeletonError, find_arms, guess_axes, read_bvh
from ..mocap.retarget import source_arm
from ..model import ModelError, builtin_models, ik, load_model
from ..model.files import read_toml
from ..model.rotations import matrix_to_quat, quat_to_matrix
from ..model.shapes import solid_mesh
from ..validation import Limits, check, describe, torque_speed_ratio, violations

DEFAULT_MOTION = "tennis_forehand"
PUBLISH_HZ = 30.0          # live view: frames a second drawn at most (a tick's state, decimated)
PLAY_HZ = 30.0             # playback: frames a second
PLOT_POINTS = 600          # samples per plotted series (decimated from the 1 ms samples)
PLOTS = ("angle (°)", "tracking error (°)", "torque (N·m)")
PLOT_WINDOW = 2.0          # s of the plots around the cursor
SOLID_RGB = (178, 184, 196)
GHOST_RGB = (90, 160, 255)
GHOST_OPACITY = 0.35
GIZMO_SCALE = 0.3          # of the arm's length: the hand's transform gizmo
SOURCE_RGB = (255, 140, 40)  # the captured arm of --source


class ViewError(ValueError):
    """Bad input to the view: one line."""


# ---------------------------------------------------------------------------- what is shown

@dataclass
class Timeline:
    """Samples on one clock: the planned arm, the measured one (a logged run), the joint torques
    and each torque's share of its servo's limit."""
    t: np.ndarray                    # (N,) s
    planned: np.ndarray              # (N, nq) rad
    tau: np.ndarray                  # (N, nv) N m
    share: np.ndarray                # (N, nv) of the servo's limit (or of the motion's peak)
    measured: np.ndarray | None = None
    share_of: str = "the servo's torque-speed limit"

    def index(self, t: float) -> int:
        return int(np.clip(np.searchsorted(self.t, t), 0, len(self.t) - 1))


def load_subject(spec: str | None):
    """(config or None, model) from a configuration or a model, by name or file."""
    spec = spec or "replica"
    is_model = spec not in builtin_configs() and spec in builtin_models() or str(spec).lower().endswith(".urdf")
    if not is_model and str(spec).lower().endswith(".toml") and spec not in builtin_configs():
        try:
            is_model = "body" in read_toml(Path(spec), ModelError)
        except FileNotFoundError:
            raise ViewError(f"{spec}: no such file") from None
    if not is_model and spec not in builtin_configs() and not Path(spec).exists():
        raise ViewError(f"{spec}: no such file, and not a built-in configuration ({', '.join(builtin_configs())}) "
                        f"or model ({', '.join(builtin_models())})")
    try:
        if is_model:
            return None, load_model(spec)
        config = load_config(spec)
        return config, config.model
    except (ModelError, ConfigError) as err:
        raise ViewError(str(err)) from None


def limits_of(config):
    if config is None:
        return None
    return Limits.of(config, config.supply.voltage)


def _own_peak_share(tau: np.ndarray) -> np.ndarray:
    peak = np.abs(tau).max(axis=0)
    return np.abs(tau) / np.where(peak > 0, peak, 1.0)


def motion_timeline(model, config, motion: Motion, time_scale: float):
    """The motion sampled every control period at the time scale, its torques (one batched RNEA)
    and, with a configuration, the validator's verdict: (timeline, result or None, limits)."""
    period = SMALL_TIME_STEP if config is None else config.control_period
    return trajectory_timeline(model, config, motion.path.at_scale(time_scale, period))


def trajectory_timeline(model, config, traj):
    """(timeline, the validator's result or None, limits or None) of a sampled trajectory."""
    limits = limits_of(config)
    if limits is None:
        tau = model.inverse_dynamics(traj.q, traj.qd, traj.qdd)
        return Timeline(traj.t, traj.q, tau, _own_peak_share(tau), share_of="the motion's peak"), None, None
    result = check(model, limits, traj)
    return Timeline(traj.t, traj.q, result.tau, result.ratios["torque_speed"]), result, limits


def log_timeline(model, config, folder: Path) -> Timeline:
    """A logged run (DIR/swing_log.csv, as servodyn swing writes it)."""
    try:
        log = read_run_log(folder, model, need=("q_d", "q", "qd", "tau"))
    except RunLogError as err:
        raise ViewError(str(err)) from None
    t, tau, qd = log.t, log.tau, log.qd
    limits = limits_of(config)
    if limits is None:
        share, share_of = _own_peak_share(tau), "the run's peak"
    else:
        share, share_of = torque_speed_ratio(limits, tau, qd)[0], "the servo's torque-speed limit"
    return Timeline(t, log.q_d, tau, share, measured=log.q, share_of=share_of)


def share_rgb(share: float) -> tuple[int, int, int]:
    """Green at no load, yellow at half the limit, red at and past it."""
    s = float(np.clip(share, 0.0, 1.0))
    if s < 0.5:
        return (int(60 + 390 * s), 200, 60)
    return (255, int(200 - 340 * (s - 0.5)), 40)


# ---------------------------------------------------------------------------- the 3-D arm

class ArmDrawing:
    """The arm's solids in the scene under `root`, one scene frame per body, posed at q."""

    def __init__(self, server, model, root: str, rgb, opacity: float | None = None, markers: float = 0.0):
        """markers: the radius (m) of a ball at each joint coloured by its torque (0: none)."""
        self.model = model
        self.frames = []
        self.markers = {}
        scene = server.scene
        for body in model.bodies:
            frame = scene.add_frame(f"{root}/{body.name}", show_axes=False)
            self.frames.append(frame)
            for k, solid in enumerate(body.solids):
                vertices, faces = solid_mesh(solid)
                scene.add_mesh_simple(f"{root}/{body.name}/solid{k}", vertices.astype(np.float32), faces,
                                      color=rgb, opacity=opacity, cast_shadow=False, receive_shadow=False)
            if markers and body.dofs and self._joint_of(body) is body:
                self.markers[body.name] = scene.add_icosphere(f"{root}/{body.name}/torque", radius=markers,
                                                              color=share_rgb(0.0), opacity=0.6)
        # which velocity dofs each body's joint drives
        self.dof_slices, k = [], 0
        for body in model.bodies:
            n = 6 if body.free else 3 if body.ball else len(body.dofs)
            self.dof_slices.append(slice(k, k + n))
            k += n

    def _joint_of(self, body):
        """The first body of a chain that turns about one point (a replica's servos in series at
        the shoulder): one joint, one marker."""
        while body.parent >= 0 and np.linalg.norm(body.pos) < 1e-9 and self.model.bodies[body.parent].dofs:
            body = self.model.bodies[body.parent]
        return body

    def pose(self, q, yield_each: bool = False) -> None:
        """Pose every body at q. yield_each: let other threads run between two bodies (the live
        view's thread must not hold the interpreter for long: the control loop waits on it)."""
        R, p = self.model.user_poses(q)
        for frame, Ri, pi in zip(self.frames, R, p):
            x, y, z, w = matrix_to_quat(Ri)
            frame.wxyz = (w, x, y, z)
            frame.position = tuple(pi)
            if yield_each:
                time.sleep(0)

    def color_joints(self, share) -> None:
        """Each joint's ball in the colour of its most loaded dof's share of its limit."""
        worst = {}
        for body, sl in zip(self.model.bodies, self.dof_slices):
            if sl.stop > sl.start:
                name = self._joint_of(body).name
                worst[name] = max(worst.get(name, 0.0), float(np.max(share[sl])))
        for name, marker in self.markers.items():
            marker.color = share_rgb(worst.get(name, 0.0))

    def show(self, visible: bool) -> None:
        for frame in self.frames:
            frame.visible = visible


# ---------------------------------------------------------------------------- the page

class SourceOverlay:
    """The captured arm a retargeted motion came from (`--source CLIP.bvh`): shoulder, elbow, wrist
    and hand as line segments, posed at the player's time (hidden during the lead-in)."""

    def __init__(self, server, t: np.ndarray, points: np.ndarray, time_scale: float):
        self.t, self.points = t * time_scale, points
        self.handle = server.scene.add_line_segments("/source", self._segments(0), SOURCE_RGB, thickness=0.012)

    def _segments(self, k: int) -> np.ndarray:
        p = self.points[k].astype(np.float32)
        return np.stack([p[:-1], p[1:]], axis=1)

    def pose(self, t: float) -> None:
        k = int(np.clip(np.searchsorted(self.t, t), 1, len(self.t) - 1))
        k -= int(t - self.t[k - 1] < self.t[k] - t)          # the nearest frame
        self.handle.visible = bool(t >= self.t[0] - 1e-9)
        self.handle.points = self._segments(k)


def check_address(host: str, port: int) -> None:
    """ViewError unless host:port can be served (viser would fail in its own thread, and hang)."""
    import socket
    if not 0 <= port <= 65535:
        raise ViewError(f"--port must be from 0 to 65535, got {port}")
    try:
        family, kind, _, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        with socket.socket(family, kind) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind(address)
    except (socket.gaierror, UnicodeError) as err:
        raise ViewError(f"--host {host}: not an address this machine can serve on ({err})") from None
    except OSError as err:
        if err.errno != errno.EADDRINUSE:          # a port in use: viser takes the next free one
            raise ViewError(f"cannot serve on {host}:{port}: {err.strerror or err}") from None


TITLE = "servodyn view"     # the page's title (viser's own page is titled "Viser")


class Viewer:
    """One viser server and its page: the arm, the ghost, the plots, the player and the editor."""

    def __init__(self, config, model, host: str = "127.0.0.1", port: int = 8080, say=print):
        import viser
        check_address(host, port)
        self.config, self.model, self.say = config, model, say
        self.server = viser.ViserServer(host=host, port=port, label=TITLE, verbose=False)
        self.server.gui.add_html(f'<img src="data:," hidden onerror="document.title=\'{TITLE}\'">')   # the tab's title
        self.lock = threading.RLock()
        server = self.server
        server.scene.set_up_direction("+z")
        server.gui.configure_theme(control_width="large")
        # lit by lights alone: an environment map's prefiltering takes software WebGL many seconds
        server.scene.configure_environment_map(hdri=None)
        server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        server.scene.add_light_ambient("/ambient", intensity=1.2)
        R, p = model.user_poses(model.neutral_q())
        reach = max(0.2, float(np.linalg.norm(p - p[0], axis=1).max()))     # the arm's length
        # looking at the shoulder from the front right, the arm left of the page's centre (the
        # panel covers the right)
        behind = np.array([1.3, -1.9, 0.7])
        right = np.cross(-behind, [0.0, 0.0, 1.0])
        centre = p[0] - np.array([0.0, 0.0, 0.3 * reach]) + 0.35 * reach * right / np.linalg.norm(right)
        server.initial_camera.position = tuple(centre + behind * reach)
        server.initial_camera.look_at = tuple(centre)
        server.scene.add_grid("/floor", width=4 * reach, height=4 * reach, cell_size=0.1,
                              position=(p[0][0], p[0][1], float(p[:, 2].min()) - 0.4 * reach), plane="xy")
        self.ghost = ArmDrawing(server, model, "/planned", GHOST_RGB, opacity=GHOST_OPACITY)
        self.arm = ArmDrawing(server, model, "/arm", SOLID_RGB, markers=0.07 * reach)
        self.arm.pose(model.neutral_q())
        self.ghost.pose(model.neutral_q())
        self.ghost.show(False)
        what = f"configuration '{config.name}', " if config is not None else ""
        self.status = server.gui.add_markdown(
            f"**servodyn** — {what}model '{model.name}' loaded: {model.nbody} bodies, {model.nv} dofs, "
            f"{model.total_mass:.2f} kg", order=0)
        self.readout = server.gui.add_markdown("", order=1)
        self.timeline: Timeline | None = None
        self.plots = {}
        self.player = None
        self.editor = None
        self.source: SourceOverlay | None = None
        self.cursor_t = 0.0
        self._stop = threading.Event()
        self._threads = []

    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"

    # ------------------------------------------------------------------ play and compare
    def show_timeline(self, timeline: Timeline, title: str) -> None:
        """Load a timeline into the player and the plots, and show its first sample."""
        with self.lock:
            self.timeline = timeline
            self.ghost.show(timeline.measured is not None)
            self._plot(timeline)
            if self.player is None:
                self._add_player()
            self.player["time"].max = float(timeline.t[-1])
            self.player["title"].content = f"**{title}** — {timeline.t[-1]:.2f} s, {len(timeline.t)} samples"
            self.seek(min(self.cursor_t, float(timeline.t[-1])))

    def _add_player(self) -> None:
        gui = self.server.gui
        with gui.add_folder("Play", order=2):
            title = gui.add_markdown("")
            play = gui.add_checkbox("Playing", False)
            speed = gui.add_slider("Speed", min=0.05, max=2.0, step=0.05, initial_value=1.0)
            slider = gui.add_slider("Time (s)", min=0.0, max=1.0, step=SMALL_TIME_STEP, initial_value=0.0)
        slider.on_update(lambda _: self._seek_from_slider())
        self.player = {"title": title, "playing": play, "speed": speed, "time": slider}
        thread = threading.Thread(target=self._play_loop, name="servodyn-view-play", daemon=True)
        thread.start()
        self._threads.append(thread)

    def _seek_from_slider(self) -> None:
        if not getattr(self, "_seeking", False):
            self.seek(float(self.player["time"].value))

    def _play_loop(self) -> None:
        last = time.perf_counter()
        while not self._stop.wait(1.0 / PLAY_HZ):
            now = time.perf_counter()
            dt, last = now - last, now
            with self.lock:
                if self.timeline is None or not self.player["playing"].value:
                    continue
                end = float(self.timeline.t[-1])
                t = self.cursor_t + dt * float(self.player["speed"].value)
                self.seek(t if t <= end else 0.0)

    def seek(self, t: float) -> None:
        """Pose the arm and the ghost at time t and move the plots and readouts there."""
        with self.lock:
            tl = self.timeline
            if tl is None:
                return
            k = tl.index(t)
            self.cursor_t = float(tl.t[k])
            with self.server.atomic():
                if tl.measured is not None:
                    self.arm.pose(tl.measured[k])
                    self.ghost.pose(tl.planned[k])
                else:
                    self.arm.pose(tl.planned[k])
                self.arm.color_joints(tl.share[k])
                if self.source is not None:
                    self.source.pose(self.cursor_t)
                self._follow_plots(self.cursor_t)
            self._seeking = True
            try:
                self.player["time"].value = self.cursor_t
            finally:
                self._seeking = False
            self.readout.content = self._readout(k)

    def _readout(self, k: int) -> str:
        tl = self.timeline
        lines = [f"t = {tl.t[k]:.3f} s; torque's share of {tl.share_of}", "",
                 "| dof | angle ° | error ° | τ N·m | share |", "|---|---:|---:|---:|---:|"]
        q = tl.measured[k] if tl.measured is not None else tl.planned[k]
        for j, name in enumerate(self.model.dof_names):
            err = f"{math.degrees(tl.planned[k, j] - q[j]):.2f}" if tl.measured is not None else "—"
            lines.append(f"| {name} | {math.degrees(q[j]):.1f} | {err} | {tl.tau[k, j]:.2f} | "
                         f"{100 * tl.share[k, j]:.0f} % |")
        return "\n".join(lines)

    def _plot(self, tl: Timeline) -> None:
        import viser.uplot as uplot
        step = max(1, len(tl.t) // PLOT_POINTS)
        t = tl.t[::step]
        series = {PLOTS[0]: np.degrees(tl.measured if tl.measured is not None else tl.planned)[::step],
                  PLOTS[2]: tl.tau[::step]}
        if tl.measured is not None:
            series[PLOTS[1]] = np.degrees(tl.planned - tl.measured)[::step]
        palette = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                   "#7f7f7f", "#bcbd22", "#17becf"]
        names = self.model.dof_names
        for title, values in series.items():
            data = (t.astype(np.float64),) + tuple(np.ascontiguousarray(values[:, j], dtype=np.float64)
                                                   for j in range(values.shape[1]))
            specs = (uplot.Series(label="t (s)"),) + tuple(
                uplot.Series(label=name, stroke=palette[j % len(palette)], width=1.5) for j, name in enumerate(names))
            handle = self.plots.get(title)
            if handle is None:
                order = 3 + list(PLOTS).index(title)
                with self.server.gui.add_folder(title.split(" (")[0].capitalize(), order=order):
                    self.plots[title] = self.server.gui.add_uplot(
                        data=data, series=specs, title=title, aspect=1.6,
                        scales={"x": uplot.Scale(time=False, auto=False, range=(0.0, PLOT_WINDOW))},
                        legend=uplot.Legend(show=True, live=False))
            else:
                handle.data = data
        for title in list(self.plots):
            self.plots[title].visible = title in series

    def _follow_plots(self, t: float) -> None:
        import viser.uplot as uplot
        end = float(self.timeline.t[-1])
        width = min(PLOT_WINDOW, end) or 1.0
        lo = float(np.clip(t - 0.75 * width, 0.0, max(0.0, end - width)))
        for handle in self.plots.values():
            handle.scales = {"x": uplot.Scale(time=False, auto=False, range=(lo, lo + width))}
            handle.title = f"{handle.title.split(' @')[0]} @ t = {t:.2f} s"

    # ------------------------------------------------------------------ shape a motion
    def edit(self, motion: Motion, time_scale: float, save_to: Path) -> "MotionEditor":
        self.editor = MotionEditor(self, motion, time_scale, save_to)
        return self.editor

    # ------------------------------------------------------------------ live
    def live(self) -> "LiveFeed":
        feed = LiveFeed(self)
        thread = threading.Thread(target=feed.publish_loop, name="servodyn-view-live", daemon=True)
        thread.start()
        self._threads.append(thread)
        return feed

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self.server.stop()


class MotionEditor:
    """The keyframes of a motion in the page's controls; every edit re-samples the motion,
    recomputes its torques in one batched RNEA and asks the validator again."""

    def __init__(self, viewer: Viewer, motion: Motion, time_scale: float, save_to: Path):
        self.viewer, self.motion, self.time_scale, self.save_to = viewer, motion, time_scale, Path(save_to)
        self.model = viewer.model
        self.result = None
        self.edits = 0
        gui = viewer.server.gui
        names = self.model.dof_names
        with gui.add_folder("Shape the motion", order=10):
            self.verdict = gui.add_markdown("")
            self.key = gui.add_slider("Keyframe", min=1, max=len(motion.t), step=1, initial_value=1)
            self.key_time = gui.add_number("Keyframe time (s)", float(motion.t[0]), step=0.01)
            self.angles = []
            for j, name in enumerate(names):
                lo, hi = self.model.lower[j], self.model.upper[j]
                lo = math.degrees(lo) if math.isfinite(lo) else -180.0
                hi = math.degrees(hi) if math.isfinite(hi) else 180.0
                self.angles.append(gui.add_number(f"{name} (°)", round(math.degrees(motion.q[0, j]), 3),
                                                  min=round(lo, 3), max=round(hi, 3), step=0.1))
            self.save_button = gui.add_button("Save keyframes")
            self.saved = gui.add_markdown(f"saves to `{self.save_to}`")
        self.hand = HandGizmo(self) if HandGizmo.fits(self.model) else None
        self._loading = False
        self.key.on_update(lambda _: self._load_keyframe())
        self.key_time.on_update(lambda _: self._changed())
        for handle in self.angles:
            handle.on_update(lambda _: self._changed())
        self.save_button.on_click(lambda _: self.save())
        self._load_keyframe()
        self.update()

    @property
    def k(self) -> int:
        return int(self.key.value) - 1

    def _load_keyframe(self) -> None:
        with self.viewer.lock:
            self._loading = True
            try:
                self.key_time.value = float(self.motion.t[self.k])
                for j, handle in enumerate(self.angles):
                    handle.value = round(math.degrees(self.motion.q[self.k, j]), 3)
            finally:
                self._loading = False
            self._show_keyframe()

    def _show_keyframe(self) -> None:
        v = self.viewer
        if v.timeline is not None:
            v.seek((self.motion.t[self.k] - self.motion.t[0]) * self.time_scale)
        if getattr(self, "hand", None) is not None:
            self.hand.follow_keyframe()

    def _changed(self) -> None:
        # viser runs these handlers in a thread pool: one edit at a time, whole, under the
        # viewer's lock (the hand's worker and the player take it too)
        with self.viewer.lock:
            if self._loading:
                return
            t = self.motion.t.copy()
            q = self.motion.q.copy()
            t[self.k] = float(self.key_time.value)
            q[self.k] = np.radians([float(h.value) for h in self.angles])
            self.set_keyframe(self.k, t[self.k], q[self.k])

    def show_angles(self) -> None:
        """The number fields to keyframe k's angles (without counting it as an edit)."""
        self._loading = True
        try:
            for j, handle in enumerate(self.angles):
                handle.value = round(math.degrees(self.motion.q[self.k, j]), 3)
        finally:
            self._loading = False

    def refuse(self, reason: str) -> None:
        """A refusal on the page, where the editor's refusals go: the verdict line."""
        self.verdict.content = f"**refused**: {reason}"

    def set_keyframe(self, k: int, t_k: float, q_k) -> bool:
        """Replace keyframe k; False (and the reason on the page) if the motion it makes is refused."""
        t = self.motion.t.copy()
        q = self.motion.q.copy()
        t[k], q[k] = t_k, q_k
        try:
            if np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
                raise TrajectoryError(f"keyframe {k + 1}: its time must lie between its neighbours' "
                                      f"({t[k - 1] if k else -math.inf:g} s and "
                                      f"{t[k + 1] if k + 1 < len(t) else math.inf:g} s)")
            motion = replace(self.motion, t=t, q=q)
        except (TrajectoryError, ValueError) as err:
            self.refuse(str(err))
            return False
        self.motion = motion
        self.edits += 1
        self.update()
        return True

    def update(self) -> None:
        """Sample, RNEA (one batched call), validate; redraw."""
        v = self.viewer
        try:
            timeline, result, limits = motion_timeline(self.model, v.config, self.motion, self.time_scale)
        except (TrajectoryError, ValueError, FloatingPointError) as err:
            self.verdict.content = f"**refused**: {err}"
            return
        self.result = result
        peak = np.abs(timeline.tau).max(axis=0)
        worst = int(np.argmax(peak))
        text = (f"edits: {self.edits}; peak torque {peak[worst]:.3f} N·m "
                f"({self.model.dof_names[worst]}); torques: "
                + ", ".join(f"{p:.3f}" for p in peak) + " N·m")
        if result is None:
            try:
                check_limits(self.motion.sample(SMALL_TIME_STEP, self.time_scale), self.model, self.motion.name)
                verdict = "within the joint limits (no configuration: no servo limits to validate against)"
            except TrajectoryError as err:
                verdict = f"**FAIL**: {err}"
        elif result.passed:
            verdict = "**PASS**: every joint within every servo limit"
        else:
            found = violations(result, self.model.dof_names)
            verdict = f"**FAIL** ({len(found)}): {describe(found[0], v.config, limits, 1, 1.0)}"
        self.verdict.content = f"{verdict}  \n{text}"
        v.show_timeline(timeline, f"{self.motion.name}, time scale {self.time_scale:g}")
        self._show_keyframe()

    def save(self) -> Path:
        self.save_to.parent.mkdir(parents=True, exist_ok=True)
        save_motion(self.motion, self.save_to)
        self.saved.content = f"saved `{self.save_to}` ({len(self.motion.t)} keyframes)"
        return self.save_to


class HandGizmo:
    """The hand of the selected keyframe as a transform gizmo: a drag event is one inverse
    kinematics solve from the keyframe's pose (its branch and elbow swivel carried on), the
    keyframe set to the result (the arm, torques and verdict follow, as for a typed angle), and the
    angle fields shown. Events that arrive while one is being handled are coalesced: the latest
    target is handled next, none is queued behind a slow one. A swivel slider turns the elbow about
    the shoulder-wrist line with the hand held; the reach and each refusal ("out of reach", "no
    swivel inside the limits") are shown on the page. The hand's orientation is followed when
    "Turn the hand too" is ticked; otherwise the wrist keeps its angles."""

    @staticmethod
    def fits(model) -> bool:
        try:
            ik.Arm.of(model)
        except ik.IkError:
            return False
        return model.nq == model.nv

    def __init__(self, editor: MotionEditor):
        self.editor = editor
        self.model = editor.model
        self.arm = ik.Arm.of(self.model)
        self.events = 0              # drag events received
        self.solves = 0              # inverse kinematics solves done (coalesced events are skipped)
        self.refusals = 0
        self.arm_s = []              # s per handled event from its arrival to the arm redrawn (IK, pose)
        self.handler_s = []          # s per handled event in all: IK, arm, keyframe, torques, verdict
        # viser runs a plain callback in a thread pool, where a drag's "start", "update"s and "end"
        # can be handled out of order (an "end" before its "start" left the gizmo deaf to the
        # keyframes); the events are queued in order on viser's loop and handled by one worker
        self._events: collections.deque = collections.deque()
        self._wake = threading.Condition()
        self._placing = False
        self.dragging = False
        server, gui = editor.viewer.server, editor.viewer.server.gui
        _, p = self.model.user_poses(self.model.neutral_q())
        size = GIZMO_SCALE * max(0.2, float(np.linalg.norm(p - p[0], axis=1).max()))
        self.gizmo = server.scene.add_transform_controls("/hand_target", scale=size, depth_test=False,
                                                         line_width=3.0)
        with gui.add_folder("Drag the hand", order=11):
            self.reach = gui.add_markdown("")
            self.turn = gui.add_checkbox("Turn the hand too", False)
            self.swivel = gui.add_slider("Elbow swivel (°)", min=-180.0, max=180.0, step=0.5, initial_value=0.0,
                                         disabled=self.arm.srs is None)
        self.gizmo.on_update(self._receive)
        worker = threading.Thread(target=self._work, name="servodyn-view-hand", daemon=True)
        worker.start()
        editor.viewer._threads.append(worker)
        self.swivel.on_update(lambda _: None if self._placing else self.solve_to(*self._hand(), swivel=True))

    def _hand(self):
        """The gizmo's pose: (position, rotation)."""
        w, x, y, z = self.gizmo.wxyz
        return np.asarray(self.gizmo.position, dtype=float), quat_to_matrix([x, y, z, w])

    def follow_keyframe(self) -> None:
        """Put the gizmo (and the swivel slider) on the selected keyframe's hand."""
        q = self.editor.motion.q[self.editor.k]
        R, p = self.arm.hand(q)
        x, y, z, w = matrix_to_quat(R)
        self._placing = True
        try:
            if not self.dragging:             # never pull the gizmo from under the pointer
                self.gizmo.position = tuple(p)
                self.gizmo.wxyz = (w, x, y, z)
            if self.arm.srs is not None:
                self.swivel.value = round(math.degrees(self.arm.swivel_of(q[self.arm.q_index])), 1)
        finally:
            self._placing = False
        self._show_reach(float(np.linalg.norm(p - self.arm.srs.S if self.arm.srs else p - self.arm.point[0])))

    def _show_reach(self, distance: float, note: str = "") -> None:
        far = self.arm.max_reach()
        self.reach.content = f"reach {distance / far:.2f} ({distance:.3f} m of {far:.3f} m){note}"

    async def _receive(self, event) -> None:
        """On viser's event loop, in the order the page sent them: the event and the gizmo's pose
        at that moment, queued for the worker (nothing awaited, nothing slow here)."""
        self.events += 1
        with self._wake:
            self._events.append((event.phase, self._hand()))
            self._wake.notify()

    def _work(self) -> None:
        """The worker: the queued events in order; of a run of updates only the latest is solved
        (a slow solve never falls behind the pointer)."""
        stop = self.editor.viewer._stop
        while not stop.is_set():
            with self._wake:
                if not self._events:
                    self._wake.wait(timeout=0.25)
                    continue
                phase, pose = self._events.popleft()
                while phase == "update" and self._events and self._events[0][0] == "update":
                    phase, pose = self._events.popleft()
            self._handle(phase, pose)

    def _on_drag(self, event) -> None:
        """One drag event handled at once, with the gizmo's present pose."""
        self.events += 1
        self._handle(event.phase, self._hand())

    def _handle(self, phase: str, pose) -> None:
        if phase == "start":
            self.dragging = True
        elif phase == "end":
            with self.editor.viewer.lock:
                self.dragging = False
                self.follow_keyframe()        # a refused target snaps back to the hand
        else:
            self.solve_to(*pose)

    def solve_to(self, position, rotation, swivel: bool = False) -> bool:
        """Keyframe k's hand to `position` (and `rotation` with "Turn the hand too"); False and the
        refusal on the page if inverse kinematics or the editor refuses it."""
        start = time.perf_counter()
        ed = self.editor
        k = ed.k
        q_prev = ed.motion.q[k]
        phi = math.radians(float(self.swivel.value)) if swivel and self.arm.srs is not None else None
        try:
            with ed.viewer.lock:
                result = ik.solve(self.model, position, rotation if self.turn.value else None, q_prev=q_prev,
                                  swivel=phi)
        except ik.IkError as err:
            self.refusals += 1
            ed.refuse(str(err))
            self._show_reach(float(np.linalg.norm(np.asarray(position) - (self.arm.srs.S if self.arm.srs else
                                                                          self.arm.point[0]))), " — refused")
            return False
        self.solves += 1
        with ed.viewer.lock:
            ed.viewer.arm.pose(result.q)      # the arm first: the verdict below takes longer
            self.arm_s.append(time.perf_counter() - start)
            # the keyframe, its torques and verdict; the swivel slider and the reach follow the
            # keyframe there (follow_keyframe)
            ok = ed.set_keyframe(k, float(ed.motion.t[k]), result.q)
            if ok:
                ed.show_angles()
        self.handler_s.append(time.perf_counter() - start)
        return ok


class LiveFeed:
    """The loop's observer: `observe` keeps the latest tick (one assignment, no copy, no lock, no
    I/O on the loop's thread); the viewer's thread draws it at most PUBLISH_HZ times a second."""

    def __init__(self, viewer: Viewer):
        self.viewer = viewer
        self.latest = None
        self.ticks = 0
        self.frames = 0
        self._done = threading.Event()

    def observe(self, t, q_d, state, tau) -> None:
        self.latest = (t, q_d, state.q, tau)
        self.ticks += 1

    def stop(self) -> None:
        self._done.set()

    def publish_loop(self) -> None:
        v = self.viewer
        shown = None
        v.ghost.show(True)
        while not v._stop.wait(1.0 / PUBLISH_HZ) and not self._done.is_set():
            sample = self.latest
            if sample is None or sample is shown:
                continue
            shown = sample
            t, q_d, q, tau = sample
            with v.lock, v.server.atomic():
                v.arm.pose(q, yield_each=True)
                v.ghost.pose(q_d, yield_each=True)
            self.frames += 1
            if self.frames % 10 == 1:
                err = np.degrees(np.abs(np.asarray(q_d) - np.asarray(q)).max())
                v.readout.content = (f"live: t = {t:.2f} s, largest tracking error {err:.2f}°, "
                                     f"{self.ticks} ticks, {self.frames} frames drawn")


# ---------------------------------------------------------------------------- the command

def open_view(spec: str | None = None, log: str | None = None, motion: str | None = None,
              time_scale: float | None = None, host: str = "127.0.0.1", port: int = 8080,
              save_to: Path | None = None, source: str | None = None, say=print) -> Viewer:
    """Serve the page for a configuration or model, with a logged run or a motion loaded; with
    `source` (a BVH clip) the captured arm a retargeted motion CSV came from, overlaid."""
    config, model = load_subject(spec)
    if source is not None and not str(motion or "").lower().endswith(".csv"):
        raise ViewError("--source overlays the clip a retargeted motion came from: give that motion's CSV "
                        "(servodyn retarget -o) as --motion")
    timeline = None
    if log is not None:
        timeline = log_timeline(model, config, Path(log))
    motion_obj = None
    nothing_to_play = None             # why there is no Play panel
    if log is None and motion is None:
        try:                           # the forehand, where the model has its dofs
            motion_obj = load_motion(DEFAULT_MOTION, model)
        except (TrajectoryError, ModelError) as err:
            nothing_to_play = (f"**No Play panel**: nothing to play. No --motion or --log was given, and the "
                               f"default motion, {DEFAULT_MOTION}, does not fit model '{model.name}' "
                               f"({str(err).split(': ', 1)[-1]}). Give `--motion` a keyframe file or a "
                               f"trajectory CSV of this model's dofs, or `--log` a run's folder.")
    elif log is None:
        name = motion
        if str(name).lower().endswith(".csv"):
            timeline = _csv_timeline(model, config, name, time_scale or 1.0)
        else:
            if str(name) not in builtin_motions() and not Path(name).exists():
                raise ViewError(f"{name}: no such file, and not a built-in motion "
                                f"({', '.join(builtin_motions())})")
            try:
                motion_obj = load_motion(name, model)
            except (TrajectoryError, ModelError) as err:
                raise ViewError(str(err)) from None
    if time_scale is None:
        time_scale = (config.swing_time_scale if config is not None and motion is None else None) or 1.0
    if not (math.isfinite(time_scale) and time_scale > 0):
        raise ViewError(f"--time-scale must be a positive number, got {time_scale}")
    try:
        viewer = Viewer(config, model, host=host, port=port, say=say)
    except OSError as err:
        raise ViewError(f"cannot serve on {host}:{port}: {err.strerror or err}") from None
    if motion_obj is not None:
        viewer.edit(motion_obj, time_scale, save_to or Path("out/view") / f"{motion_obj.name}.toml")
    elif timeline is not None:
        if source is not None:
            try:
                clip = read_bvh(source)
                arms = find_arms(clip)
                t_source, points = source_arm(clip, model, float(timeline.t[-1]) / time_scale, arms,
                                              guess_axes(clip, arms)[0] if arms else None)
            except (BvhError, RetargetError, SkeletonError) as err:
                viewer.close()
                raise ViewError(str(err)) from None
            viewer.source = SourceOverlay(viewer.server, t_source, points, time_scale)
        viewer.show_timeline(timeline, f"run {log}" if log else f"{motion} at time scale {time_scale:g}")
    elif nothing_to_play:
        viewer.readout.content = nothing_to_play
    return viewer


def _csv_timeline(model, config, name: str, time_scale: float) -> Timeline:
    try:
        return trajectory_timeline(model, config, motion_path(name, model).at_scale(time_scale))[0]
    except (TrajectoryError, ValueError) as err:
        raise ViewError(str(err)) from None


def serve_forever(viewer: Viewer, say=print) -> None:
    say(f"servodyn view: {viewer.url}  (Ctrl-C stops)", flush=True)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        say("\nstopped", flush=True)
    finally:
        viewer.close()


def live_viewer(spec: str | None, host: str = "127.0.0.1", port: int = 8080, say=print):
    """The page for `servodyn swing --view`, and the feed the loop calls (its observer)."""
    config, model = load_subject(spec)
    try:
        viewer = Viewer(config, model, host=host, port=port, say=say)
    except OSError as err:
        raise ViewError(f"cannot serve on {host}:{port}: {err.strerror or err}") from None
    say(f"servodyn view: {viewer.url} shows the arm live", flush=True)
    return viewer, viewer.live()


def replay_after_live(viewer: Viewer, feed: LiveFeed, out: Path, say=print) -> None:
    """After the run: its log in the player, served until Ctrl-C."""
    feed.stop()
    if (out / "swing_log.csv").exists():
        try:
            viewer.show_timeline(log_timeline(viewer.model, viewer.config, out), f"run {out}")
        except ViewError as err:
            say(f"servodyn view: the run's log cannot be shown: {err}")
    say(f"live view: {feed.frames} frames drawn for {feed.ticks} ticks")
    serve_forever(viewer, say)
