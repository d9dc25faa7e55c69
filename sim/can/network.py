"""The simulated CAN bus: every motor sees every frame (CAN is a broadcast medium) and answers
the ones for it. In lock-step the plant advances one control period once every motor has had its
command frame for the tick."""

from __future__ import annotations

from .motor import CanMotor


class CanNetwork:
    def __init__(self, motors: list[CanMotor]):
        self.motors = list(motors)
        self.on_tick = None              # called when every motor has its command for the tick
        self._commanded: set[int] = set()
        self.frames_in = self.frames_out = 0

    def motor(self, can_id: int) -> CanMotor:
        for m in self.motors:
            if m.can_id == can_id:
                return m
        raise KeyError(f"no motor with CAN id {can_id}")

    def handle(self, arbitration_id: int, data: bytes) -> list[tuple[int, bytes]]:
        """One frame from the host; the frames the motors put on the bus in answer."""
        self.frames_in += 1
        out = []
        for k, motor in enumerate(self.motors):
            answers, command = motor.receive(arbitration_id, bytes(data))
            out += answers
            if command:
                self._commanded.add(k)
        self.frames_out += len(out)
        if self.on_tick is not None and len(self._commanded) == len(self.motors):
            self._commanded.clear()
            self.on_tick()
        return out
