"""The firmware under QEMU as a controller: the emulator's command line, its serial sockets, and the
simulated Dynamixel bus served on them (used by `swing --controller qemu:BOARD`, servodyn.hil and the soak).

QEMU runs the firmware image with its UART on a TCP socket
(`-serial tcp:127.0.0.1:PORT,server=on,wait=on,nodelay=on`); this side connects and serves the
simulated Dynamixel bus of the robot configuration on it, the same bus `servodyn sim` puts on a
pseudo-terminal. Lock-step: the plant advances one control period whenever the firmware ends a
command transaction (its sync write), so the run is deterministic and faster than real time.
`-icount shift=N,sleep=off` makes the emulated clock count instructions (2^N ns each), so the
firmware's SysTick figures are instruction counts: exact and repeatable (not cycles).

The emulated clock must not run while this side is slow to answer, or a reply late in wall time
(a loaded machine) reads as a silent servo: the images are hardware-in-the-loop builds whose second
UART (MPS2 UART1, STM32F405 USART2) is a sync line (a second `-serial` socket). After each chunk read from the firmware that ends a
packet or is answered, this side sends on it the bytes read and the bytes sent so far (two
little-endian uint32); the firmware sleeps in WFI, executing nothing and with no timer to jump to,
until its reply is there or these counts say that nothing more is coming, and only then counts its
reply timeout (firmware/mcu/board_io.c). A silent servo still times out; a slow host never does.

Every exchange is recorded: what the servos reported and what the firmware commanded. `replay`
recomputes each command with the host's double-precision controller from the same measured state
(`compare` asserts they agree within one servo unit), and the tracking error of the run.
"""

from __future__ import annotations

import shutil
import socket
import struct
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..hal.dynamixel import Instruction, PacketError, decode_frame, split_fast_reply
from ..hal.dynamixel.control_table import ADDR_GOAL_CURRENT, ADDR_TORQUE_ENABLE, PRESENT_LENGTH
from ..hal.dynamixel.instructions import parse_sync_write
from .native import FirmwareError

BOARDS = {"an386": ("mps2-an386", "Cortex-M4F"), "an500": ("mps2-an500", "Cortex-M7"),
          "f405": ("netduinoplus2", "STM32F405 Cortex-M4F")}
ROOT = Path(__file__).resolve().parents[2]
# the processor clock SysTick counts: the MPS2's 25 MHz; the F405's 168 MHz (QEMU's is fixed there)
SYSTICK_HZ = {"an386": 25e6, "an500": 25e6, "f405": 168e6}


@dataclass
class Record:
    """What crossed the bus: each fast sync read's reply (current, velocity, position register
    values per servo, in joint order) and each Goal Current sync write (per servo)."""
    reads: list = field(default_factory=list)
    goals: list = field(default_factory=list)
    torque_off: bool = False


def default_elf(board: str) -> Path:
    return ROOT / "build" / "fw" / board / "servodyn-fw.elf"


class FirmwareLink:
    """A simulated robot's Dynamixel bus (SimulatedRobot.port) served on a socket, lock-stepped to the firmware's command transactions.
    Fault injection: on_tick(k, arm) runs after the k-th Goal Current write has moved the plant
    (what it does to the servos shows in the next read); tamper(reply) may change reply bytes."""

    def __init__(self, arm, on_tick=None, tamper=None):
        self.arm, self.on_tick, self.tamper = arm, on_tick, tamper
        self.ids = [s.id for s in arm.servos]
        self.record = Record()
        self.packets = 0                       # instruction packets heard (the sync line's cue)
        arm.lockstep()                         # each sync write moves the plant one period
        arm.bus.on_instruction = self._exchange

    def _exchange(self, exchange) -> None:
        self.packets += 1
        request = exchange.request
        if request.instruction == Instruction.FAST_SYNC_READ and exchange.replies:
            try:
                blocks = split_fast_reply(decode_frame(exchange.replies[0].data), [PRESENT_LENGTH] * len(self.ids))
            except PacketError:           # cut short by a silent servo: the firmware gets no state
                return
            self.record.reads.append(np.array(
                [[int.from_bytes(b.data[0:2], "little", signed=True),
                  int.from_bytes(b.data[2:6], "little", signed=True),
                  int.from_bytes(b.data[6:10], "little", signed=True)] for b in blocks]))
        elif request.instruction == Instruction.SYNC_WRITE:
            address, writes = parse_sync_write(request.params)
            if address == ADDR_GOAL_CURRENT:
                values = dict((i, int.from_bytes(d, "little", signed=True)) for i, d in writes)
                self.record.goals.append(np.array([values[i] for i in self.ids]))
            elif address == ADDR_TORQUE_ENABLE and all(d == b"\x00" for _, d in writes):
                self.record.torque_off = True
            if address == ADDR_GOAL_CURRENT and self.on_tick is not None:
                self.on_tick(len(self.record.goals) - 1, self.arm)

    def serve(self, sock: socket.socket, deadline: float, sync: socket.socket | None = None) -> None:
        """Answer the firmware on `sock` until it closes. With `sync` (the firmware's sync line, a
        hardware-in-the-loop build's UART1): after each chunk that ended a packet or was answered, the
        counts of bytes read and sent so far (not after a packet's first bytes: QEMU passes the
        firmware's bytes on as they are written, and a record for each would flood the line)."""
        read = sent = 0
        while time.monotonic() < deadline:
            try:
                data = sock.recv(4096)
            except socket.timeout:
                continue
            except ConnectionResetError:       # QEMU exited while its last bytes were in flight
                return
            if not data:
                return
            read += len(data)
            packets = self.packets
            reply = self.arm.handle(data)
            if reply and self.tamper is not None:
                reply = self.tamper(reply)
            if reply:
                sock.sendall(reply)
                sent += len(reply)
            if sync is not None and (reply or self.packets != packets):
                try:
                    sync.sendall(struct.pack("<II", read & 0xFFFFFFFF, sent & 0xFFFFFFFF))
                except (BrokenPipeError, ConnectionResetError):     # QEMU has exited
                    return
        raise FirmwareError("the firmware run took too long (time-out)")


def free_ports(n: int) -> list[int]:
    """n distinct free ports (held together while asked for, so no two are the same)."""
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def qemu_command(board: str, elf: Path, port: int, icount_shift: int, args: str = "",
                 sync_port: int | None = None, extra: tuple = ()) -> list[str]:
    """QEMU's command line: the bus UART (MPS2 UART0, F405 USART1: -serial #0) on `port`, the sync
    line (MPS2 UART1, F405 USART2: -serial #1) on `sync_port`. sleep=off: an idle core does not
    let the emulated clock run in wall time (the images spin rather than WFI between ticks for it:
    docs/boards.md). `extra`: more options (e.g. -d unimp -D FILE: the unmodelled devices' register
    writes, the F405's pin and clock set-up, tests/test_f405.py)."""
    machine, _ = BOARDS[board]
    semihosting = "enable=on,target=native,arg=servodyn-fw" + "".join(f",arg={a}" for a in args.split())
    serial = ["-serial", f"tcp:127.0.0.1:{port},server=on,wait=on,nodelay=on"]
    if sync_port is not None:
        serial += ["-serial", f"tcp:127.0.0.1:{sync_port},server=on,wait=on,nodelay=on"]
    return ["qemu-system-arm", "-M", machine, "-display", "none", "-monitor", "none",
            "-icount", f"shift={icount_shift},sleep=off", "-semihosting-config", semihosting,
            *serial, *extra, "-kernel", str(elf)]


def connect(proc: subprocess.Popen, port: int, deadline: float) -> socket.socket:
    """A connection to one of QEMU's serial sockets, once it listens."""
    while True:
        try:
            sock = socket.create_connection(("127.0.0.1", port), timeout=1.0)
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise FirmwareError(f"QEMU did not open its serial port: {proc.stderr.read().strip()}") from None
            time.sleep(0.05)
            continue
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(1.0)
        return sock


def check_arm_elf(elf: Path) -> None:
    """FirmwareError unless `elf` is a 32-bit little-endian ARM executable: QEMU given anything
    else starts, faults and prints its registers instead of an error."""
    try:
        with open(elf, "rb") as f:
            header = f.read(20)
    except OSError as err:
        raise FirmwareError(f"{elf}: cannot read ({err.strerror or err})") from None
    if header[:4] != b"\x7fELF":
        raise FirmwareError(f"{elf}: not an ELF file (build the firmware with `make fw`)")
    # e_ident: class 1 = 32-bit, data 1 = little-endian; e_machine 40 = ARM
    if header[4] != 1 or header[5] != 1 or int.from_bytes(header[18:20], "little") != 40:
        raise FirmwareError(f"{elf}: an ELF file, but not a 32-bit little-endian ARM image "
                            "(build the firmware with `make fw`)")


def image(board: str, elf=None) -> Path:
    """The firmware image to run on `board`, checked: FirmwareError for an unknown board, no
    image, or a file that is no 32-bit ARM executable."""
    if board not in BOARDS:
        raise FirmwareError(f"unknown board '{board}' (one of {', '.join(BOARDS)})")
    elf = Path(elf) if elf else default_elf(board)
    if not elf.is_file():
        raise FirmwareError(f"no firmware image at {elf} (build it with `make fw`)")
    check_arm_elf(elf)
    return elf


QEMU_ICOUNT_SHIFT = 3      # a controller under QEMU: 2^3 ns an instruction, 125 MIPS, a fast Cortex-M4


def link_image(board: str) -> Path:
    """The general application's image for `board` (build/fw/BOARD-link, `make fw`), checked."""
    return image(board, ROOT / "build" / "fw" / f"{board}-link" / "servodyn-fw-link.elf")


class QemuController:
    """The general application's image (firmware/app/fw_link.c) running under QEMU, lock-stepped to a
    simulated arm served on its bus UART (FirmwareLink, every exchange recorded in `record`); the
    host link on `-serial #2`, a socket whose descriptor is `fd`. args: the image's semihosting
    arguments (once=1 baud=N are added)."""

    def __init__(self, board: str, arm, baud: int, icount_shift: int = QEMU_ICOUNT_SHIFT, args: str = "",
                 timeout: float = 600.0, on_tick=None, elf=None):
        elf = image(board, elf) if elf else link_image(board)
        if shutil.which("qemu-system-arm") is None:
            raise FirmwareError("qemu-system-arm not found (`make toolchain` installs it)")
        self.name = f"qemu:{board}"
        self.bus = FirmwareLink(arm, on_tick=on_tick)
        self.record = self.bus.record
        self.deadline = time.monotonic() + timeout
        port, sync_port, link_port = free_ports(3)
        extra = ("-serial", f"tcp:127.0.0.1:{link_port},server=on,wait=on,nodelay=on")
        self.proc = subprocess.Popen(qemu_command(board, elf, port, icount_shift, f"once=1 baud={baud} {args}",
                                                  sync_port, extra),
                                     stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.sockets = []
        try:
            for p in (port, sync_port, link_port):
                self.sockets.append(connect(self.proc, p, self.deadline))
        except BaseException:
            self.close()
            raise
        sock, sync, host = self.sockets
        self.serving = threading.Thread(target=self.bus.serve, args=(sock, self.deadline, sync), daemon=True)
        self.serving.start()
        host.setblocking(False)
        self.fd = host.fileno()
        self.output = ""

    def poll(self):
        """None while the image runs, else QEMU's exit status."""
        return self.proc.poll()

    def finish(self, timeout: float) -> str:
        """Wait for the image's end (it ends at torque off); its output (the report lines)."""
        self.serving.join(max(1.0, min(timeout, self.deadline - time.monotonic())))
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise FirmwareError("QEMU did not exit after the firmware's run") from None
        self.output = out + "\n" + err          # semihosting writes to QEMU's stderr
        return self.output

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for s in self.sockets:
            s.close()


def to_instructions(counts: float, board: str, icount_shift: int) -> float:
    """SysTick clock counts under `-icount shift=N` as instructions (2^N ns each): exact, not cycles."""
    return counts * 1e9 / SYSTICK_HZ[board] / 2.0 ** icount_shift
