"""The host's side of bring-up (hal/ports.py, `servodyn ports`): adapters and CAN links read from sysfs,
and each thing on the host that stands between servodyn and a port — the port missing, permission,
another process holding it, the FTDI latency timer, real-time priority — as one line with its fix.
Everything runs on a stand-in tree of /dev, /sys, /proc and /etc built in tmp_path (as
test_realtime_cpu stands a file in for the sysfs CPU mask), so no test depends on the machine's
adapters; lock_port runs on a real pseudo-terminal."""

from __future__ import annotations

import errno
import json
import os
import pathlib
from pathlib import Path

import pytest

from servodyn.hal import port_access, ports
from servodyn.hal.bringup import ERROR, WARNING
from servodyn.hal.errors import ServoInitializationError
from servodyn.tools.cli import main

USB = "sys/devices/pci0000:00/0000:00:14.0/usb1"
BY_ID = "usb-FTDI_USB__-__Serial_Converter_FT6Z5XYZ-if00-port0"
UID = 4321                                         # the stand-in process's user: owns nothing here


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _link(at: Path, to: Path | str) -> None:
    """A symlink as sysfs and udev make them: relative (an absolute target as /proc's fd links)."""
    at.parent.mkdir(parents=True, exist_ok=True)
    at.symlink_to(to if isinstance(to, str) else os.path.relpath(to, at.parent))


def _usb(root: Path, port: str, vid: str, pid: str, **strings) -> Path:
    device = root / USB / port
    _write(device / "idVendor", vid + "\n")
    _write(device / "idProduct", pid + "\n")
    for name, text in strings.items():
        _write(device / name, text + "\n")
    return device


def stand_in(tmp_path: Path, *, latency: str | None = "16", holder: bool = True, member: bool = False,
             rtprio=(0, 0), caps: int = 0) -> Path:
    """/dev, /sys, /proc and /etc of a machine with a U2D2 on ttyUSB0 (FTDI, latency timer 16 ms, held
    by Dynamixel Wizard, a by-id link), an OpenRB-150 on ttyACM0 (cdc_acm), a built-in UART ttyS0, a
    candleLight on can0, a vcan0 and an eth0; this process is user 4321, not in 'dialout'."""
    root = tmp_path / "root"
    # the U2D2: usb1/1-2, its interface 1-2:1.0, the usb-serial port ttyUSB0 and its tty
    u2d2 = _usb(root, "1-2", "0403", "6014", manufacturer="FTDI", product="USB <-> Serial Converter",
                serial="FT6Z5XYZ")
    port = u2d2 / "1-2:1.0" / "ttyUSB0"
    (port / "tty" / "ttyUSB0").mkdir(parents=True)
    _link(port / "tty" / "ttyUSB0" / "device", port)
    (root / "sys/bus/usb-serial/drivers/ftdi_sio").mkdir(parents=True)
    _link(port / "driver", root / "sys/bus/usb-serial/drivers/ftdi_sio")
    _link(root / "sys/class/tty/ttyUSB0", port / "tty" / "ttyUSB0")
    _link(root / "sys/bus/usb-serial/devices/ttyUSB0", port)
    if latency is not None:
        _write(port / "latency_timer", latency + "\n")
    # the OpenRB-150: a cdc_acm interface and its tty
    board = _usb(root, "1-3", "2f5d", "2202", manufacturer="ROBOTIS", product="OpenRB-150")
    interface = board / "1-3:1.0"
    (interface / "tty" / "ttyACM0").mkdir(parents=True)
    _link(interface / "tty" / "ttyACM0" / "device", interface)
    (root / "sys/bus/usb/drivers/cdc_acm").mkdir(parents=True)
    _link(interface / "driver", root / "sys/bus/usb/drivers/cdc_acm")
    _link(root / "sys/class/tty/ttyACM0", interface / "tty" / "ttyACM0")
    # a built-in UART (no USB device above it) and a console (no device at all)
    uart = root / "sys/devices/platform/serial8250/tty/ttyS0"
    uart.mkdir(parents=True)
    _link(uart / "device", root / "sys/devices/platform/serial8250")
    _link(root / "sys/class/tty/ttyS0", uart)
    (root / "sys/class/tty/console").mkdir(parents=True)
    # CAN: a candleLight (gs_usb) as can0, a virtual vcan0; eth0 is no CAN link
    candle = _usb(root, "1-4", "1d50", "606f", product="candleLight USB to CAN adapter")
    (root / "sys/bus/usb/drivers/gs_usb").mkdir(parents=True)
    _link(candle / "1-4:1.0" / "driver", root / "sys/bus/usb/drivers/gs_usb")
    for name, kind, state in (("can0", "280", "up"), ("vcan0", "280", "unknown"), ("eth0", "1", "up")):
        _write(root / "sys/class/net" / name / "type", kind + "\n")
        _write(root / "sys/class/net" / name / "operstate", state + "\n")
    _link(root / "sys/class/net/can0/device", candle / "1-4:1.0")
    # /dev: the device nodes (files here), rw for owner and group only; the by-id link
    for tty in ("ttyUSB0", "ttyACM0", "ttyS0"):
        _write(root / "dev" / tty, "").chmod(0o660)
    _link(root / "dev/serial/by-id" / BY_ID, root / "dev/ttyUSB0")
    gid = (root / "dev/ttyUSB0").stat().st_gid
    _write(root / "etc/group", f"dialout:x:{gid}:{'alice' if member else ''}\nalice:x:{UID}:\n")
    _write(root / "etc/passwd", f"alice:x:{UID}:{UID}::/home/alice:/bin/bash\n")
    # /proc: this process (user 4321, its groups, capabilities, limits), and Dynamixel Wizard holding ttyUSB0
    _write(root / "proc/self/status", f"Name:\tpython\nUid:\t{UID}\t{UID}\t{UID}\t{UID}\n"
                                      f"Gid:\t{UID}\t{UID}\t{UID}\t{UID}\nGroups:\t{UID}\nCapEff:\t{caps:016x}\n")
    _write(root / "proc/self/limits", "Limit                     Soft Limit           Hard Limit           Units\n"
                                      f"Max realtime priority     {rtprio[0]:<21}{rtprio[1]:<21}\n")
    if holder:
        _link(root / "proc/4242/fd/7", "/dev/ttyUSB0")
        _write(root / "proc/4242/cmdline", "DynamixelWizard2\0")
    _link(root / "proc/4243/fd/3", "/dev/null")                  # a process holding something else
    return root


def _checks(findings):
    return {f.check: f for f in findings}


# ---------------------------------------------------------------------------- what the host has

def test_serial_ports_are_the_usb_adapters_with_their_descriptors(tmp_path):
    found = ports.serial_ports(stand_in(tmp_path))
    assert [p.device for p in found] == ["/dev/ttyACM0", "/dev/ttyUSB0"], \
        "the USB adapters in name order; ttyS0 (no USB device above it) and the console are not adapters"
    board, u2d2 = found
    assert (u2d2.vid_pid, u2d2.manufacturer, u2d2.product, u2d2.serial, u2d2.driver) == \
        ("0403:6014", "FTDI", "USB <-> Serial Converter", "FT6Z5XYZ", "ftdi_sio"), \
        "read from the USB device above the tty"
    assert u2d2.by_id == f"/dev/serial/by-id/{BY_ID}", "the stable name whose link points to it"
    assert u2d2.adapter.name == "U2D2" and u2d2.adapter.bus == "dynamixel", "recognised by its VID:PID"
    assert (board.vid_pid, board.driver, board.adapter.name, board.by_id) == \
        ("2f5d:2202", "cdc_acm", "OpenRB-150", None), "a cdc_acm board: the interface's driver; no by-id link here"
    assert ports.serial_ports(tmp_path / "empty") == [], "a machine without sysfs entries has none"


def test_the_adapter_table_is_spelt_as_sysfs_spells_ids():
    for vid, pid in ports.ADAPTERS:
        assert len(vid) == len(pid) == 4 and (vid + pid) == (vid + pid).lower(), \
            f"{vid}:{pid}: sysfs gives four lower-case hex digits, and lookups compare them so"
    assert {a.bus for a in ports.ADAPTERS.values()} == {"dynamixel", "can"}, "what each carries"


def test_can_links_are_the_links_of_type_280(tmp_path):
    links = {link.name: link for link in ports.can_links(stand_in(tmp_path))}
    assert sorted(links) == ["can0", "vcan0"], "eth0 (type 1) is no CAN link"
    can0 = links["can0"]
    assert (can0.operstate, can0.driver, can0.vid_pid, can0.adapter.name) == \
        ("up", "gs_usb", "1d50:606f", "candleLight (gs_usb)"), "its USB adapter, recognised"
    assert can0.bitrate is None, "a stand-in tree never asks `ip` (it would describe this machine)"
    assert links["vcan0"].operstate == "unknown" and links["vcan0"].adapter is None, "a virtual link: no adapter"


def test_ip_details_give_the_bit_rate_and_controller_state():
    text = json.dumps([{"ifname": "lo", "linkinfo": None},
                       {"ifname": "can0", "linkinfo": {"info_kind": "can", "info_data": {
                           "state": "ERROR-ACTIVE", "restart_ms": 0, "bittiming": {"bitrate": 1000000}}}}])
    assert ports._ip_can_details(text) == {"can0": {"bitrate": 1000000, "state": "ERROR-ACTIVE", "restart_ms": 0}}, \
        "`ip -details -json link show`'s CAN links, the others left out"
    assert ports._ip_can_details("not json") == {}, "an ip that says something else is no CAN link"


# ---------------------------------------------------------------------------- findings, each with its fix

def test_a_missing_port_names_the_ports_there_are(tmp_path):
    root = stand_in(tmp_path)
    [missing] = port_access.port_findings("/dev/ttyUSB9", root)
    assert missing.check == "port" and missing.severity == ERROR
    assert missing.line() == ("bus '/dev/ttyUSB9': port: found no /dev/ttyUSB9, expected a serial port; serial ports "
                              "here: /dev/ttyACM0 (OpenRB-150), /dev/ttyUSB0 (U2D2); `servodyn ports` lists them"), \
        "what does exist, by name, and where to look"
    [none] = port_access.port_findings("/dev/ttyUSB0", tmp_path / "empty")
    assert none.fix == ports.NO_ADAPTERS and "dmesg | tail" in none.fix and "ftdi_sio" in none.fix, \
        "no adapter at all: the cable, the kernel's log, the driver"


def test_permission_names_the_group_and_the_usermod_line(tmp_path):
    root = stand_in(tmp_path, holder=False)
    denied = _checks(port_access.port_findings("/dev/ttyUSB0", root))["permission"]
    assert "group 'dialout'" in denied.found, f"the group that owns the device: {denied.found}"
    assert denied.fix == "`sudo usermod -aG dialout $USER`, then log out and in", \
        "the exact line to run (servodyn never runs sudo), and that it takes a new login"
    again = _checks(port_access.port_findings(f"/dev/serial/by-id/{BY_ID}", root))["permission"]
    assert again.fix == denied.fix, "the by-id name is the same device"
    member = _checks(port_access.port_findings("/dev/ttyUSB0", stand_in(tmp_path / "m", holder=False, member=True)))
    assert member["permission"].fix.startswith("'alice' is in 'dialout' already") and \
        "log out and in" in member["permission"].fix, "added to the group, but this session began before"


def test_another_process_holding_the_port_is_named(tmp_path):
    root = stand_in(tmp_path)
    held = _checks(port_access.port_findings("/dev/ttyUSB0", root))["port in use"]
    assert held.found == "held by pid 4242 (DynamixelWizard2)", "its pid and command line, from /proc"
    assert "kill 4242" in held.fix and "Disconnect" in held.fix, held.fix
    assert "port in use" not in _checks(port_access.port_findings("/dev/ttyACM0", root)), "nobody holds ttyACM0"
    assert [str(h) for h in port_access.holders(f"/dev/serial/by-id/{BY_ID}", root)] == ["pid 4242 (DynamixelWizard2)"], \
        "a by-id name finds the holders of the device it points to"


def test_an_ftdi_latency_timer_above_1_ms_is_a_warning_with_the_udev_rule(tmp_path):
    latency = _checks(port_access.port_findings("/dev/ttyUSB0", stand_in(tmp_path)))["latency timer"]
    assert (latency.found, latency.expected, latency.severity) == ("16 ms", "1 ms", WARNING), \
        "servodyn lowers it at open, so before open it is a warning"
    assert latency.fix.startswith("servodyn asks it down to 1 ms at open") and ports.LATENCY_UDEV_RULE in latency.fix, \
        "what open does, and the rule that sets it for every plug-in"
    assert latency.fix.endswith("(now: `echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer`)"), \
        "the machine's own path, never the stand-in tree's"
    assert "latency timer" not in _checks(port_access.port_findings("/dev/ttyUSB0", stand_in(tmp_path / "1", latency="1"))), \
        "1 ms is what is wanted"
    assert "latency timer" not in _checks(port_access.port_findings("/dev/ttyACM0", stand_in(tmp_path / "a"))), \
        "a cdc_acm board has no latency timer: no file means no FTDI adapter, not a finding"


@pytest.mark.parametrize("rtprio, caps, fix", [
    ((0, 0), 0, ports.REALTIME_FIX),
    ((0, 99), 0, "`ulimit -r 99` in the shell that starts servodyn (the hard limit allows it)"),
    ((99, 99), 0, None),
    ((0, 0), 1 << ports.CAP_SYS_NICE, None),
    ((50, 50), 0, ports.REALTIME_FIX)])
def test_realtime_priority_needs_rtprio_or_cap_sys_nice(tmp_path, rtprio, caps, fix):
    found = port_access.realtime_findings(stand_in(tmp_path, rtprio=rtprio, caps=caps), priority=80)
    if fix is None:
        assert found == [], f"RLIMIT_RTPRIO {rtprio} with capabilities {caps:x}: SCHED_FIFO at 80 is allowed"
    else:
        [refused] = found
        assert refused.severity == WARNING and refused.fix == fix, \
            f"RLIMIT_RTPRIO {rtprio}: the loop would run at normal priority; the fix: {refused.fix}"
        assert refused.found.startswith("SCHED_FIFO not allowed"), "the words hal.realtime uses"


def test_the_loop_says_the_same_fix_when_sched_fifo_is_refused(monkeypatch, capsys):
    from servodyn.hal import realtime

    def refuse(*args):
        raise PermissionError(errno.EPERM, "Operation not permitted")
    monkeypatch.setattr(realtime.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime, "_refused", set())
    with realtime.realtime_priority(realtime.LOOP_PRIORITY) as granted:
        assert granted is False
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.endswith(ports.REALTIME_FIX), f"one line, its fix hal.ports's: {err}"


def test_open_failure_is_one_line_with_its_fix(tmp_path):
    root = stand_in(tmp_path, holder=False)
    assert port_access.open_failure("/dev/ttyUSB0", errno.EACCES, root) == (
        "/dev/ttyUSB0: cannot open (Permission denied): -rw-rw---- group 'dialout' (this user is not in it); "
        "`sudo usermod -aG dialout $USER`, then log out and in"), "the group and the line"
    missing = port_access.open_failure("/dev/ttyUSB3", errno.ENOENT, root)
    assert missing.startswith("/dev/ttyUSB3: cannot open (No such file or directory); serial ports here: ") \
        and "/dev/ttyUSB0 (U2D2)" in missing, missing
    busy = port_access.open_failure("/dev/ttyUSB0", errno.EBUSY, stand_in(tmp_path / "b"))
    assert "held by pid 4242 (DynamixelWizard2)" in busy, busy


# ---------------------------------------------------------------------------- at open, on a real port

@pytest.fixture
def pty():
    master, slave = os.openpty()
    yield slave, os.ttyname(slave)
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def test_lock_port_refuses_a_second_holder_and_names_it(pty):
    fd, path = pty
    again = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        port_access.lock_port(fd, path)                       # the first: ours alone
        with pytest.raises(ServoInitializationError) as refused:
            port_access.lock_port(again, path)
        line = str(refused.value)
        assert "\n" not in line and line.startswith(f"{path}: in use, locked by pid {os.getpid()} ("), line
        assert "this process" in line, f"the holder is this very process: {line}"
        os.close(fd)                                   # closing the first descriptor lets the lock go
        port_access.lock_port(again, path)
    finally:
        os.close(again)


def test_the_latency_timer_is_lowered_at_open(tmp_path, pty):
    fd, _ = pty
    root = stand_in(tmp_path, holder=False)
    assert port_access.lower_latency(fd, "/dev/ttyUSB0", root) == (16, 1), \
        "a pseudo-terminal refuses TIOCSSERIAL, so the writable sysfs file is what lowered it"
    assert port_access.latency_file("/dev/ttyUSB0", root).read_text().strip() == "1"
    assert port_access.lower_latency(fd, "/dev/ttyACM0", root) == (None, None), "no latency timer: nothing to do"


def test_a_latency_timer_that_stays_high_refuses_real_time_only(tmp_path, pty, monkeypatch):
    fd, _ = pty
    root = stand_in(tmp_path, holder=False)

    def read_only(self, *args, **kwargs):          # sysfs as a user sees it: 0644, root's
        raise PermissionError(errno.EACCES, "Permission denied", str(self))
    monkeypatch.setattr(pathlib.Path, "write_text", read_only)
    with pytest.raises(ServoInitializationError) as refused:
        port_access.claim_port(fd, "/dev/ttyUSB0", realtime=True, root=root)
    line = str(refused.value)
    assert "\n" not in line and line.startswith("/dev/ttyUSB0: latency timer at 16 ms"), line
    assert ports.LATENCY_UDEV_RULE in line and "sudo tee" in line, f"the fix, for good and for now: {line}"
    assert port_access.claim_port(fd, "/dev/ttyUSB0", realtime=False, root=root) == (16, 16), \
        "bring-up commands open without refusing"


def test_the_dynamixel_bus_claims_a_real_port_and_closes_it_when_refused(monkeypatch, pty):
    from servodyn.hal import make_bus
    from servodyn.hal.config import load_config
    from servodyn.hal.dynamixel import backend
    _, path = pty
    claimed = []

    def refuse(fd, port, realtime):
        claimed.append((port, realtime))
        raise ServoInitializationError(f"{port}: in use, held by pid 4242 (DynamixelWizard2)")
    monkeypatch.setattr(backend, "is_pseudo_terminal", lambda p: False)     # as if it were an adapter
    monkeypatch.setattr(backend, "claim_port", refuse)
    bus = make_bus(load_config("replica"), port=path, realtime=False)
    with pytest.raises(ServoInitializationError, match="held by pid 4242"):
        bus.open()
    assert claimed == [(path, False)], "claimed once, with the bus's realtime option"
    assert not bus.port.is_open and not bus.is_open, "a refused port is closed again (its lock let go)"


def test_a_port_that_does_not_exist_says_what_to_check(tmp_path):
    from servodyn.hal import make_bus
    from servodyn.hal.config import load_config
    with pytest.raises(ServoInitializationError) as refused:
        make_bus(load_config("replica"), port=str(tmp_path / "ttyUSB9")).open()
    line = str(refused.value)
    assert line.startswith(f"{tmp_path / 'ttyUSB9'}: cannot open (No such file or directory); ") and "\n" not in line
    assert "servodyn ports" in line or line.endswith(ports.NO_ADAPTERS), \
        f"the ports this machine has, or what to check when it has none: {line}"


# ---------------------------------------------------------------------------- servodyn ports

def test_servodyn_ports_prints_both_tables(tmp_path, capsys):
    root = stand_in(tmp_path)
    assert main(["ports", "--root", str(root)]) == 0, "a listing: nothing failed"
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "serial adapters" and lines[1].split() == \
        ["device", "adapter", "VID:PID", "product", "latency", "held", "by", "by-id"]
    usb = next(line for line in lines if line.lstrip().startswith("/dev/ttyUSB0"))
    for shown in ("U2D2", "0403:6014", "USB <-> Serial Converter", "16 ms", "pid 4242 (DynamixelWizard2)",
                  f"/dev/serial/by-id/{BY_ID}"):
        assert shown in usb, f"{shown!r} in the U2D2's row: {usb}"
    under = lines[lines.index(usb) + 1:]
    held = "! bus '/dev/ttyUSB0': port in use: found held by pid 4242"
    assert any(line.strip().startswith(held) for line in under), "its findings under its row"
    assert any("latency timer: found 16 ms" in line for line in under)
    acm = next(line for line in lines if line.lstrip().startswith("/dev/ttyACM0"))
    assert "OpenRB-150" in acm and " - " in acm, f"no latency timer, no holder: {acm}"
    assert "SocketCAN links" in lines
    can0 = next(line for line in lines if line.lstrip().startswith("can0"))
    assert can0.split()[:2] == ["can0", "up"] and "candleLight (gs_usb)" in can0, can0


def test_servodyn_ports_json_and_none_found(tmp_path, capsys):
    root = stand_in(tmp_path)
    assert main(["ports", "--json", "--root", str(root)]) == 0
    report = json.loads(capsys.readouterr().out)
    u2d2 = next(p for p in report["serial"] if p["device"] == "/dev/ttyUSB0")
    assert (u2d2["adapter"], u2d2["vid_pid"], u2d2["latency_ms"], u2d2["held_by"]) == \
        ("U2D2", "0403:6014", 16, [{"pid": 4242, "command": "DynamixelWizard2"}])
    assert {f["check"] for f in u2d2["findings"]} == {"permission", "port in use", "latency timer"}, \
        "each finding as doctor --json has it"
    assert [link["name"] for link in report["can"]] == ["can0", "vcan0"]
    (tmp_path / "bare").mkdir()
    assert main(["ports", "--root", str(tmp_path / "bare")]) == 0
    assert capsys.readouterr().out.strip() == ports.NO_ADAPTERS, "none found: what to check"
