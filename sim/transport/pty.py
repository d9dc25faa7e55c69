"""A simulated arm behind a pseudo-terminal, so dynamixel-sdk, or any serial client, opens it as
a port.

`PtyServer` serves the bytes in one loop that blocks on the pseudo-terminal (no polling): in
lock-step the host's command transactions advance the plant; in real time the plant is brought
up to the wall clock, whole periods only, before each packet is answered and at least every
`REALTIME_WAKE` s while the host is quiet (gravity goes on; the servos' watchdogs run on the wall
clock, `SimulatedRobot.wall_clock`). Either way the servos' receivers time the bytes on the wall
clock (the 1.5 ms inter-byte timeout), and `pause(seconds)` freezes the whole simulator, as a
stalled bus or process would. The loop runs in
a background thread (`start()`, for tests and tools that share the process) or in the calling
thread (`serve_forever()`).

A control socket (`serve_forever(control)`) takes requests between two packets, so a server in
another process (servodyn.sim.serve.SimProcess) injects faults, power-cycles the robot,
reads the plant's clock and the servos' torque deterministically, or pauses it.

Line speed. The servos hear only bytes sent at their own speed, so the server learns the speed
the host set on its end of the pseudo-terminal and tells the arm (`hear_at`). Checked on Linux
with pyserial 3.5 and dynamixel-sdk 4.1.0's PortHandler: a pty master's termios *is* its slave's
(the kernel's TCGETS on a master reads the slave side), and it stays set after the host closes its
port while this server holds the slave open. `termios.tcgetattr(master)` gives only the
B-constant: pyserial's 57600, 1 M and 4 M read back as B57600 (4097), B1000000 (4104) and
B4000000 (4111); 4.5 M, which pyserial sets through TCSETS2 with BOTHER, reads back as BOTHER
(4096), no speed at all. The TCGETS2 ioctl gives the speed in c_ispeed/c_ospeed for each of them:
57600, 1000000, 4000000 and 4500000 (the kernel fills them for a B-constant too).
dynamixel-sdk's setBaudRate takes 57600, 1 M and 4 M (it reopens the port at that speed) and
refuses 4.5 M (not among its 17 rates: it returns False and the port keeps its speed). A fresh
pseudo-terminal runs at 38400 (B38400): the server sets it to the bus's configured speed at start,
so a host that opens the path without setting a speed talks at the bus's.

The server reads the speed with TCGETS2 each time it reads the host's bytes: about 1 µs a call
alone, 1 to 4 µs in the serving loop (measured), against some 70 to 100 µs of the server's CPU a
transaction of the swing. Being told instead was tried and dropped: with the master in packet mode
(TIOCPKT) and EXTPROC in the slave's lflag, each change of the slave's termios does reach the
master as a status read (TIOCPKT_IOCTL, 0x40; the SDK's setBaudRate 0x41, with a flush), but so
does every tcflush: dynamixel-sdk's clearPort (reset_input_buffer) before each packet woke the
server with a TIOCPKT_FLUSHREAD status 1.9 times a transaction, an extra wake-up and read dearer
than the ioctl. The speed is the one set when the server reads: a host changes speed between
exchanges (the SDK reopens its port to do it), not with bytes of the old speed unread.
"""

from __future__ import annotations

import fcntl
import json
import os
import select
import struct
import sys
import termios
import threading
import time
import tty

REALTIME_WAKE = 0.02     # s: a real-time plant is brought up to the wall clock at least this often

# Linux's struct termios2 (asm-generic/termbits.h): c_iflag, c_oflag, c_cflag, c_lflag (4 bytes
# each), c_line, c_cc[19], c_ispeed, c_ospeed; TCGETS2 / TCSETS2 = _IOR / _IOW('T', 0x2A / 0x2B,
# struct termios2); BOTHER in c_cflag's CBAUD bits: "the speed is in c_ispeed / c_ospeed"
TERMIOS2 = struct.Struct("<4I B 19s 2I")
TCGETS2 = 0x80000000 | TERMIOS2.size << 16 | ord("T") << 8 | 0x2A     # 0x802C542A on x86-64 and arm64
TCSETS2 = 0x40000000 | TERMIOS2.size << 16 | ord("T") << 8 | 0x2B
BOTHER = 0o010000
_OSPEED = TERMIOS2.size - 4
_U32 = struct.Struct("<I")


def line_speed(fd: int, buffer: bytearray | None = None) -> int:
    """The speed (bit/s) a serial line's termios holds (a pty master: its slave's); `buffer`, of
    TERMIOS2.size bytes, saves an allocation a call."""
    buffer = bytearray(TERMIOS2.size) if buffer is None else buffer
    fcntl.ioctl(fd, TCGETS2, buffer, True)
    return _U32.unpack_from(buffer, _OSPEED)[0]


def set_line_speed(fd: int, speed: int) -> None:
    """Set a serial line's speed in and out (BOTHER: any speed, as pyserial does for 4.5 M)."""
    buffer = bytearray(TERMIOS2.size)
    fcntl.ioctl(fd, TCGETS2, buffer, True)
    iflag, oflag, cflag, lflag, line, cc, _, _ = TERMIOS2.unpack(buffer)
    cflag = (cflag & ~termios.CBAUD) | BOTHER
    fcntl.ioctl(fd, TCSETS2, TERMIOS2.pack(iflag, oflag, cflag, lflag, line, cc, speed, speed))


class PtyServer:
    """A Dynamixel bus of a simulated robot (SimulatedRobot.port) behind a pseudo-terminal."""

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
        # the host's line speed, told to the arm when it changes (an arm without hear_at: not at all;
        # the module's docstring)
        self._hear_at = getattr(arm, "hear_at", None)
        self._termios = bytearray(TERMIOS2.size)
        self._speed: int | None = None
        if self._hear_at is not None and getattr(arm, "baud", None):
            set_line_speed(self.slave, arm.baud)
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()  # stop() wakes the blocked loop through it
        self._lock = arm.lock                   # shared by every bus of one robot
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
        if hasattr(arm, "bus"):
            arm.bus.served_clock = mode       # what a swing on this pseudo-terminal asks (served_clock)

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
        """SimulatedRobot.inject_fault between two transactions: the packet in flight sees the servo
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
        """The plant's time (s) and each device's torque_off (SimulatedRobot.status)."""
        return self._request({"op": "status"})

    def _catch_up(self) -> None:
        """Real time: run the plant in whole periods up to the wall clock (never ahead of it).
        A plant that failed is reported once; the servos' clocks go on without it."""
        if self._plant_failed:
            self.arm.tick()
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
            speed = line_speed(self.master, self._termios) if self._hear_at is not None else None
        except OSError:
            return False
        with self._lock:
            try:
                if speed != self._speed:
                    self._speed = speed
                    self._hear_at(speed)
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

    def power_cycle(self) -> None:
        """SimulatedRobot.power_cycle between two transactions."""
        with self._lock:
            self.arm.power_cycle()

    def _request(self, request: dict) -> dict:
        """One request of the control socket: fault, clear, pause (answered, then the freeze),
        power_cycle, status or quit."""
        op = request.get("op")
        try:
            if op == "fault":
                self.inject_fault(request["id"], request.get("fault", "silent"))
            elif op == "clear":
                self.clear_faults()
            elif op == "pause":
                self.pause(float(request["seconds"]))
            elif op == "power_cycle":
                self.power_cycle()
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
            return {"ok": True, "errors": self.errors, **self.arm.status()}
