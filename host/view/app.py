"""The page: `Viewer` holds one viser server — the arm, the planned arm as a ghost, the status and
readout, the player (play, pause, scrub, speed) and the angle, tracking-error and torque plots that
follow its time cursor — and starts the shaping editor (editor.py) and the live feed (live.py)."""

from __future__ import annotations

import contextlib
import errno
import io
import math
import socket
import threading
import time
from pathlib import Path

import numpy as np

from ..control.motion import Motion
from ..control.timing import SMALL_TIME_STEP
from .drawing import GHOST_OPACITY, GHOST_RGB, SOLID_RGB, ArmDrawing, SourceOverlay
from .editor import MotionEditor
from .live import LiveFeed
from .timeline import Timeline, ViewError

PLAY_HZ = 30.0             # playback: frames a second
PLOT_POINTS = 600          # samples per plotted series (decimated from the 1 ms samples)
PLOTS = ("angle (°)", "tracking error (°)", "torque (N·m)")
PLOT_WINDOW = 2.0          # s of the plots around the cursor
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf")


def check_address(host: str, http_port: int) -> None:
    """ViewError unless host:http_port can be served (viser would fail in its own thread, and hang)."""
    if not 0 <= http_port <= 65535:
        raise ViewError(f"the page's TCP port must be from 0 to 65535, got {http_port}")
    try:
        family, kind, _, _, address = socket.getaddrinfo(host, http_port, type=socket.SOCK_STREAM)[0]
        with socket.socket(family, kind) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind(address)
    except (socket.gaierror, UnicodeError) as err:
        raise ViewError(f"host {host}: not an address this machine can serve on ({err})") from None
    except OSError as err:
        if err.errno != errno.EADDRINUSE:          # a port in use: viser takes the next free one
            raise ViewError(f"cannot serve on {host}:{http_port}: {err.strerror or err}") from None


def _quiet():
    """viser prints a banner with the URL on stdout when it starts, and a line when it stops, even
    unasked (verbose=False): the command says the URL itself, and stdout is for data."""
    return contextlib.redirect_stdout(io.StringIO())


def _set_page_title(server, title: str) -> None:
    """The browser tab's title (viser's page says "Viser"): a script every page runs on connecting.
    viser has no call for it; its message for running a script on the page is kept for new pages."""
    from viser import _messages
    source = f"document.title = {title!r};"
    server.scene._websock_interface.queue_message(_messages.RunJavascriptMessage(source=source))


class Viewer:
    """One viser server and its page: the arm, the ghost, the plots, the player and the editor."""

    def __init__(self, config, model, host: str = "127.0.0.1", http_port: int = 8080, say=print):
        import viser
        check_address(host, http_port)
        self.config, self.model, self.say = config, model, say
        try:
            with _quiet():
                self.server = viser.ViserServer(host=host, port=http_port, verbose=False)
        except OSError as err:
            raise ViewError(f"cannot serve on {host}:{http_port}: {err.strerror or err}") from None
        self.lock = threading.RLock()
        server = self.server
        self.title = f"servodyn — {config.name if config is not None else model.name}"
        _set_page_title(server, self.title)
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
    def http_port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}/"

    def wait_for_browser(self, poll: float = 0.1) -> None:
        """Return once a browser has the page open (a client connected); KeyboardInterrupt ends the wait."""
        while not self.server.get_clients():
            time.sleep(poll)

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
        names = self.model.dof_names
        for title, values in series.items():
            data = (t.astype(np.float64),) + tuple(np.ascontiguousarray(values[:, j], dtype=np.float64)
                                                   for j in range(values.shape[1]))
            specs = (uplot.Series(label="t (s)"),) + tuple(
                uplot.Series(label=name, stroke=PALETTE[j % len(PALETTE)], width=1.5) for j, name in enumerate(names))
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
        with _quiet():
            self.server.stop()


