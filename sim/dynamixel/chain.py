"""The servos of one simulated bus, their per-tick work done for all of them at once.

Every control period the plant asks each servo for its current and tells it where its shaft is,
and the bus clocks each servo and reads its Present registers. ``ServoChain`` does that work for
the whole chain in one C call each (``_chain``, sim/dynamixel/c/_chain.c: the same operations in
the same order on the same doubles as the Servo methods it stands for, so the registers and the
currents are bit for bit theirs). What is not the common case — a mode other than Current Control
with torque on, a watchdog that trips, a value the Python code would refuse with an exception — the
C side leaves to each servo's own method, which stays the definition of the behaviour.
"""

from __future__ import annotations

from collections.abc import Sequence

from servodyn.hal.dynamixel.control_table import PWM_FULL, TICKS_PER_REV, VELOCITY_UNIT, WATCHDOG_UNIT, OperatingMode

from . import _chain
from .servo import Servo


def _bits(mask: int):
    """The indices of the set bits of `mask`."""
    k = 0
    while mask:
        if mask & 1:
            yield k
        mask >>= 1
        k += 1


class ServoChain:
    """The servos of a bus as one drive chain (the plant's ``chain``) and one clock."""

    def __init__(self, servos: Sequence[Servo]):
        self.servos = list(servos)
        layouts = {tuple((s.items[name].address, s.items[name].size, s.items[name].signed) for name in _chain.FIELDS)
                   for s in self.servos}
        if len(layouts) > 1:
            raise ValueError("ServoChain: the servos' control tables differ in layout")
        fields = layouts.pop() if layouts else tuple((0, 1, False) for _ in _chain.FIELDS)
        constants = tuple((s.model.stall_current, s.model.nominal_voltage, s.model.no_load_speed, s.model.current_unit)
                          for s in self.servos)
        self._c = _chain.Chain(self.servos, fields, constants,
                               (TICKS_PER_REV, VELOCITY_UNIT, PWM_FULL, WATCHDOG_UNIT, int(OperatingMode.CURRENT)))

    def covers(self, servos: list[Servo]) -> bool:
        """Whether this chain is exactly `servos`, in order (a bus's list can be changed)."""
        return servos == self.servos

    # --- the plant's side (plant.Plant's chain) ----------------------------------------------------

    def output(self, position, velocity, dt: float, current, torque) -> None:
        """Each servo's motor current for the next `dt` (Servo.output_current) into `current` and
        the torque at its horn (Servo.output_torque) into `torque`; position and velocity at each
        horn, all four float64 arrays."""
        general, off = self._c.currents(position, velocity, current)
        servos = self.servos
        for k in _bits(off):
            servos[k]._pid.reset()                 # torque off (Servo.output_current)
        velocities = velocity.tolist()
        if general:
            positions = position.tolist()
            for k in _bits(general):
                current[k] = float(servos[k].output_current(positions[k], velocities[k], dt))
        for k, (servo, amps, speed) in enumerate(zip(servos, current.tolist(), velocities)):
            torque[k] = servo.output_torque(amps, speed)

    def publish(self, position, velocity, current) -> None:
        """Servo.set_present of every servo (float64 arrays)."""
        self._c.publish(position, velocity, current)

    # --- the bus's side ------------------------------------------------------------------------------

    def refresh(self) -> None:
        """The Present registers of every servo whose shaft moved since they were written (those
        the C side leaves stay stale: the servo writes them itself when read)."""
        self._c.refresh()

    def clock(self, now: float) -> None:
        """Every servo not clocked at `now` yet is (VirtualBus.tick)."""
        general = self._c.clock(now)
        for k in _bits(general):
            servo = self.servos[k]
            if servo.clocked_at != now:
                servo.clock(now)

    def heard(self, now: float) -> None:
        """A packet for every servo arrived at `now` (Servo.heard)."""
        general = self._c.heard(now)
        for k in _bits(general):
            self.servos[k].heard(now)
