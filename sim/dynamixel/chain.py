"""The servos of one simulated bus, their per-tick work done for the whole chain.

Every control period the plant asks each servo for its current and tells it where its shaft is
(`output`, `publish`: the plant's drives one by one, plant.Drives), and the bus clocks each servo
(`clock`: DynamixelWire.tick). ``ServoChain`` is both for the servos of one bus, so that the plant
and the bus share one object; each servo's own methods (servo.py, drive.py) are the one
definition of what it does.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..plant import Drives

from .servo import Servo


class ServoChain(Drives):
    """The servos of a bus as one drive chain (the plant's ``chain``) and one clock."""

    def __init__(self, servos: Sequence[Servo]):
        super().__init__(list(servos))
        self.servos = self.drives

    @classmethod
    def of(cls, servos: Sequence[Servo]) -> ServoChain:
        """The chain of `servos`."""
        return cls(servos)

    def covers(self, servos: list[Servo]) -> bool:
        """Whether this chain is exactly `servos`, in order (a bus's list can be changed)."""
        return servos == self.servos

    def clock(self, now: float) -> None:
        """Every servo not clocked at `now` yet is (DynamixelWire.tick): one clocked at `now` already
        has since heard a packet (silent 0) or nothing, so clocking it again would change nothing."""
        for servo in self.servos:
            if servo.clocked_at != now:
                servo.clock(now)
