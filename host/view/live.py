"""`servodyn swing --view`: the loop hands each tick's state to `LiveFeed.observe`, which only
keeps the latest; a thread of the viewer's own draws it at most PUBLISH_HZ times a second."""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .app import Viewer

PUBLISH_HZ = 30.0          # live view: frames a second drawn at most (a tick's state, decimated)


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
