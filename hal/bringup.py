"""Bring-up on every kind of bus: what it finds (`Found`, a device a scan found; `Finding`, what a
check found wrong, with its fix) and `BringUp`, the one interface the commands (servodyn.tools.bringup)
drive a bus through, whatever its kind. Each backend describes its own (`Backend.bringup`, "module:class",
imported on first use as python-can finds its interfaces): hal.dynamixel.session, hal.can.session,
hal.feetech.session.
The host's side (ports, permissions, the latency timer, locks) is hal.ports and hal.port_access.

    Finding("firmware", found=44, expected=">= 45", joint="r_elbow_flexion", id=4,
            fix="update the firmware with Dynamixel Wizard 2.0 (Tools > Firmware Update)")
    with bringup_class(config.buses["arm"].kind)(config, "arm", "/dev/ttyUSB0") as session:
        findings = session.doctor()

`BringUp` refuses a path that is a terminal before anything is sent (`not_a_bus`), puts the port's
termios settings back when it closes, and turns a port lost under an operation into one line naming
the port (`PortLost`).
"""

from __future__ import annotations

import importlib
import os
import stat
import termios
from abc import ABC, abstractmethod
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from .backend import BACKENDS, backend
from .bus import port_gone
from .config import load_config
from .errors import ConfigError, HalError, ServoInitializationError, ServoOperationError
from .ports import ROOT, _under, bus_ports, is_pseudo_terminal

ERROR, WARNING = "error", "warning"


@dataclass(frozen=True)
class Finding:
    """One thing a check found wrong, in one line with its fix. `severity` "error": a run refuses to
    start on it (doctor exits 1); "warning": it runs, but the user should know."""
    check: str                    # short name: "permission", "latency timer", "firmware", "drive mode", ...
    found: Any
    expected: Any
    fix: str                      # what to do, as exact as a command line where there is one
    joint: str | None = None      # the configuration's dof, when the finding is a joint's
    id: int | None = None         # the servo's or motor's id on its bus
    bus: str | None = None        # the configuration's bus name, or the port
    severity: str = ERROR

    def line(self) -> str:
        """One line: where, what was found against what is expected, and the fix."""
        where = []
        if self.bus:
            where.append(f"bus '{self.bus}'")
        if self.joint:
            where.append(f"joint '{self.joint}'")
        if self.id is not None:
            where.append(f"id {self.id}")
        head = (" ".join(where) + ": ") if where else ""
        return f"{head}{self.check}: found {self.found}, expected {self.expected}; {self.fix}"

    def as_json(self) -> dict:
        """doctor --json's object: joint, id, check, found, expected, fix (and bus, severity)."""
        return {k: (v if isinstance(v, (int, float, str, bool, type(None))) else str(v))
                for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Found:
    """One device a scan found: its id on the bus, model, firmware and the rate it answered at.
    `extra`: what the kind adds (a Damiao motor's Master ID, a CAN motor's status)."""
    id: int
    model_number: int | None
    model: str | None             # the catalogue's name, or None when the number is not in it
    firmware: int | None
    baud: int                     # the rate it answered at (serial baud or CAN bit rate)
    kind: str = "dynamixel"
    extra: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        """scan --json's object: id, model_number, model, firmware, baud (and kind, extra)."""
        return {"id": self.id, "model_number": self.model_number, "model": self.model,
                "firmware": self.firmware, "baud": self.baud, "kind": self.kind, **self.extra}


# ---------------------------------------------------------------------------- errors

class BadRequest(HalError, ValueError):
    """Bring-up asked what cannot be done as asked: a rate a bus kind does not have, a bus kind
    without a bring-up, a refresh rate out of range, input that ended before the last step."""


class PortLost(ServoOperationError):
    """The port went away under a bring-up operation (unplugged, or its simulator ended): one line
    naming it."""

    def __init__(self, path: str, reason: str):
        self.path, self.reason = path, reason
        super().__init__(f"{path}: the port was lost ({reason}): check its cable and power, then "
                         "`servodyn ports`")


def _gone(err: BaseException) -> str | None:
    """Why the port is gone, if `err` or an error in its chain says so (hal.bus.port_gone)."""
    seen, todo = set(), [err]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        seen.add(id(e))
        reason = port_gone(e)
        if reason:
            return reason
        todo += [e.__cause__, e.__context__]
    return None


# ---------------------------------------------------------------------------- terminals

def _controlling(rdev: int, root: Path = ROOT) -> str | None:
    """The first process whose controlling terminal is the device `rdev`, "pid N (command)"."""
    try:
        procs = [p for p in _under(root, "proc").iterdir() if p.name.isdigit()]
    except OSError:
        return None
    for proc in sorted(procs, key=lambda p: int(p.name)):
        try:
            text = (proc / "stat").read_text()
        except OSError:
            continue
        head, _, tail = text.rpartition(")")
        fields = tail.split()
        if len(fields) < 5 or not fields[4].lstrip("-").isdigit():
            continue
        nr = int(fields[4])             # tty_nr: major in bits 8-15, minor in 0-7 and 20-31
        if nr and os.makedev((nr >> 8) & 0xFFF, (nr & 0xFF) | ((nr >> 12) & 0xFFF00)) == rdev:
            return f"pid {proc.name} ({head.partition('(')[2]})"
    return None


def not_a_bus(path: str, root: Path = ROOT) -> str | None:
    """Why `path` must not be opened as a bus (a terminal someone types in), or None. Allowed: a
    tty with a device under it in sysfs (a USB adapter, a UART) and a pseudo-terminal that is no
    process's controlling terminal (what `servodyn sim` serves: a terminal emulator's or ssh's is
    its shell's). Refused: the controlling terminal (/dev/tty), the console, a virtual terminal,
    a pseudo-terminal a shell runs on, and any other character device (/dev/null). A path that
    is not a device is left to the open, which says what it is."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    if not stat.S_ISCHR(st.st_mode):
        return None
    fix = "give the adapter's path (`servodyn ports` lists them)"
    if is_pseudo_terminal(path) and os.path.basename(os.path.realpath(path)).isdigit():
        holder = _controlling(st.st_rdev, root)
        if holder is None:
            return None
        return (f"{path} is the terminal of {holder}, not a simulated bus (`servodyn sim` prints its own): "
                f"nothing sent; {fix}")
    node = _under(root, f"sys/dev/char/{os.major(st.st_rdev)}:{os.minor(st.st_rdev)}")
    if (node / "subsystem").resolve().name != "tty":
        return f"{path} is not a serial port: nothing sent; {fix}"
    if (node / "device").exists():
        return None
    name = node.resolve().name
    what = {"tty": "the controlling terminal (this terminal)", "console": "the system console",
            "ptmx": "the pseudo-terminal multiplexer"}.get(name, f"a virtual terminal ({name})")
    return f"{path} is {what}, not a serial adapter: nothing sent; {fix}"


class _KeptTermios:
    """A tty's termios settings, read before the bus opens it and put back when it closes (the bus
    leaves it raw at its own rate otherwise)."""

    def __init__(self, path: str):
        self.fd, self.saved = None, None
        if not path.startswith("/"):
            return                            # a SocketCAN link: no file
        try:
            fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return                            # the bus's own open says why
        try:
            self.saved, self.fd = termios.tcgetattr(fd), fd
        except termios.error:
            os.close(fd)

    def restore(self) -> None:
        if self.fd is None:
            return
        try:
            termios.tcsetattr(self.fd, termios.TCSANOW, self.saved)
        except (termios.error, OSError):
            pass                              # the port is gone: nothing to put back
        finally:
            os.close(self.fd)
            self.fd = None


# ---------------------------------------------------------------------------- the interface

@dataclass
class Scan:
    """What a scan found: the devices, the lines a person reads (a table, collisions, frames heard,
    the count), and the kind's own result for `compare`."""
    found: list[Found]
    lines: list[str]
    result: Any = None


@dataclass(frozen=True)
class Outcome:
    """A recovery's result on one joint: whether it is as asked, in words."""
    joint: Any                    # hal.config.JointConfig
    ok: bool
    text: str


@dataclass(frozen=True)
class MonitorRow:
    """A joint's state now: SI (q, qd at the joint) and as the device reports it (`raw`: position,
    velocity, effort), effort in its unit, temperature(s), voltage, error; q None: no answer."""
    joint: str
    id: int
    q: float | None = None
    qd: float | None = None
    raw: tuple[str, str, str] = ("-", "-", "-")
    effort: str = "-"
    temperature: str = "-"
    voltage: str = "-"
    error: str = "no answer"


class BringUp(ABC):
    """One bus of a configuration (or, `config` None, a bare port for a scan) opened for bring-up
    on `path`: a context manager. The public operations guard the port (a lost port is
    `PortLost`); a kind implements the `_` ones (as python-can's recv and _recv_internal)."""

    device = "device"             # what the kind calls the things on its bus: "servo", "motor"

    def __init__(self, config, bus: str | None, path: str):
        self.config, self.bus, self.path = config, bus, path
        self.joints = list(config.joints_on(bus)) if config is not None else []
        self._termios = None

    # --- what a kind implements
    @classmethod
    def claims(cls, path: str) -> bool:
        """Whether a port given without a configuration is a bus of this kind (scan --port PATH)."""
        return False

    @classmethod
    @abstractmethod
    def scan_rates(cls, text: str | None, spec=None) -> tuple[int, ...]:
        """--baud ("all" or None, or a comma list) as the rates a scan of this kind tries, for the
        bus `spec` (hal.config.BusConfig; None: a bare port); BadRequest in one line."""

    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    @abstractmethod
    def scanning(self, rates) -> str:
        """The line said before a scan: where, at which rates, what is sent."""

    @abstractmethod
    def _scan(self, rates) -> Scan: ...

    @abstractmethod
    def _compare(self, scan: Scan) -> list[Finding]: ...

    @abstractmethod
    def looking(self) -> str:
        """The line said before find_alone."""

    @abstractmethod
    def _find_alone(self, joint) -> tuple[Found, str]:
        """The one device on the bus, to be set up as `joint`, and a line describing it; one line's
        error otherwise."""

    @abstractmethod
    def _setup_plan(self, found: Found, joint) -> list:
        """The writes that make `found` the joint's device, each with .what and .line(); nothing sent
        but reads."""

    @abstractmethod
    def setup_intro(self, joint) -> str:
        """The line above the plan: where the writes go."""

    @abstractmethod
    def already(self, joint) -> str:
        """The line when the plan is empty."""

    @abstractmethod
    def _apply_setup(self, found: Found, joint, steps: list, written: list) -> list[str]:
        """The plan written (each step appended to `written` once the device took it); the lines of
        what was done."""

    def setup_lost(self, steps: list, written: list) -> str:
        """What a set-up stopped part way (the port lost, a write refused) left written, in words."""
        if not written:
            return "nothing of the set-up was written"
        left = [s.what for s in steps[len(written):]]
        return (f"written before it stopped: {', '.join(s.what for s in written)}"
                + (f"; not written: {', '.join(left)}" if left else ""))

    @abstractmethod
    def _doctor(self) -> list[Finding]: ...

    @abstractmethod
    def _torque_off(self) -> tuple[str, list[Outcome]]:
        """Torque off on every device of the bus: a line saying so, each joint's outcome."""

    @abstractmethod
    def _reboot(self) -> tuple[str, list[Outcome]]:
        """Each device restarted (or, a kind without a reboot, what it does instead, said in the line)."""

    @abstractmethod
    def _clear_errors(self) -> tuple[str, list[Outcome]]: ...

    @abstractmethod
    def _horn(self, joint) -> float:
        """The joint's horn (motor output) angle now, rad."""

    @abstractmethod
    def _monitor(self) -> list[MonitorRow]: ...

    def _calibration(self, joint, values: dict) -> tuple[dict, list]:
        """A calibration measured by hand (direction, zero_offset: the horn's angle at the zero pose,
        position_limits) as the device will hold it: the values the configuration then gets, and
        the writes to the device (each with .what and .line()) that make it so; nothing sent but
        reads. A kind that keeps no calibration in its devices: the values as they are, no write."""
        return values, []

    def _apply_calibration(self, joint, steps: list) -> str:
        """The calibration's writes made and checked; a line saying so."""
        raise BadRequest(f"a {type(self).__name__} keeps no calibration in its devices")

    # --- what the commands call
    def __enter__(self) -> "BringUp":
        refused = not_a_bus(self.path)
        if refused:
            raise ServoInitializationError(refused)
        self._termios = _KeptTermios(self.path)
        try:
            self._open()                      # a port that does not open says why itself
        except BaseException:
            self._termios.restore()
            raise
        return self

    def __exit__(self, kind, err, tb) -> None:
        try:
            with self._guard():
                self._close()
        except PortLost:
            if err is None:                    # lost after the last operation: still said
                raise
        except Exception:                      # noqa: BLE001 - the operations are done; a close that
            pass                               # fails (a driver's goodbye on a dying port) changes nothing
        finally:
            self._termios.restore()

    @contextmanager
    def _guard(self):
        try:
            yield
        except PortLost:
            raise
        except Exception as err:
            reason = _gone(err)
            if reason is None:
                raise
            raise PortLost(self.path, reason) from None

    def _guarded(name):
        def call(self, *args, **kwargs):
            with self._guard():
                return getattr(self, "_" + name)(*args, **kwargs)
        call.__name__ = name
        call.__doc__ = f"`_{name}` with the port guarded (a lost port: PortLost)."
        return call

    scan = _guarded("scan")
    compare = _guarded("compare")
    find_alone = _guarded("find_alone")
    setup_plan = _guarded("setup_plan")
    apply_setup = _guarded("apply_setup")
    doctor = _guarded("doctor")
    torque_off = _guarded("torque_off")
    reboot = _guarded("reboot")
    clear_errors = _guarded("clear_errors")
    horn = _guarded("horn")
    monitor = _guarded("monitor")
    calibration = _guarded("calibration")
    apply_calibration = _guarded("apply_calibration")
    del _guarded


def serial_rates(text: str | None, scan_order, known, family: str) -> tuple[int, ...]:
    """--baud on a serial bus: "all" or None (`scan_order`, every rate of `known`) or a comma list of
    rates, each one of `known` (a `family` rate); BadRequest in one line."""
    if text in (None, "all"):
        return tuple(scan_order)
    rates = []
    for part in text.split(","):
        try:
            rate = int(part.strip())
        except ValueError:
            raise BadRequest(f"--baud: {part!r} is not a rate (all, or some of {', '.join(map(str, known))})") from None
        if rate not in known:
            raise BadRequest(f"--baud: {rate} is not a {family} rate ({', '.join(map(str, known))})")
        rates.append(rate)
    return tuple(dict.fromkeys(rates))


def bringup_class(kind: str) -> type[BringUp]:
    """The bring-up of a bus kind (its Backend's `bringup`), imported on first use; BadRequest for
    a kind without one."""
    where = backend(kind).bringup
    if not where:
        having = [k for k in BACKENDS if backend(k).bringup]
        raise BadRequest(f"a {kind} bus has no bring-up (bring-up speaks to {', '.join(having)} buses)")
    module_name, class_name = where.split(":")
    try:
        return getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as err:
        raise ServoInitializationError(f"bus kind {kind!r}: cannot load its bring-up {where} ({err})") from err


def bringup_for_path(path: str) -> type[BringUp]:
    """The bring-up of the kind that claims a port given without a configuration."""
    for kind in BACKENDS:
        if backend(kind).bringup and bringup_class(kind).claims(path):
            return bringup_class(kind)
    raise BadRequest(f"{path}: no bus kind takes this port without a configuration: give --config FILE")


# ---------------------------------------------------------------------------- what the commands share

def config_and_ports(config_name: str, port) -> tuple:
    """The configuration (hal.config.RobotConfig) and the real port of each of its buses; one
    line (ConfigError) when a bus has none."""
    config = load_config(config_name)
    ports = bus_ports(config, port)
    if not ports:
        raise ConfigError(f"'{config.name}' names no real port (port = \"auto\" is the simulated bus): give "
                          "--port PATH (`servodyn ports` lists the adapters)")
    return config, ports


def session(config, bus: str, path: str) -> BringUp:
    """The bring-up of bus `bus` of `config` on `path`, not yet open."""
    return bringup_class(config.buses[bus].kind)(config, bus, path)


def open_limp(config, ports: dict, stack, then: str, say) -> dict:
    """Every bus opened (on `stack`, a contextlib.ExitStack, which closes them) and torque off on
    each, said first with what comes `then`: bus -> its open BringUp."""
    sessions = {}
    for bus, path in ports.items():
        sessions[bus] = stack.enter_context(session(config, bus, path))
        say(f"bus '{bus}' ({path}): torque off on every {sessions[bus].device} {then}".replace(" :", ":"))
        sessions[bus].torque_off()
    return sessions
