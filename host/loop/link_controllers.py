"""Who runs the control loop (`servodyn swing --controller python|native|qemu:BOARD|PORT`), and, for
every controller but the Python loop, the line to it: the general firmware application
(firmware/app/fw_link.c) on the host link (docs/host-link.md).

    native       the application as a Linux process (build/fw/native/servodyn-fw-link), its host
                 link on a pseudo-terminal, its bus the simulated (or the configuration's) port
    qemu:BOARD   the application's image for BOARD under QEMU (build/fw/BOARD-link), lock-stepped
                 to a simulated arm on its bus UART (servodyn.loop.qemu.QemuController)
    PORT         a board already running the application, on a serial port (or a pseudo-terminal:
                 the Linux process started with link=pty); its buses are its own

Each is an object with `name`, `fd` (the link's descriptor, non-blocking), `poll()` (None while it
runs, else its exit status), `finish(timeout)` (its output once it ends) and `close()`.
"""

from __future__ import annotations

import os
import subprocess
import tty
from dataclasses import dataclass
from pathlib import Path

import serial

from ..errors import InputError
from .native import FirmwareError
from .qemu import BOARDS

ROOT = Path(__file__).resolve().parents[2]
NATIVE_LINK = ROOT / "build" / "fw" / "native" / "servodyn-fw-link"
LINK_BAUD = 2_000_000            # the host link's UART (docs/host-link.md): 2 Mbps 8N1
QEMU_LINK_BOARDS = ("an386", "f405")       # the boards with an image of the general application


class ControllerError(InputError):
    """A --controller that names no controller."""


@dataclass(frozen=True)
class ControllerChoice:
    """What --controller names: kind python, native, qemu (board) or port (path)."""
    kind: str
    board: str | None = None
    path: str | None = None

    def __str__(self) -> str:
        return {"qemu": f"qemu:{self.board}", "port": self.path}.get(self.kind, self.kind)


def parse_controller(text: str) -> ControllerChoice:
    """--controller's value: python, native, qemu:BOARD or a serial port's path."""
    text = str(text).strip()
    if text in ("python", "native"):
        return ControllerChoice(text)
    if text.startswith("qemu:") or text == "qemu":
        board = text[5:]
        if board not in QEMU_LINK_BOARDS:
            boards = ", ".join(f"qemu:{b} ({BOARDS[b][0]}, {BOARDS[b][1]})" for b in QEMU_LINK_BOARDS)
            raise ControllerError(f"--controller {text}: QEMU runs the controller on {boards}")
        return ControllerChoice("qemu", board=board)
    if text.startswith("/") or text.upper().startswith("COM") or text.startswith("./"):
        return ControllerChoice("port", path=text)
    raise ControllerError(f"--controller {text!r}: python, native, qemu:BOARD (BOARD one of "
                          f"{', '.join(QEMU_LINK_BOARDS)}) or the serial port of a board running the controller "
                          "(e.g. /dev/ttyACM0)")


class NativeController:
    """The general application as a Linux process on its buses, its host link on a pseudo-terminal."""

    def __init__(self, arguments: list, *, realtime: bool, tolerance_us: int | None = None,
                 exe: Path | None = None):
        """arguments: the process's bus arguments (its Dynamixel port first, baud=N, can=PATH, reply_ms=N:
        servodyn.loop.native_link.bus_arguments)."""
        exe = Path(exe) if exe else NATIVE_LINK
        if not exe.is_file():
            raise FirmwareError(f"no native controller at {exe} (build it with `make fw`)")
        self.name = "native"
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        command = [str(exe), *arguments, f"link={os.ttyname(self.slave)}", "once=1"]
        if realtime:
            command.append("realtime")
            if tolerance_us is not None:
                command.append(f"tolerance_us={tolerance_us}")
        self.proc = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.fd = self.master

    def poll(self):
        return self.proc.poll()

    def finish(self, timeout: float) -> str:
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise FirmwareError(f"the native controller did not end within {timeout:g} s of torque off") from None
        return out + "\n" + err

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class PortController:
    """A board running the general application on the serial port `path` (2 Mbps 8N1 raw), or the
    Linux process's pseudo-terminal (link=pty). Nothing of it ends with the run: it stays powered."""

    def __init__(self, path: str, baud: int = LINK_BAUD):
        try:
            self.port = serial.Serial(path, baud, timeout=0, write_timeout=1.0)
        except (serial.SerialException, OSError, ValueError) as err:
            reason = getattr(err, "strerror", None) or str(err).split(":")[-1].strip() or err
            raise FirmwareError(f"--controller {path}: cannot open the controller's port ({reason})") from None
        self.name = path
        self.fd = self.port.fileno()
        os.set_blocking(self.fd, False)

    def poll(self):
        return None

    def finish(self, timeout: float) -> str:
        return ""

    def close(self) -> None:
        self.port.close()
