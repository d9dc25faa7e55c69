"""Simulated CAN buses served to a host: on python-can's in-process `virtual` interface, or behind
an SLCAN adapter on a pseudo-terminal (Lawicel ASCII), so any python-can program in another process
opens it with can.Bus(interface="slcan", channel=PATH, bitrate=1000000).

The adapter speaks what python-can and slcan firmware (CANable and similar) speak: `O` open, `L`
listen-only, `C` close, `S0`-`S8` bit rate, `sXXYY` bit timing, `V` version, `N` serial number,
`F` status flags, `Z0/1` time stamps, each acknowledged with CR (BEL for a command it refuses);
frames `tIIIL<data>` and `TIIIIIIIIL<data>` (acknowledged `z`/`Z` CR, as Lawicel's adapter does),
remote `r`/`R`, CAN FD `d`/`D`/`b`/`B` (hex length code); an empty line is acknowledged too (python-can
sends one at open). The motors' frames go back as `t` lines. In real time a second thread advances
the plant by the wall clock; in lock-step the motors' command rounds do.

Like a real adapter, it never waits for its host: a host that writes without reading fills the
pseudo-terminal and then the adapter's own buffer (OUT_QUEUE bytes); what does not fit then is
dropped, each motor's frame counted (`dropped`) and `F` reports a data overrun (bit 3) once. The
adapter goes on reading and answering meanwhile, so a host that reads again gets the answers to its
new frames (a blocking write had stopped the adapter after ~1,500 unread frames, and the host's
blocking send with it).
"""

from __future__ import annotations

import os
import select
import sys
import threading
import time
import tty

from servodyn.hal.can.spec import SIMULATOR_SERIALS

BITRATE_CODES = {"0": 10_000, "1": 20_000, "2": 50_000, "3": 100_000, "4": 125_000, "5": 250_000,
                 "6": 500_000, "7": 800_000, "8": 1_000_000}
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
OK, BELL = b"\r", b"\a"
MAX_LINE = 160                 # characters: a 64-byte FD frame is 138
OUT_QUEUE = 4096               # bytes of answers the adapter holds for a host that is not reading
DATA_OVERRUN = 0x08            # bit 3 of the status flags (`F`): frames were lost, the host did not read


class _Server:
    """What both transports share: the lock around the robot, the real-time clock, fault injection.
    `port`: the CAN bus of a simulated robot (SimulatedRobot.port)."""

    def __init__(self, port, mode: str, control_period: float | None, on_error):
        if mode not in ("lockstep", "realtime"):
            raise ValueError("mode must be 'lockstep' or 'realtime'")
        self.arm, self.mode = port, mode
        self.bus = port.name
        self._stop = threading.Event()
        self._lock = port.lock          # shared by every bus of one robot
        self.errors = 0
        self.on_error = on_error or (lambda message: print(message, file=sys.stderr, flush=True))
        self._threads = [threading.Thread(target=self._serve, name="servodyn-can-sim", daemon=True)]
        if mode == "lockstep":
            port.lockstep(control_period)
        else:
            self._threads.append(threading.Thread(target=self._clock, name="servodyn-plant", daemon=True))

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        for thread in self._threads:
            thread.start()

    def stop(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._close()

    def inject_fault(self, can_id: int, fault="silent") -> None:
        with self._lock:
            self.arm.inject_fault(can_id, fault)

    def _answer(self, arbitration_id: int, data: bytes) -> list[tuple[int, bytes]]:
        with self._lock:
            try:
                return self.arm.handle(arbitration_id, data)
            except Exception as err:        # a serving thread that died would leave the bus deaf
                self.errors += 1
                self.on_error(f"simulated CAN bus: {type(err).__name__} while answering the host: {err}")
                return []

    def _clock(self) -> None:
        period = self.arm.small_time_step
        start = time.perf_counter() - self.arm.time
        while not self._stop.is_set():
            delay = start + self.arm.time + period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            with self._lock:
                self.arm.advance(period)


class VirtualCanServer(_Server):
    """A simulated robot's CAN bus on python-can's virtual interface, channel `channel`, in this process: the
    motors answer from a thread, or (threaded=False) in the thread of whoever waits for them, through
    `host_bus()`: the frames still travel through python-can's virtual channel, but a lock-step run
    no longer pays two threads' hand-over of the interpreter lock for every frame."""

    def __init__(self, port, channel: str, mode: str = "lockstep", control_period: float | None = None,
                 on_error=None, threaded: bool = True):
        import can
        self.channel = channel
        self.can = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._message = can.Message
        super().__init__(port, mode, control_period, on_error)
        if not threaded:
            self._threads = [t for t in self._threads if t.name != "servodyn-can-sim"]

    def _serve(self) -> None:
        while not self._stop.is_set():
            self._take(self.can.recv(0.05))

    def _take(self, msg) -> None:
        if msg is None or msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        for reply_id, data in self._answer(msg.arbitration_id, bytes(msg.data)):
            if reply_id < 0:               # an error frame, its class in the id (sim/faults.py)
                self.can.send(self._message(arbitration_id=-reply_id, data=data, is_error_frame=True))
            else:
                self.can.send(self._message(arbitration_id=reply_id, data=data, is_extended_id=False))

    def pump(self) -> None:
        """Answer every frame waiting on the channel, in this thread."""
        while (msg := self.can.recv(0.0)) is not None:
            self._take(msg)

    def host_bus(self):
        """A python-can virtual bus on the channel whose recv() lets the motors answer first."""
        import can
        server = self

        class PumpedBus(can.interfaces.virtual.VirtualBus):
            def _recv_internal(self, timeout):
                server.pump()
                return super()._recv_internal(timeout)

            def send(self, msg, timeout=None):
                network = server.arm.network
                if network.bus_off():      # a bus-off fault: as python-can reports a failed send
                    raise can.CanOperationError("bus-off: the controller is off the bus after too many errors")
                super().send(msg, timeout)

        return PumpedBus(channel=self.channel)

    def _close(self) -> None:
        self.can.shutdown()


class SlcanServer(_Server):
    """A simulated robot's CAN bus behind an SLCAN adapter on a pseudo-terminal (`path`)."""

    def __init__(self, port, mode: str = "realtime", control_period: float | None = None, on_error=None,
                 ack_frames: bool = True):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        os.set_blocking(self.master, False)     # the adapter never waits for its host
        self.is_open, self.bitrate, self.ack_frames = False, None, ack_frames
        self.lines = self.refused = 0
        self.dropped = 0                        # the motors' frames lost: the host was not reading
        self._out = bytearray()                 # answers the pseudo-terminal had no room for yet
        self._overrun = False                   # a frame dropped since the host last asked `F`
        super().__init__(port, mode, control_period, on_error)

    def _close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def _serve(self) -> None:
        pending = b""
        while not self._stop.is_set():
            try:
                ready, writable, _ = select.select([self.master], [self.master] if self._out else [], [], 0.05)
                if writable and not self._flush():
                    return
                if not ready:
                    continue
                pending += os.read(self.master, 4096)
            except BlockingIOError:
                continue
            except OSError:
                return
            *lines, pending = pending.replace(b"\n", b"").split(b"\r")
            if len(pending) > MAX_LINE:          # no CR in sight: garbage, dropped
                pending = b""
                self.refused += 1
                self._queue(BELL)
            for line in lines:
                self._queue(self.line(line))
            if self._out and not self._flush():
                return

    def _queue(self, answer: bytes) -> None:
        """An answer for the host, whole or not at all: one that would overflow the adapter's
        buffer is dropped, its frames counted (the host sees lines, never a part of one)."""
        if len(self._out) + len(answer) <= OUT_QUEUE:
            self._out += answer
            return
        lost = sum(1 for line in answer.split(OK) if line[:1] in (b"t", b"T"))
        self.dropped += lost
        self._overrun = self._overrun or bool(lost)

    def _flush(self) -> bool:
        """As much of the buffered answers as the pseudo-terminal takes now; False when it is gone."""
        try:
            sent = os.write(self.master, self._out)
        except BlockingIOError:
            return True
        except OSError:
            return False
        del self._out[:sent]
        return True

    def line(self, raw: bytes) -> bytes:
        """One Lawicel command line (without its CR) in, the adapter's answer out."""
        self.lines += 1
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            self.refused += 1
            return BELL
        answer = self._command(text)
        if answer == BELL:
            self.refused += 1
        return answer

    def _command(self, text: str) -> bytes:
        if not text:
            return OK
        head, rest = text[0], text[1:]
        if head in "OL":
            self.is_open = True
            return OK
        if head == "C":
            self.is_open = False
            return OK
        if head == "S" and rest in BITRATE_CODES:
            if self.is_open:
                return BELL
            self.bitrate = BITRATE_CODES[rest]
            return OK
        if head == "s" and len(rest) == 4 and _is_hex(rest):
            return BELL if self.is_open else OK
        if head == "V" and not rest:
            return b"V1013\r"
        if head == "v" and not rest:
            return b"v1013\r"
        if head == "N" and not rest:
            return f"N{SIMULATOR_SERIALS[self.mode]}\r".encode()
        if head == "F" and not rest:
            flags, self._overrun = DATA_OVERRUN if self._overrun else 0, False
            return b"F%02X\r" % flags
        if head == "Z" and rest in ("0", "1"):
            return OK
        if head in "tTrRdDbB":
            return self._frame(head, rest)
        return BELL

    def _frame(self, head: str, rest: str) -> bytes:
        extended = head in "TRDB"
        width = 8 if extended else 3
        if len(rest) < width + 1 or not _is_hex(rest[:width + 1]) or not self.is_open:
            return BELL
        arbitration_id = int(rest[:width], 16)
        code = int(rest[width], 16)
        if arbitration_id > (0x1FFFFFFF if extended else 0x7FF):
            return BELL
        if head in "dDbB":
            length = FD_LENGTHS[code]
        elif code <= 8:
            length = code
        else:
            return BELL
        payload = rest[width + 1:]
        if head in "rR":
            payload = payload if len(payload) in (0, 4) else "x"   # a remote frame carries no data
            return (b"Z\r" if extended else b"z\r") if self.ack_frames and _is_hex(payload or "0") else \
                (OK if _is_hex(payload or "0") else BELL)
        data_hex = payload[:2 * length]
        tail = payload[2 * length:]
        if len(data_hex) != 2 * length or not _is_hex(data_hex or "0") or (tail and not (len(tail) == 4 and _is_hex(tail))):
            return BELL
        ack = (b"Z\r" if extended else b"z\r") if self.ack_frames else OK
        if extended:
            return ack                               # the motors speak 11-bit ids only
        replies = self._answer(arbitration_id, bytes.fromhex(data_hex))
        # Lawicel's lines carry no error frame: one among the answers is lost here
        return ack + b"".join(f"t{i:03X}{len(d)}{d.hex().upper()}\r".encode() for i, d in replies if i >= 0)


def _is_hex(text: str) -> bool:
    return bool(text) and all(c in "0123456789abcdefABCDEF" for c in text)
