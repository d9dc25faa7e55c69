"""A simulated arm behind a pseudo-terminal, so dynamixel-sdk, or any serial client, opens it as
a port.

`PtyServer` serves the bytes in one loop that blocks on the pseudo-terminal (no polling): in
lock-step the host's command transactions advance the plant; in real time the plant is brought
up to the wall clock, whole periods only, before each packet is answered and at least every
`REALTIME_WAKE` s while the host is quiet (gravity goes on; the servos' watchdogs run on the wall
clock, `SimulatedArm.wall_clock`). Either way the servos' receivers time the bytes on the wall
clock (the 1.5 ms inter-byte timeout), and `pause(seconds)` freezes the whole simulator, as a
stalled bus or process would. The loop runs in
a background thread (`start()`, for tests and tools that share the process) or in the calling
thread (`serve_forever()`).

`SimProcess` runs it in a child process (`python -m servodyn.sim.transport.pty`), so the host
loop's figures are its own: the child dies with its parent (PR_SET_PDEATHSIG, and the end of its
control socket), and the parent injects faults and reads the plant's clock and the servos' torque
through that socket, each request answered before the next packet is sent (deterministic).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
from contextlib import nullcontext

from servodyn.control.realtime import SIMULATOR_PRIORITY, realtime_priority

REALTIME_WAKE = 0.02     # s: a real-time plant is brought up to the wall clock at least this often


class PtyServer:
    """A SimulatedArm behind a pseudo-terminal."""

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
        self._wake_r, self._wake_w = os.pipe()  # stop() wakes the blocked loop through it
        self._lock = getattr(arm, "lock", None) or threading.Lock()   # shared by every bus of one robot
        self._thread = None
        self._epoch = None                      # wall clock at plant time 0 (real time)
        self._paused_until = 0.0
        self._plant_failed = False
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
        """Serve in a background thread."""
        self._thread = threading.Thread(target=self.serve_forever, name="servodyn-sim", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for fd in (self.master, self.slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def inject_fault(self, servo_id: int, fault: str | int = "silent") -> None:
        """SimulatedArm.inject_fault between two transactions: the packet in flight sees the servo
        either before or after."""
        with self._lock:
            self.arm.inject_fault(servo_id, fault)

    def clear_faults(self) -> None:
        with self._lock:
            self.arm.clear_faults()

    def pause(self, seconds: float) -> None:
        """Freeze the simulator for `seconds` from now: nothing is read or answered and no clock
        moves (the host's bytes wait in the pseudo-terminal); then it goes on."""
        self._paused_until = time.monotonic() + seconds

    def _frozen(self) -> bool:
        """Wait out a pause; True if the server was stopped meanwhile."""
        paused = False
        while (left := self._paused_until - time.monotonic()) > 0:
            paused = True
            if self._stop.wait(min(left, 0.05)):
                return True
        if paused and self._epoch is not None:     # after a pause the plant goes on from where it stood
            self._epoch = time.perf_counter() - self.arm.time
        return self._stop.is_set()

    @property
    def servos(self) -> int:
        return len(self.arm.servos)

    def status(self) -> dict:
        """The plant's time (s) and each servo's torque_off, as SimProcess.status()."""
        return self._request({"op": "status"})

    def _catch_up(self) -> None:
        """Real time: run the plant in whole periods up to the wall clock (never ahead of it).
        A plant that failed is reported once; the servos' clocks go on without it."""
        if self._plant_failed:
            self.arm.bus.tick()
            return
        period = self.arm.small_time_step
        behind = int((time.perf_counter() - self._epoch - self.arm.time) / period + 1e-9)
        if behind > 0:
            self.arm.advance(behind * period)

    def serve_forever(self, control=None) -> None:
        """Answer the host until stop() (or, with a control socket, until it closes). control:
        a connected socket whose requests (one JSON object a line) run between two packets."""
        realtime = self.mode == "realtime"
        self._epoch = time.perf_counter() - self.arm.time
        watch = [self.master, self._wake_r] + ([control] if control is not None else [])
        pending = b""
        while not self._frozen():
            try:
                ready, _, _ = select.select(watch, [], [], REALTIME_WAKE if realtime else None)
            except (OSError, ValueError):
                return
            if self._paused_until > time.monotonic():
                continue
            if realtime:
                with self._lock:
                    try:
                        self._catch_up()
                    except Exception as err:     # a plant that cannot go on: one line, the servos go on
                        self.errors += 1
                        self._plant_failed = True
                        self.on_error(f"simulated bus: {type(err).__name__} in the plant, which stops: {err}")
            # the host's bytes first: a request on the control socket comes after what the host
            # wrote before it (a process that wrote its last packet and exited, then a status)
            if self.master in ready and not self._answer():
                return
            if control is not None and control in ready:
                data = control.recv(4096)
                if not data:
                    return                           # the parent is gone, or done
                pending += data
                while b"\n" in pending:
                    line, pending = pending.split(b"\n", 1)
                    control.sendall((json.dumps(self._request(json.loads(line))) + "\n").encode())

    def _answer(self) -> bool:
        """Read what the host sent and answer it; False when the pseudo-terminal is gone."""
        try:
            data = os.read(self.master, 4096)
        except OSError:
            return False
        with self._lock:
            try:
                reply = self.arm.handle(data)
            except Exception as err:       # a serving loop that died would leave the bus deaf
                self.errors += 1
                self.on_error(f"simulated bus: {type(err).__name__} while answering the host: {err}")
                reply = b""
        if reply:
            try:
                os.write(self.master, reply)
            except OSError:
                return False
        return True

    def _drain(self, quiet: float = 0.02) -> None:
        """Answer the host's bytes still in flight (a pseudo-terminal hands written bytes over
        asynchronously) until it has been quiet for `quiet` s."""
        while select.select([self.master], [], [], quiet)[0] and self._answer():
            pass

    def _request(self, request: dict) -> dict:
        """One request of the control socket: fault, clear, status or quit."""
        op = request.get("op")
        try:
            if op == "fault":
                self.inject_fault(request["id"], request.get("fault", "silent"))
            elif op == "clear":
                self.clear_faults()
            elif op == "quit":
                self._stop.set()
            elif op != "status":
                raise ValueError(f"unknown request {op!r}")
        except (ValueError, KeyError) as err:
            return {"ok": False, "error": str(err)}
        if op == "status" and self._thread is None:
            self._drain()
        with self._lock:
            if self.mode == "realtime":
                self._catch_up()
            return {"ok": True, "time": self.arm.time, "errors": self.errors,
                    "torque_off": [not servo.torque_enabled for servo in self.arm.servos]}


class SimProcessError(RuntimeError):
    """The simulator's child process could not start or stopped answering its control socket."""


class SimProcess:
    """The simulated bus of a configuration file in a child process, on a pseudo-terminal."""

    def __init__(self, config_path, mode: str = "lockstep", start_timeout: float = 60.0):
        if mode not in ("lockstep", "realtime"):
            raise ValueError("mode must be 'lockstep' or 'realtime'")
        self._control, child = socket.socketpair()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "servodyn.sim.transport.pty", "--config", str(config_path), "--mode", mode,
             "--control-fd", str(child.fileno()), "--parent", str(os.getpid())],
            pass_fds=(child.fileno(),), stdin=subprocess.DEVNULL)
        child.close()
        self._control.settimeout(start_timeout)
        self._buffer = b""
        try:
            hello = self._receive()
        except SimProcessError:
            self.stop()
            raise
        if not hello.get("ok"):
            self.stop()
            raise SimProcessError(f"simulated bus: {hello.get('error')}")
        self.path, self.servos = hello["path"], hello["servos"]
        self._control.settimeout(10.0)

    def __enter__(self) -> "SimProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _receive(self) -> dict:
        while b"\n" not in self._buffer:
            try:
                data = self._control.recv(4096)
            except (OSError, socket.timeout) as err:
                raise SimProcessError(f"simulated bus: no answer from its process ({err})") from None
            if not data:
                raise SimProcessError(f"simulated bus: its process ended (exit status {self.process.poll()})")
            self._buffer += data
        line, self._buffer = self._buffer.split(b"\n", 1)
        return json.loads(line)

    def request(self, op: str, **args) -> dict:
        try:
            self._control.sendall((json.dumps({"op": op, **args}) + "\n").encode())
        except OSError as err:
            raise SimProcessError(f"simulated bus: its process is gone ({err})") from None
        answer = self._receive()
        if not answer.get("ok", False):
            raise ValueError(answer.get("error", "refused"))
        return answer

    def inject_fault(self, servo_id: int, fault: str | int = "silent") -> None:
        """The fault is in place when this returns: the next packet sees it."""
        self.request("fault", id=servo_id, fault=fault)

    def clear_faults(self) -> None:
        self.request("clear")

    def status(self) -> dict:
        """The plant's time (s) and each servo's torque_off, as the simulator sees them now."""
        return self.request("status")

    def stop(self) -> None:
        """Ask the child to end, and make sure it has."""
        if self.process.poll() is None:
            try:
                self._control.sendall(b'{"op": "quit"}\n')
            except OSError:
                pass
            try:
                self.process.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._control.close()


def _die_with_parent(parent: int) -> None:
    """SIGTERM when the parent process ends (Linux prctl PR_SET_PDEATHSIG), and a check that it
    has not ended already before the call."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)        # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        pass                                           # elsewhere: the control socket's end stops it
    if os.getppid() != parent:
        sys.exit(0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.sim.transport.pty",
                                     description="the simulated bus in a child process (SimProcess)")
    parser.add_argument("--config", required=True)
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    parser.add_argument("--control-fd", type=int, required=True)
    parser.add_argument("--parent", type=int, required=True)
    args = parser.parse_args(argv)
    _die_with_parent(args.parent)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    control = socket.socket(fileno=args.control_fd)
    from servodyn.hal.config import load_config
    from ..arm import SimulatedArm
    try:
        arm = SimulatedArm(load_config(args.config))
    except Exception as err:     # reported to the parent as one line, never a traceback
        control.sendall((json.dumps({"ok": False, "error": str(err)}) + "\n").encode())
        return 2
    server = PtyServer(arm, args.mode)
    gc.freeze()      # the set-up's objects (model, tables, numpy) out of every later collection
    control.sendall((json.dumps({"ok": True, "path": server.path, "servos": len(arm.servos)}) + "\n").encode())
    try:
        # in real time the simulated servos answer ahead of everything else, as hardware does
        with realtime_priority(SIMULATOR_PRIORITY, "the simulated bus") if args.mode == "realtime" else nullcontext():
            server.serve_forever(control)
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
