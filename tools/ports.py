"""`servodyn ports`: the serial adapters and SocketCAN links of this machine in one table each —
what each adapter is (hal.ports.ADAPTERS), its latency timer and who holds it — and under each
port what on the host stands in its way, with the fix (hal.port_access.port_findings).

    serial adapters
      device        adapter  VID:PID    product                   latency  held by  by-id
      /dev/ttyUSB0  U2D2     0403:6014  USB <-> Serial Converter  16 ms    -        /dev/serial/by-id/usb-FTDI_...
        ! bus '/dev/ttyUSB0': latency timer: found 16 ms, expected 1 ms; servodyn asks it down to 1 ms ...
    SocketCAN links
      link  state  bitrate        controller    adapter
      can0  up     1000000 bit/s  ERROR-ACTIVE  candleLight (gs_usb)
"""

from __future__ import annotations

import json
from pathlib import Path

from ..hal.can.spec import Can
from ..hal.port_access import holders, latency_timer, port_findings
from ..hal.ports import NO_ADAPTERS, ROOT, can_links, serial_ports


def ports_report(root: Path = ROOT) -> dict:
    """{"serial": [...], "can": [...]}: each adapter with its latency timer, holders and findings."""
    serial = []
    for port in serial_ports(root):
        entry = port.as_json()
        entry["latency_ms"] = latency_timer(port.device, root)
        entry["held_by"] = [{"pid": h.pid, "command": h.command} for h in holders(port.device, root)]
        entry["findings"] = [f.as_json() | {"line": f.line()} for f in port_findings(port.device, root)]
        serial.append(entry)
    return {"serial": serial, "can": [link.as_json() for link in can_links(root)]}


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    widths = [max(len(row[k]) for row in [header, *rows]) for k in range(len(header))]
    return ["  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in [header, *rows]]


def _serial_row(port: dict) -> list[str]:
    held = ", ".join(f"pid {h['pid']} ({h['command']})" for h in port["held_by"])
    latency = f"{port['latency_ms']} ms" if port["latency_ms"] is not None else "-"
    return [port["device"], port["adapter"] or "-", port["vid_pid"] or "-", port["product"] or "-", latency,
            held or "-", port["by_id"] or "-"]


def ports_lines(report: dict) -> list[str]:
    """The report as the command prints it: a table of each, a port's findings under its row."""
    serial, can = report["serial"], report["can"]
    if not serial and not can:
        return [NO_ADAPTERS]
    lines = []
    if serial:
        table = _table(["device", "adapter", "VID:PID", "product", "latency", "held by", "by-id"],
                       [_serial_row(port) for port in serial])
        lines += ["serial adapters", table[0]]
        for row, port in zip(table[1:], serial):
            lines.append(row)
            lines.extend(f"    ! {f['line']}" for f in port["findings"])
    else:
        lines.append(f"serial adapters: none ({NO_ADAPTERS.split(': ', 1)[1]})")
    if can:
        rows = [[link["name"], link["operstate"] or "-", f"{link['bitrate']} bit/s" if link["bitrate"] else "-",
                 link["state"] or "-", link["adapter"] or link["driver"] or "-"] for link in can]
        lines += ["SocketCAN links", *_table(["link", "state", "bitrate", "controller", "adapter"], rows)]
        lines.extend(f"    ! {link['name']} is down: `sudo ip link set {link['name']} up type can bitrate "
                     f"{Can.default_baud}`" for link in can if link["operstate"] == "down")
    else:
        lines.append("SocketCAN links: none (a candleLight or CANable on gs_usb firmware shows up as can0)")
    return lines


def run_ports(root: Path = ROOT, as_json: bool = False, say=print) -> int:
    report = ports_report(Path(root))
    if as_json:
        say(json.dumps(report, indent=1))
    else:
        for line in ports_lines(report):
            say(line)
    return 0
