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

from servodyn.hal.dynamixel import ALERT_BIT, ErrorNumber
from servodyn.hal.dynamixel.control_table import PWM_FULL, TICKS_PER_REV, VELOCITY_UNIT, WATCHDOG_UNIT, OperatingMode

from . import _chain
from .drive import Mechanics
from .servo import _CHANGES, GOAL_ITEMS, Servo

# the Mechanics fields Mechanics.torque reads, in the order the C side takes them
_MECHANICS = ("torque_constant", "gear_efficiency", "viscous_friction", "coulomb_friction", "coulomb_velocity")
# items whose write _check_value or _apply treats apart from the rest (besides _CHANGES): their
# writes stay with Servo.write
_APART = frozenset({"goal_position", "bus_watchdog", "torque_enable"})


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
        """ValueError when the servos cannot be one chain (control tables of other layouts, too
        many servos): `of` gives the chain that covers none then."""
        self.servos = list(servos)
        try:
            layouts = {tuple((s.items[name].address, s.items[name].size, s.items[name].signed)
                             for name in _chain.FIELDS) for s in self.servos}
        except KeyError as missing:
            raise ValueError(f"ServoChain: a servo without the item {missing}") from None
        if len(layouts) > 1:
            raise ValueError("ServoChain: the servos' control tables differ in layout")
        fields = layouts.pop() if layouts else tuple((0, 1, False) for _ in _chain.FIELDS)
        constants = tuple((s.model.stall_current, s.model.nominal_voltage, s.model.no_load_speed, s.model.current_unit)
                          for s in self.servos)
        self._c = _chain.Chain(self.servos, fields, constants,
                               (TICKS_PER_REV, VELOCITY_UNIT, PWM_FULL, WATCHDOG_UNIT, int(OperatingMode.CURRENT)))
        self._rules: dict[tuple[int, int], tuple | None] = {}      # (address, length) -> write rule
        # the torque in C only for servos whose output_torque is Servo's (Mechanics.torque)
        self._torque_kind = Mechanics if all(type(s).output_torque is Servo.output_torque for s in self.servos) \
            else None

    @classmethod
    def of(cls, servos: Sequence[Servo]) -> ServoChain:
        """The chain of `servos`, or one of none (it covers no bus of servos: each goes on its own)."""
        try:
            return cls(servos)
        except ValueError:
            return cls([])

    def covers(self, servos: list[Servo]) -> bool:
        """Whether this chain is exactly `servos`, in order (a bus's list can be changed)."""
        return servos == self.servos

    # --- the plant's side (plant.Plant's chain) ----------------------------------------------------

    def output(self, position, velocity, dt: float, current, torque) -> None:
        """Each servo's motor current for the next `dt` (Servo.output_current) into `current` and
        the torque at its horn (Servo.output_torque) into `torque`; position and velocity at each
        horn, all four float64 arrays."""
        servos = self.servos
        velocities = velocity.tolist()
        k = self._c.currents(position, velocity, current, 0)
        while k < len(servos):            # a servo of the C side's, then on from the next
            current[k] = float(servos[k].output_current(position[k].item(), velocities[k], dt))
            k = self._c.currents(position, velocity, current, k + 1)
        kind, n = self._torque_kind, len(servos)
        k = self._c.torques(current, velocity, torque, 0, kind, _MECHANICS) if kind is not None else 0
        while k < n:                      # Servo.output_torque: another Mechanics or another Servo
            torque[k] = servos[k].output_torque(current[k].item(), velocities[k])
            k = self._c.torques(current, velocity, torque, k + 1, kind, _MECHANICS) if kind is not None else k + 1

    def publish(self, position, velocity, current) -> None:
        """Servo.set_present of every servo (float64 arrays)."""
        self._c.publish(position, velocity, current)

    # --- the bus's side ------------------------------------------------------------------------------

    def refresh(self) -> None:
        """The Present registers of every servo whose shaft moved since they were written (those
        the C side leaves stay stale: the servo writes them itself when read)."""
        self._c.refresh()

    def clock(self, now: float) -> None:
        """Every servo not clocked at `now` yet is (DynamixelWire.tick)."""
        general = self._c.clock(now)
        if general:
            for k in _bits(general):
                servo = self.servos[k]
                if servo.clocked_at != now:
                    servo.clock(now)

    def heard(self, now: float) -> None:
        """A packet for every servo arrived at `now` (Servo.heard)."""
        general = self._c.heard(now)
        if general:
            for k in _bits(general):
                self.servos[k].heard(now)

    def write(self, address: int, length: int, params: bytes) -> bool:
        """A broadcast SYNC WRITE's parameters (DynamixelWire._writes) applied, when its span is one
        RAM item that only Servo._check_value's common rules check (range, mask, limit, a
        tripped watchdog for a goal) for every servo alike; False (nothing done) otherwise."""
        rule = self._rules.get((address, length), False)
        if rule is False:
            rule = self._rules[address, length] = self._rule(address, length)
        return rule is not None and self._c.write(params, rule) >= 0

    def _rule(self, address: int, length: int) -> tuple | None:
        rules = set()
        for servo in self.servos:
            layout = servo._layout(address, length)
            if isinstance(layout, ErrorNumber):
                return None
            items, eeprom = layout
            item = items[0][0]
            if eeprom or len(items) != 1 or item.name in _CHANGES or item.name in _APART or item.choices is not None:
                return None
            limit = servo.items[item.limit] if item.limit is not None else None
            rules.add((item.signed, item.name in GOAL_ITEMS, item.low, item.high, item.mask,
                       None if limit is None else (limit.address, limit.size, limit.signed)))
        return rules.pop() if len(rules) == 1 else None

    def fast_read(self, ids: bytes, address: int, length: int, frame: bytearray, starts: list[int]) -> int:
        """DynamixelWire._fast_reads of one span from every servo of `ids`, filled in the reply laid
        out in `frame` (block k at starts[k]): the blocks filled, -1 for no reply, -2 when it is
        the servos' own (DynamixelWire's general path)."""
        return self._c.fast_read(ids, address, length, frame, starts, ALERT_BIT, ErrorNumber.ACCESS)
