"""`servodyn soak`: swings with one random fault each, on the host, the firmware and CAN (make soak)."""

from __future__ import annotations

from ..soak import MIXED_EVERY, run as run_soak
from .argtypes import count
from .common import describe


def add_arguments(p) -> None:
    describe(p, "Swings on the simulated buses with one random fault each (a silent servo, a hardware error, a "
             "stall, a corrupt reply, a NaN in the motion, ...), on the host loop, through the firmware under QEMU "
             "and on the simulated CAN motors; every run must stop safely with the fault's exit status. A few "
             "minutes; not part of make test.", "servodyn soak --runs 20 --firmware 0 --can 6",
             exits="0 every run stopped safely, 1 one did not (or hung)")
    p.add_argument("--runs", type=count(0), default=207, help="swings on the host (default 207: 23 per class)")
    p.add_argument("--firmware", type=count(0), default=14, help="runs through the firmware under QEMU "
                   "(default 14: 2 per class that can run there; 0 for none)")
    p.add_argument("--can", type=count(0), default=48, help="swings on the simulated CAN motors (default 48: 6 "
                   f"per class, every {MIXED_EVERY}th on replica_mixed; 0 for none)")
    p.add_argument("--seed", type=int, default=2026, help="the random faults' seed (default 2026)")
    p.add_argument("--jobs", type=count(1, what="worker processes"), default=2, help="worker processes (default 2)")


def run(args) -> int:
    return run_soak(args)
