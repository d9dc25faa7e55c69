"""The simulated CAN bus: every motor sees every frame (CAN is a broadcast medium) and answers
the ones for it (a factory-fresh Damiao motor answers on id 0, two motors on one CAN ID both
answer: on a real bus their frames would collide). In lock-step the plant advances one control period once every motor has had its
command frame for the tick. A fault of the wire (sim/faults.py, CanWireFault) acts on one motor's
answers, or on the host's controller (bus-off)."""

from __future__ import annotations

import time

from ..faults import BUS_OFF, CAN_ERR_BUSOFF, CanWireFault
from .motor import CanMotor


class CanNetwork:
    def __init__(self, motors: list[CanMotor]):
        self.motors = list(motors)
        self.on_tick = None              # called when every motor has its command for the tick
        self._commanded: set[int] = set()
        self.frames_in = self.frames_out = 0
        self.wire: dict[int, CanWireFault] = {}    # CAN id -> the fault on that motor's answers
        self.bus_off_until = 0.0         # time.monotonic() until which the host's sends fail
        self._bus_off_pending = False    # the bus-off error frame, with the next answers

    def inject(self, can_id: int, kind: str, seed: int = 0) -> None:
        """A fault of the wire from now on (sim/faults.py: garbage, wrong_id, error_frame, bus_off);
        seed: its random bytes."""
        fault = CanWireFault(kind, seed=seed)
        self.motor(can_id)               # KeyError for a motor not on this bus
        if kind == "bus_off":
            self.bus_off_until = time.monotonic() + BUS_OFF
            self._bus_off_pending = True
        else:
            self.wire[can_id] = fault

    def bus_off(self) -> bool:
        """Whether the host's controller is off the bus now (its sends fail)."""
        return time.monotonic() < self.bus_off_until

    def power_cycle(self) -> None:
        """The bus's power off and on: every motor loses its RAM (CanMotor.power_cycle)."""
        for motor in self.motors:
            motor.power_cycle()
        self._commanded.clear()

    def motor(self, can_id: int) -> CanMotor:
        for m in self.motors:
            if m.can_id == can_id:
                return m
        raise KeyError(f"no motor with CAN id {can_id}")

    def handle(self, arbitration_id: int, data: bytes) -> list[tuple[int, bytes]]:
        """One frame from the host; the frames the motors put on the bus in answer."""
        self.frames_in += 1
        out = []
        if self._bus_off_pending:
            self._bus_off_pending = False
            out.append((-CAN_ERR_BUSOFF, bytes(8)))   # an error frame (sim/faults.py)
        for k, motor in enumerate(self.motors):
            answers, command = motor.receive(arbitration_id, bytes(data))
            if motor.can_id in self.wire and answers:
                answers = self.wire[motor.can_id].apply(answers, motor.dialect.name)
            out += answers
            if command:
                self._commanded.add(k)
        self.frames_out += len(out)
        if self.on_tick is not None and len(self._commanded) == len(self.motors):
            self._commanded.clear()
            self.on_tick()
        return out
