"""Simulated CAN motors behind the real frames (hal.can's codec): `motor` (a motor's firmware and
physics), `network` (the bus every motor listens to)."""

from .motor import CanMotor
from .network import CanNetwork

__all__ = ["CanMotor", "CanNetwork"]
