"""`servodyn view` and `servodyn swing --view`: the command's side of the browser view (the page
itself is the servodyn.view library). Its arguments are checked here in the command's words; the
page is served until Ctrl-C; its messages go to stderr."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

from ..view import LiveFeed, Viewer, ViewError, log_timeline
from ..view import live_viewer as _live_viewer
from ..view import open_view as _open_view

__all__ = ["ViewError", "live_viewer", "open_view", "replay_after_live", "serve_forever"]


def _stderr(*args, **kwargs) -> None:
    print(*args, file=sys.stderr, **kwargs)


def _check_port(port: int) -> None:
    if not 0 <= port <= 65535:
        raise ViewError(f"--port must be from 0 to 65535, got {port}")


def open_view(spec: str | None = None, log: str | None = None, motion: str | None = None,
              time_scale: float | None = None, host: str = "127.0.0.1", port: int = 8080,
              save_to: Path | None = None, source: str | None = None, say=_stderr) -> Viewer:
    """`servodyn view`'s page (servodyn.view.open_view; `port` is the page's TCP port)."""
    _check_port(port)
    if time_scale is not None and not (math.isfinite(time_scale) and time_scale > 0):
        raise ViewError(f"--time-scale must be a positive number, got {time_scale}")
    return _open_view(spec, log=log, motion=motion, time_scale=time_scale, host=host, http_port=port,
                      save_to=save_to, source=source, say=say)


def serve_forever(viewer: Viewer, say=_stderr) -> None:
    say(f"servodyn view: {viewer.url}  (Ctrl-C stops)", flush=True)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        say("\nstopped", flush=True)
    finally:
        viewer.close()


def live_viewer(spec: str | None, host: str = "127.0.0.1", port: int = 8080, say=_stderr, wait: bool = True):
    """`servodyn swing --view`: the page and the feed the loop calls (its observer). With `wait`
    it returns once a browser has the page open: a lock-step swing on the simulated bus is over in
    a few seconds, before a page opened after this line could draw (Ctrl-C stops the wait)."""
    _check_port(port)
    viewer, feed = _live_viewer(spec, host=host, http_port=port, say=say)
    if not wait:
        say(f"servodyn view: {viewer.url} shows the arm live", flush=True)
        return viewer, feed
    say(f"servodyn view: open {viewer.url} — the swing starts once a browser shows the page (Ctrl-C stops)",
        flush=True)
    try:
        viewer.wait_for_browser()
    except KeyboardInterrupt:
        viewer.close()
        raise
    say("servodyn view: a browser has the page; the swing starts", flush=True)
    return viewer, feed


def replay_after_live(viewer: Viewer, feed: LiveFeed, out: Path, say=_stderr) -> None:
    """After the run: its log in the player, served until Ctrl-C."""
    feed.stop()
    if (out / "swing_log.csv").exists():
        try:
            viewer.show_timeline(log_timeline(viewer.model, viewer.config, out), f"run {out}")
        except ViewError as err:
            say(f"servodyn view: the run's log cannot be shown: {err}")
    say(f"live view: {feed.frames} frames drawn for {feed.ticks} ticks")
    serve_forever(viewer, say)
