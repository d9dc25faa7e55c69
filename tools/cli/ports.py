"""`servodyn ports`: the machine's serial adapters and CAN links (data, on stdout)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..ports import run_ports
from .common import describe


def add_arguments(p) -> None:
    describe(p, "The USB serial adapters (device, stable by-id name, VID:PID, product, the adapter recognised, FTDI "
             "latency timer, the process holding it) and SocketCAN links (state, bit rate), each port's problems "
             "with their fixes. Changes nothing.", "servodyn ports --json")
    p.add_argument("--json", action="store_true", help="as JSON, for scripts")
    p.add_argument("--root", type=Path, default=Path("/"), help=argparse.SUPPRESS)   # a stand-in /dev, /sys, /proc


def run(args) -> int:
    return run_ports(args.root, as_json=args.json)
