"""What on this machine stands between servodyn and a port: the port missing, its permission,
another process holding it, the FTDI latency timer, real-time priority, each a hal.bringup.Finding
with its fix; and claiming a port servodyn has opened (ours alone, its latency timer at 1 ms).

    findings = port_findings("/dev/ttyUSB0") + realtime_findings(priority=80)
    claim_port(fd, "/dev/ttyUSB0")               # at open: ours alone, its latency timer at 1 ms

Every check reads a tree of /dev, /sys, /proc and /etc under `root` ("/" on a machine; the tests
build a stand-in one). The checks only read; lock_port and lower_latency act on a port servodyn has
opened, and nothing here runs sudo: a fix that needs it is printed as the exact line to run. The
ports themselves (which adapters, which links) are hal.ports.
"""

from __future__ import annotations

import array
import errno
import fcntl
import os
import stat
import termios
from pathlib import Path

from .bringup import WARNING, Finding
from .errors import ServoInitializationError
from .ports import ASYNC_LOW_LATENCY, CAP_SYS_NICE, Holder, LATENCY_UDEV_RULE, NO_ADAPTERS, REALTIME_FIX, ROOT, _read, _under, serial_ports


def _tty_name(path: str, root: Path) -> str:
    """ttyUSB0 for /dev/ttyUSB0 and for a /dev/serial/by-id link to it."""
    node = _under(root, path)
    return node.resolve().name if node.exists() else Path(path).name


def _system_path(path: str, root: Path) -> str:
    """The device's own path as the processes see it (/dev/ttyUSB0 for a by-id link to it)."""
    node = _under(root, path)
    if not node.exists():
        return str(path)
    top = Path(root).resolve()
    return "/" + str(node.resolve().relative_to(top)) if node.resolve().is_relative_to(top) else str(path)


def latency_file(path: str, root: Path = ROOT) -> Path:
    """The adapter's latency timer in sysfs (only an FTDI adapter, ftdi_sio, has one)."""
    return _under(root, f"sys/bus/usb-serial/devices/{_tty_name(path, root)}/latency_timer")


def latency_timer(path: str, root: Path = ROOT) -> int | None:
    """The adapter's latency timer in ms; None when it has none (not an FTDI adapter, a pseudo-terminal)."""
    text = _read(latency_file(path, root))
    return int(text) if text and text.isdigit() else None


def _command(proc: Path) -> str:
    raw = b""
    try:
        raw = (proc / "cmdline").read_bytes()
    except OSError:
        pass
    words = [w.decode(errors="replace") for w in raw.split(b"\0") if w]
    if not words:
        return _read(proc / "comm") or "?"
    text = " ".join([Path(words[0]).name, *words[1:]])
    return text if len(text) <= 60 else text[:57] + "..."


def holders(path: str, root: Path = ROOT, skip: tuple[int, int] | None = None) -> list[Holder]:
    """The processes that have the device open, from /proc/<pid>/fd (other users' processes only
    when this one may read them); `skip`: a (pid, fd) not to count, the descriptor being locked."""
    target = _system_path(path, root)
    found = []
    try:
        procs = [p for p in _under(root, "proc").iterdir() if p.name.isdigit()]
    except OSError:
        return []
    for proc in sorted(procs, key=lambda p: int(p.name)):
        pid = int(proc.name)
        try:
            fds = list((proc / "fd").iterdir())
        except OSError:
            continue                      # gone, or another user's
        for fd in fds:
            if skip is not None and (pid, fd.name) == (skip[0], str(skip[1])):
                continue
            try:
                if os.readlink(fd) == target:
                    command = _command(proc)
                    if Path(root) == ROOT and pid == os.getpid():
                        command += ", this process"
                    found.append(Holder(pid, command))
                    break
            except OSError:
                continue
    return found


# ---------------------------------------------------------------------------- what stands in the way

def _status_ids(root: Path) -> tuple[int, set[int]]:
    """This process's effective uid and its groups, from /proc/self/status."""
    text = _read(_under(root, "proc/self/status")) or ""
    fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
    try:
        uid = int(fields["Uid"].split()[1])
        groups = {int(g) for g in fields.get("Groups", "").split()} | {int(fields["Gid"].split()[1])}
    except (KeyError, IndexError, ValueError):
        uid, groups = os.geteuid(), set(os.getgroups()) | {os.getegid()}
    return uid, groups


def _entries(root: Path, name: str) -> list[list[str]]:
    text = _read(_under(root, f"etc/{name}")) or ""
    return [line.split(":") for line in text.splitlines() if line and not line.startswith("#")]


def _group(gid: int, root: Path) -> tuple[str, list[str]]:
    """A group's name and members (/etc/group)."""
    for entry in _entries(root, "group"):
        if len(entry) >= 4 and entry[2] == str(gid):
            return entry[0], [m for m in entry[3].split(",") if m]
    return str(gid), []


def _user(uid: int, root: Path) -> str | None:
    for entry in _entries(root, "passwd"):
        if len(entry) >= 3 and entry[2] == str(uid):
            return entry[0]
    return None


def _may_read_write(st: os.stat_result, uid: int, groups: set[int]) -> bool:
    if uid == 0:
        return True
    if st.st_uid == uid:
        return st.st_mode & 0o600 == 0o600
    if st.st_gid in groups:
        return st.st_mode & 0o060 == 0o060
    return st.st_mode & 0o006 == 0o006


def _permission(path: str, root: Path) -> Finding | None:
    """Whether this process may open the device for reading and writing; if not, the group to join."""
    node = _under(root, path)
    if Path(root) == ROOT and os.access(node, os.R_OK | os.W_OK):
        return None                       # an ACL (a desktop session's uaccess) counts too
    st = node.stat()
    uid, groups = _status_ids(root)
    if _may_read_write(st, uid, groups):
        return None
    group, members = _group(st.st_gid, root)
    found = f"{stat.filemode(st.st_mode)} group '{group}' (this user is not in it)"
    user = _user(uid, root)
    if st.st_mode & 0o060 != 0o060 or group == "root":
        port = next((p for p in serial_ports(root) if p.device == _system_path(path, root)), None)
        match = f'ATTRS{{idVendor}}=="{port.vid}", ATTRS{{idProduct}}=="{port.pid}", ' if port and port.vid else ""
        fix = (f"give it a group with a udev rule in /etc/udev/rules.d/99-servodyn.rules: SUBSYSTEM==\"tty\", "
               f"{match}GROUP=\"dialout\", MODE=\"0660\", then `sudo udevadm control --reload-rules && "
               "sudo udevadm trigger`, `sudo usermod -aG dialout $USER`, and log out and in")
    elif user and user in members:
        fix = f"'{user}' is in '{group}' already but this session began before: log out and in (or `newgrp {group}`)"
    else:
        fix = f"`sudo usermod -aG {group} $USER`, then log out and in"
    return Finding("permission", found=found, expected="read and write", fix=fix, bus=path)


def _holder_fix(others: list[Holder]) -> str:
    if any("ModemManager" in h.command for h in others):
        return ("ModemManager probes new serial ports: keep it off this one with a udev rule "
                "ENV{ID_MM_DEVICE_IGNORE}=\"1\" for the adapter, or `sudo systemctl stop ModemManager`")
    pids = " ".join(str(h.pid) for h in others)
    return (f"close it (Dynamixel Wizard: Disconnect) or `kill {pids}`: two programs on one bus "
            "garble each other's packets")


def _ports_here(root: Path) -> str:
    ports = serial_ports(root)
    if not ports:
        return NO_ADAPTERS
    named = ", ".join(p.device + (f" ({p.adapter.name})" if p.adapter else "") for p in ports)
    return f"serial ports here: {named}; `servodyn ports` lists them"


def latency_fix(path: str, root: Path = ROOT) -> str:
    """How to get the latency timer to 1 ms for good."""
    return (f"for every plug-in, the udev rule {LATENCY_UDEV_RULE} in /etc/udev/rules.d/99-ftdi-latency.rules "
            f"(now: `echo 1 | sudo tee /sys/bus/usb-serial/devices/{_tty_name(path, root)}/latency_timer`)")


def port_findings(path: str, root: Path = ROOT) -> list[Finding]:
    """What on the host keeps `path` from serving a real-time bus: the port missing (and the ports
    there are), permission, another process holding it, an FTDI latency timer above 1 ms. Reads only."""
    if not _under(root, path).exists():
        return [Finding("port", found=f"no {path}", expected="a serial port", fix=_ports_here(root), bus=path)]
    findings = []
    denied = _permission(path, root)
    if denied:
        findings.append(denied)
    others = [h for h in holders(path, root) if h.pid != os.getpid()]
    if others:
        findings.append(Finding("port in use", found="held by " + ", ".join(map(str, others)),
                                expected="no other process", fix=_holder_fix(others), bus=path))
    latency = latency_timer(path, root)
    if latency is not None and latency > 1:
        findings.append(Finding("latency timer", found=f"{latency} ms", expected="1 ms",
                                fix=f"servodyn asks it down to 1 ms at open (ASYNC_LOW_LATENCY); "
                                    + latency_fix(path, root), bus=path, severity=WARNING))
    return findings


def _rtprio(root: Path) -> tuple[int, int]:
    """RLIMIT_RTPRIO (soft, hard) from /proc/self/limits ("unlimited": 99, the highest priority)."""
    for line in (_read(_under(root, "proc/self/limits")) or "").splitlines():
        if line.startswith("Max realtime priority"):
            soft, hard = line.split()[3:5]
            return tuple(99 if v == "unlimited" else int(v) for v in (soft, hard))
    return 0, 0


def _capabilities(root: Path) -> int:
    for line in (_read(_under(root, "proc/self/status")) or "").splitlines():
        if line.startswith("CapEff:"):
            return int(line.split()[1], 16)
    return 0


def realtime_findings(root: Path = ROOT, priority: int = 1) -> list[Finding]:
    """Whether this process may take SCHED_FIFO at `priority` (the loop's: hal.realtime.LOOP_PRIORITY):
    CAP_SYS_NICE (root has it) or RLIMIT_RTPRIO at least that. Without it the loop runs at normal
    priority: a warning, with the fix."""
    soft, hard = _rtprio(root)
    if _capabilities(root) & (1 << CAP_SYS_NICE) or soft >= priority:
        return []
    fix = (f"`ulimit -r {hard}` in the shell that starts servodyn (the hard limit allows it)"
           if hard >= priority else REALTIME_FIX)
    return [Finding("real-time priority", found=f"SCHED_FIFO not allowed (RLIMIT_RTPRIO {soft}, no CAP_SYS_NICE)",
                    expected=f"RLIMIT_RTPRIO >= {priority} or CAP_SYS_NICE", fix=fix, severity=WARNING)]


def open_failure(path: str, reason: int | str, root: Path = ROOT) -> str:
    """The one line for a port that did not open: the OS's reason (an errno) and, where the host
    tells why, the fix (the ports there are, the group to join, the process holding it)."""
    text = os.strerror(reason) if isinstance(reason, int) else str(reason)
    line = f"{path}: cannot open ({text})"
    if reason == errno.ENOENT:
        return f"{line}; {_ports_here(root)}"
    try:
        findings = port_findings(path, root)
    except OSError:
        return line
    # the finding that explains this errno first (a busy port may also be one this user may not open)
    likely = {errno.EACCES: "permission", errno.EPERM: "permission", errno.EBUSY: "port in use"}.get(reason)
    for finding in sorted(findings, key=lambda f: f.check != likely):
        if finding.check in ("port", "permission", "port in use"):
            return f"{line}: {finding.found}; {finding.fix}"
    return line


# ---------------------------------------------------------------------------- at open, on a real port

def lock_port(fd: int, path: str, root: Path = ROOT) -> None:
    """The port ours alone: an exclusive advisory lock (pyserial's exclusive=True, flock LOCK_EX |
    LOCK_NB), and no other process with it open — dynamixel-sdk and Dynamixel Wizard take no lock,
    so the lock alone would not see them. ServoInitializationError in one line naming the holder."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as err:
        if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
            found = holders(path, root, skip=(os.getpid(), fd))
            who = ", ".join(map(str, found)) or f"a process this user cannot see (`sudo fuser -v {path}` names it)"
            raise ServoInitializationError(f"{path}: in use, locked by {who}; "
                                           f"{_holder_fix(found) if found else 'close it and open again'}") from None
        # any other refusal: a device that takes no lock; who else has it open is still looked for
    others = [h for h in holders(path, root) if h.pid != os.getpid()]
    if others:
        fcntl.flock(fd, fcntl.LOCK_UN)
        raise ServoInitializationError(f"{path}: in use, held by {', '.join(map(str, others))}; "
                                       f"{_holder_fix(others)}")


def lower_latency(fd: int, path: str, root: Path = ROOT) -> tuple[int | None, int | None]:
    """The adapter's latency timer (ms) before and after asking it down to 1 ms: the TIOCSSERIAL
    ASYNC_LOW_LATENCY flag (pyserial's set_low_latency_mode; ftdi_sio then uses 1 ms), then, if it
    is still above, 1 written to the sysfs file where this process may. (None, None): the port has
    no latency timer (not an FTDI adapter)."""
    file = latency_file(path, root)
    before = latency_timer(path, root)
    if before is None or before <= 1:
        return before, before
    try:
        serial = array.array("i", [0] * 32)          # struct serial_struct; flags is its fifth int
        fcntl.ioctl(fd, termios.TIOCGSERIAL, serial)
        serial[4] |= ASYNC_LOW_LATENCY
        fcntl.ioctl(fd, termios.TIOCSSERIAL, serial)
    except (OSError, AttributeError):
        pass
    after = latency_timer(path, root)
    if after is not None and after > 1:
        try:
            file.write_text("1\n")
        except OSError:
            pass
        after = latency_timer(path, root)
    return before, after


def claim_port(fd: int, path: str, realtime: bool = True, root: Path = ROOT) -> tuple[int | None, int | None]:
    """At open, on a real adapter: lock it (lock_port) and ask its latency timer down (lower_latency).
    `realtime`: the bus carries a real-time loop, so a timer that stays above 1 ms is refused
    (ServoInitializationError with its fix): every read would wait for it. Returns (before, after)."""
    lock_port(fd, path, root)
    before, after = lower_latency(fd, path, root)
    if realtime and after is not None and after > 1:
        raise ServoInitializationError(
            f"{path}: latency timer at {after} ms and servodyn may not lower it (expected 1 ms: every read "
            f"waits for it and a 1 ms loop overruns); {latency_fix(path, root)}")
    return before, after
