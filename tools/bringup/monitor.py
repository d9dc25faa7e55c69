"""`servodyn monitor`: torque off on every bus of a configuration, then every joint's state, SI and
raw, refreshed in place until Ctrl-C (each bus read through its kind's bring-up, hal.bringup).
Its errors are the HAL's, one line each (tools/bringup makes them the command's)."""

from __future__ import annotations

import math
import sys
import time
from contextlib import ExitStack

from ...hal.bringup import BadRequest, config_and_ports, open_limp

MAX_RATE = 100.0        # refreshes per second: a table redrawn faster is not read, and the bus is busy
MIN_RATE = 0.1          # at least one refresh every 10 s
HEADS = ("joint", "id", "q deg", "q raw", "qd rad/s", "qd raw", "I or τ", "raw", "°C", "V", "error")


def monitor(config_name: str, port, count: int | None, rate: float, say=print) -> int:
    """Torque off, then every joint's state, SI and raw, refreshed in place until Ctrl-C (or
    `count` refreshes). `rate` and `count` are checked before anything is sent."""
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and MIN_RATE <= rate <= MAX_RATE):
        raise BadRequest(f"--rate must be a number of refreshes per second from {MIN_RATE:g} to {MAX_RATE:g}, "
                         f"got {rate!r}")
    if count is not None and count < 1:
        raise BadRequest(f"--count must be a whole number of refreshes >= 1, got {count}")
    config, ports = config_and_ports(config_name, port)
    try:
        with ExitStack() as stack:
            sessions = open_limp(config, ports, stack, "(support the arm), then read only", say)
            live = _live_table() if sys.stdout.isatty() and count is None else None
            shown = 0
            with live or _Plain(say) as out:
                while count is None or shown < count:
                    out.update(_table(config, sessions))
                    shown += 1
                    if count is None or shown < count:
                        time.sleep(1.0 / rate)
    except KeyboardInterrupt:
        say("")
    return 0


class _Plain:
    """Monitor's output when not on a terminal: each refresh printed as a block."""

    def __init__(self, say):
        self.say = say

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, table) -> None:
        from rich.console import Console
        console = Console(width=140, force_terminal=False, color_system=None)
        with console.capture() as capture:
            console.print(table)
        self.say(capture.get().rstrip())


def _live_table():
    from rich.live import Live
    return Live(refresh_per_second=10, transient=False)


def _table(config, sessions):
    from rich.table import Table
    table = Table(title=f"{config.name}: torque off (Ctrl-C ends)", title_justify="left")
    for head in HEADS:
        table.add_column(head, justify="left" if head == "joint" else "right")
    for here in sessions.values():
        for row in here.monitor():
            if row.q is None:
                table.add_row(row.joint, str(row.id), *["-"] * (len(HEADS) - 3), row.error)
                continue
            table.add_row(row.joint, str(row.id), f"{math.degrees(row.q):8.2f}", row.raw[0], f"{row.qd:7.3f}",
                          row.raw[1], row.effort, row.raw[2], row.temperature, row.voltage, row.error)
    return table
