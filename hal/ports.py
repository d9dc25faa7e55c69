"""The ports of this machine and of a configuration: the serial adapters and SocketCAN links this
machine has (read from a tree of /dev, /sys and /proc under `root`: "/" on a machine, a stand-in in
the tests), and which port each bus of a configuration is driven on (`bus_ports`, the `--port
BUS=PATH` mapping). What stands in a port's way (permissions, holders, the latency timer) is
hal.port_access.

    for port in serial_ports():                  # /dev/ttyUSB0, 0403:6014, U2D2, ...
        print(port.device, port.vid_pid, port.adapter and port.adapter.name)
    bus_ports(config, ["arm=/dev/ttyUSB0", "can=can0"])     # {"arm": "/dev/ttyUSB0", "can": "can0"}
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from dataclasses import asdict, dataclass
from pathlib import Path

from .errors import ConfigError

ROOT = Path("/")


@dataclass(frozen=True)
class Adapter:
    """A USB adapter servodyn recognises by its VID:PID."""
    name: str
    bus: str                 # what it carries: "dynamixel" (a serial port) or "can"
    note: str = ""           # what else has the same id, or how it shows up


# The one table of USB adapters, by (VID, PID) as sysfs spells them. Each id checked where its maker
# sets it:
#   0403:6014  FTDI's id of the FT232H (Linux drivers/usb/serial/ftdi_sio_ids.h, FTDI_232H_PID), the
#              U2D2's chip: "U2D2 board" in Interbotix/interbotix_ros_core's 99-interbotix-udev.rules
#   2f5d:2202  ROBOTIS-GIT/OpenRB-150 boards.txt (vid.0, pid.0; usb_product "OpenRB-150"), the same id
#              in its bootloader (bootloaders/openrb-150/src/board_definitions_openrb150.h)
#   0483:5740  ROBOTIS-GIT/OpenCR 99-opencr-cdc.rules; it is ST's virtual COM port id
#   fff1:ff48  OpenCM9.04: the same OpenCR rules file, and Interbotix's ("OpenCM9.04C board")
#   1d50:606f  candle-usb/candleLight_fw include/config.h (USBD_VID, USBD_PID_FS), every board it builds
#   16d0:117e  normaldotcom/canable2-fw src/usbd_desc.c (USBD_VID, USBD_PID)
#   ad50:60c4  normaldotcom/canable-fw src/usbd_desc.c (USBD_VID, USBD_PID_FS)
ADAPTERS: dict[tuple[str, str], Adapter] = {
    ("0403", "6014"): Adapter("U2D2", "dynamixel", "FTDI FT232H: any FT232H adapter has this id"),
    ("2f5d", "2202"): Adapter("OpenRB-150", "dynamixel"),
    ("0483", "5740"): Adapter("OpenCR", "dynamixel", "ST's virtual COM port: other STM32 boards have this id"),
    ("fff1", "ff48"): Adapter("OpenCM9.04", "dynamixel"),
    ("1d50", "606f"): Adapter("candleLight (gs_usb)", "can", "candleLight firmware, e.g. on a CANable: "
                                                            "a SocketCAN link (can0), no tty"),
    ("16d0", "117e"): Adapter("CANable 2.0 (slcan)", "can", "slcan firmware: a tty python-can's slcan opens"),
    ("ad50", "60c4"): Adapter("CANable 1.0 (slcan)", "can", "slcan firmware: a tty python-can's slcan opens"),
}

CAN_LINK_TYPE = 280              # ARPHRD_CAN (linux/if_arp.h): /sys/class/net/<link>/type of a CAN link
ASYNC_LOW_LATENCY = 1 << 13      # linux/tty_flags.h: ftdi_sio then uses a 1 ms latency timer
CAP_SYS_NICE = 23                # linux/capability.h: may raise scheduling priority (SCHED_FIFO)
# the udev rule that sets every FTDI adapter's latency timer to 1 ms when it is plugged in (the notes)
LATENCY_UDEV_RULE = 'ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{latency_timer}="1"'
NO_ADAPTERS = ("no adapters found: check the cable (and the adapter's power), `dmesg | tail` right after "
               "plugging it in, and its driver (`lsmod | grep -e ftdi_sio -e cdc_acm -e gs_usb`)")
# how to allow SCHED_FIFO for a user (hal.realtime says it when the policy is refused)
REALTIME_FIX = ("add `@realtime - rtprio 99` to /etc/security/limits.conf and this user to that group "
                "(`sudo groupadd -f realtime; sudo usermod -aG realtime $USER`), then log out and in "
                "(a container: --cap-add=SYS_NICE)")


def is_pseudo_terminal(path: str) -> bool:
    """True for a pseudo-terminal (what `servodyn sim` serves); a USB serial or SLCAN adapter is a
    tty of its own (/dev/ttyUSB*, /dev/ttyACM*), a SocketCAN channel no device file at all."""
    return os.path.realpath(path).startswith("/dev/pts/")


# ---------------------------------------------------------------------------- what the host has

@dataclass(frozen=True)
class SerialPort:
    """A USB serial adapter: its device, stable name and what its USB descriptor says."""
    device: str                   # /dev/ttyUSB0
    by_id: str | None             # /dev/serial/by-id/usb-..., when a link there points to it
    vid: str | None
    pid: str | None
    manufacturer: str | None
    product: str | None
    serial: str | None
    driver: str | None            # ftdi_sio, cdc_acm, ...
    adapter: Adapter | None       # recognised by VID:PID (ADAPTERS), else None

    @property
    def vid_pid(self) -> str | None:
        return f"{self.vid}:{self.pid}" if self.vid and self.pid else None

    def as_json(self) -> dict:
        found = asdict(self)
        found["adapter"] = self.adapter.name if self.adapter else None
        found["vid_pid"] = self.vid_pid
        return found


@dataclass(frozen=True)
class CanLink:
    """A SocketCAN link: its state and, where `ip` tells it, its bit rate and controller state."""
    name: str
    operstate: str | None         # up, down, unknown (a vcan link)
    bitrate: int | None
    state: str | None             # the controller's: ERROR-ACTIVE, ERROR-PASSIVE, BUS-OFF, STOPPED
    driver: str | None            # gs_usb, peak_usb, vcan, ...
    vid_pid: str | None
    adapter: Adapter | None

    def as_json(self) -> dict:
        found = asdict(self)
        found["adapter"] = self.adapter.name if self.adapter else None
        return found


@dataclass(frozen=True)
class Holder:
    """A process that has a device open."""
    pid: int
    command: str

    def __str__(self) -> str:
        return f"pid {self.pid} ({self.command})"


def _under(root: Path, path) -> Path:
    return Path(root) / str(path).lstrip("/")


def _read(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except (OSError, UnicodeDecodeError):
        return None


def _natural(path: Path):
    """ttyUSB2 before ttyUSB10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _usb_device(start: Path, root: Path) -> Path | None:
    """The USB device above a sysfs device directory: the first one up with an idVendor file."""
    top = _under(root, "sys").resolve()
    here = start.resolve()
    while here != top and top in here.parents:
        if (here / "idVendor").is_file():
            return here
        here = here.parent
    return None


def _driver(device: Path) -> str | None:
    link = device / "driver"
    return link.resolve().name if link.exists() else None


def _recognised(vid: str | None, pid: str | None) -> Adapter | None:
    return ADAPTERS.get(((vid or "").lower(), (pid or "").lower()))


def _by_id(root: Path) -> dict[Path, str]:
    """The devices /dev/serial/by-id's links point to, each with its link's name."""
    folder = _under(root, "dev/serial/by-id")
    try:
        links = sorted(folder.iterdir())
    except OSError:
        return {}
    return {link.resolve(): f"/dev/serial/by-id/{link.name}" for link in links}


def serial_ports(root: Path = ROOT) -> list[SerialPort]:
    """Every USB serial adapter (a tty with a USB device above it in sysfs), in name order."""
    named = _by_id(root)
    found = []
    try:
        ttys = sorted(_under(root, "sys/class/tty").iterdir(), key=_natural)
    except OSError:
        return []
    for tty in ttys:
        device = tty / "device"
        if not device.exists():
            continue                      # a virtual terminal or a pseudo-terminal
        usb = _usb_device(device, root)
        if usb is None:
            continue                      # a built-in UART (ttyS*), not an adapter
        vid, pid = _read(usb / "idVendor"), _read(usb / "idProduct")
        node = _under(root, f"dev/{tty.name}")
        found.append(SerialPort(
            device=f"/dev/{tty.name}", by_id=named.get(node.resolve()) if node.exists() else None,
            vid=vid, pid=pid, manufacturer=_read(usb / "manufacturer"), product=_read(usb / "product"),
            serial=_read(usb / "serial"), driver=_driver(device), adapter=_recognised(vid, pid)))
    return found


def _ip_can_details(text: str) -> dict[str, dict]:
    """From `ip -details -json link show`: each CAN link's bit rate, controller state and restart-ms."""
    try:
        links = json.loads(text)
    except ValueError:
        return {}
    details = {}
    for link in links if isinstance(links, list) else []:
        kind = link.get("linkinfo") or {}
        info = kind.get("info_data") or {}
        if kind.get("info_kind") == "can" and isinstance(info, dict) and link.get("ifname"):
            details[link["ifname"]] = {"bitrate": (info.get("bittiming") or {}).get("bitrate"),
                                       "state": info.get("state"), "restart_ms": info.get("restart_ms")}
    return details


def _ip_details(root: Path) -> dict[str, dict]:
    """`ip -details -json link show` on this machine (never on a stand-in tree); {} without ip."""
    if Path(root) != ROOT or shutil.which("ip") is None:
        return {}
    try:
        done = subprocess.run(["ip", "-details", "-json", "link", "show"], capture_output=True, text=True,
                              timeout=5)
    except (OSError, subprocess.SubprocessError):
        return {}
    return _ip_can_details(done.stdout) if done.returncode == 0 else {}


def can_links(root: Path = ROOT) -> list[CanLink]:
    """Every SocketCAN link (a network link of type 280), in name order; the bit rate when `ip` gives it."""
    try:
        links = sorted(_under(root, "sys/class/net").iterdir(), key=_natural)
    except OSError:
        return []
    links = [link for link in links if _read(link / "type") == str(CAN_LINK_TYPE)]
    details = _ip_details(root) if links else {}
    found = []
    for link in links:
        device = link / "device"
        usb = _usb_device(device, root) if device.exists() else None
        vid, pid = (_read(usb / "idVendor"), _read(usb / "idProduct")) if usb else (None, None)
        info = details.get(link.name, {})
        bitrate = info.get("bitrate") or _read(link / "can_bittiming" / "bitrate")   # a driver's own, rarely
        found.append(CanLink(name=link.name, operstate=_read(link / "operstate"),
                             bitrate=int(bitrate) if str(bitrate or "").isdigit() else None,
                             state=info.get("state"),
                             driver=_driver(device) if device.exists() else _read(link / "kind"),
                             vid_pid=f"{vid}:{pid}" if vid and pid else None, adapter=_recognised(vid, pid)))
    return found


# s to wait for replies from a bus on a pseudo-terminal (a simulated bus, `servodyn sim`), per bus
# kind: a pseudo-terminal under CPU load can hold bytes back for over 100 ms (measured here), far
# beyond a real bus's deadline (Dynamixel 34 ms packet timeout, CAN 20 ms). Dynamixel: the
# simulator's own process; on a machine loaded 4x over its cores a reply was seen to wait over
# 250 ms. CAN: the motors' server is a thread of the loop's process, and on a loaded 2-core machine
# a read waited 0.46 s once in 6000 ticks (measured).
PTY_REPLY_TIMEOUT = {"dynamixel": 1.0, "can": 2.0, "feetech": 1.0}


def bus_ports(config, port=None) -> dict[str, str]:
    """The port of each bus of `config` (a RobotConfig) driven on hardware, {} when every bus is
    simulated. `port`: None (each bus's configured port; "auto" means simulated), a path (a one-bus
    configuration), or a list of "BUS=PATH" items naming each bus of a configuration with several.
    Either every bus has a port or none has: ConfigError naming what is missing or unknown."""
    given = {}
    for item in [] if port is None else [port] if isinstance(port, str) else port:
        if "=" in item and item.split("=", 1)[0] in config.buses:
            name, path = item.split("=", 1)
        elif len(config.buses) == 1:
            name, path = next(iter(config.buses)), item
        else:
            raise ConfigError(f"'{config.name}' has {len(config.buses)} buses ({', '.join(config.buses)}): give "
                              f"each its port as --port BUS=PATH, not {item!r}")
        if not path or name in given:
            raise ConfigError(f"--port {name}=...: {'an empty path' if not path else 'given twice'}")
        given[name] = path
    ports = {name: given.get(name) or (bus.port if bus.port != "auto" else None)
             for name, bus in config.buses.items()}
    missing = [name for name, path in ports.items() if path is None]
    if len(missing) == len(ports):
        return {}
    if missing:
        raise ConfigError(f"bus '{missing[0]}' of '{config.name}' has no port while "
                          f"{', '.join(repr(n) for n in ports if n not in missing)} has one: give it as --port "
                          f"{missing[0]}=PATH (all buses real, or all simulated)")
    return ports
