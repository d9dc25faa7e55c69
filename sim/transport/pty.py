"""A simulated arm behind a pseudo-terminal, so dynamixel-sdk, or any serial client, opens it as
a port. A background thread serves the bytes; in real time a second one advances the plant by
the wall clock (and the servos' watchdogs run on it), in lock-step the host's command transactions
do. Either way the servos' receivers time the bytes on the wall clock (the 1.5 ms inter-byte
timeout), and `pause(seconds)` freezes the whole simulator, as a stalled bus or process would."""

from __future__ import annotations

import os
import select
import sys
import threading
import time
import tty


class PtyServer:
    """A SimulatedArm behind a pseudo-terminal, served by a background thread."""

    def __init__(self, arm, mode: str = "lockstep", control_period: float | None = None, on_error=None):
        """on_error(message): told, in one line, of an exception the arm raised while handling the
        host's bytes (default: standard error); the server goes on serving."""
        if mode not in ("lockstep", "realtime"):
            raise ValueError("mode must be 'lockstep' or 'realtime'")
        self.arm, self.mode = arm, mode
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)                 # bytes pass untouched: no echo, no line editing
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._serve, name="servodyn-sim", daemon=True)
        self._paused_until = 0.0
        self.errors = 0
        self.on_error = on_error or (lambda message: print(message, file=sys.stderr, flush=True))
        if mode == "lockstep":
            arm.lockstep(control_period)
        else:
            arm.wall_clock()
        arm.wire_clock()

    def __enter__(self) -> "PtyServer":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        self._thread.start()
        if self.mode == "realtime":
            threading.Thread(target=self._clock, name="servodyn-plant", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.ident is not None:
            self._thread.join(timeout=2.0)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def inject_fault(self, servo_id: int, fault: str | int = "silent") -> None:
        """SimulatedArm.inject_fault between two transactions: the packet in flight sees the servo
        either before or after."""
        with self._lock:
            self.arm.inject_fault(servo_id, fault)

    def pause(self, seconds: float) -> None:
        """Freeze the simulator for `seconds` from now: nothing is read or answered and no clock
        moves (the host's bytes wait in the pseudo-terminal); then it goes on."""
        self._paused_until = time.monotonic() + seconds

    def _frozen(self) -> bool:
        """Wait out a pause; True if the server was stopped meanwhile."""
        while (left := self._paused_until - time.monotonic()) > 0:
            if self._stop.wait(min(left, 0.05)):
                return True
        return self._stop.is_set()

    def clear_faults(self) -> None:
        with self._lock:
            self.arm.clear_faults()

    def _serve(self) -> None:
        while not self._frozen():
            try:
                ready, _, _ = select.select([self.master], [], [], 0.05)
                if not ready or self._paused_until > time.monotonic():
                    continue
                data = os.read(self.master, 4096)
            except OSError:
                return
            with self._lock:
                try:
                    reply = self.arm.handle(data)
                except Exception as err:       # a serving thread that died would leave the bus deaf
                    self.errors += 1
                    self.on_error(f"simulated bus: {type(err).__name__} while answering the host: {err}")
                    reply = b""
            if reply:
                try:
                    os.write(self.master, reply)
                except OSError:
                    return

    def _clock(self) -> None:
        period = self.arm.small_time_step
        start = time.perf_counter()
        plant_failed = False
        while not self._frozen():
            if self._paused_until:         # after a pause the plant goes on from where it stood
                start, self._paused_until = time.perf_counter() - self.arm.time, 0.0
            target = start + self.arm.time + period
            delay = target - time.perf_counter()
            time.sleep(max(delay, 0.0))        # behind, still yield: the serving thread needs the lock
            with self._lock:
                if plant_failed:               # the servos' clocks go on without it
                    self.arm.bus.tick()
                    continue
                try:
                    self.arm.advance(period)
                except Exception as err:
                    self.errors += 1
                    plant_failed = True
                    self.on_error(f"simulated bus: {type(err).__name__} in the plant, which stops: {err}")
