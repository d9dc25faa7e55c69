"""The simulated arm of a robot configuration: the plant, and behind each bus of the
configuration the devices that speak its wire protocol.

    arm = SimulatedArm(load_config("replica"))
    reply = arm.handle(request_bytes)         # what the servos put on the wire
    arm.advance(1e-3)                         # the plant runs; the servos' registers follow
    arm.inject_fault(4, "silent")             # servo 4 stops answering (or "overload", ...)

Two clocks, chosen by whoever serves the arm (sim/transport): `lockstep()` advances the plant by
one control period whenever the host ends a command transaction (a sync write), so a run is
deterministic and as fast as the host can go; otherwise the server advances it by the wall clock,
and `wall_clock()` puts the servos' own clocks (Bus Watchdog, Realtime Tick) on it too, so a host
that dies is noticed in real time even when the plant falls behind. `wire_clock()` times the
bytes as a servo's receiver does (a frame with a gap over 1.5 ms between bytes is dropped).
"""

from __future__ import annotations

import time as _time

from servodyn.control.timing import plant_step
from servodyn.hal.config import RobotConfig
from servodyn.hal.dynamixel.control_table import HARDWARE_FAULTS
from servodyn.hal.dynamixel.reader import BYTE_TIMEOUT

from .dynamixel import Servo, VirtualBus
from .faults import WIRE_FAULTS, WireFault
from .plant import Plant, PlantView

PUSHED = 0.5     # rad beyond its upper limit an external push moves a joint ("pushed"): past
                 # the host's and the firmware's range margins (0.05, 0.35 rad)
FAULTS = ("silent", "pushed", *HARDWARE_FAULTS, *WIRE_FAULTS)


class SimulatedArm(PlantView):
    """Servos and plant of a robot configuration (one Dynamixel bus); q in the model's dof order."""

    def __init__(self, config: RobotConfig, *, small_time_step: float | None = None, q0=None,
                 integrator: str = "rk4"):
        kinds = {bus.kind for bus in config.buses.values()}
        if kinds != {"dynamixel"} or len(config.buses) != 1:
            raise ValueError(f"'{config.name}': the simulator serves one Dynamixel bus "
                             f"(this configuration has {', '.join(sorted(kinds))})")
        self.config, self.model = config, config.model
        self.joints = [next(j for j in config.joints if j.dof == name) for name in self.model.dof_names]
        self.servos = [Servo(j.servo, j.id, position=0.0, zero_ticks=0) for j in self.joints]
        small_time_step = small_time_step or plant_step(config.control_period)   # RK4 step
        self.plant = Plant(self.model, self.joints, self.servos, small_time_step=small_time_step, q0=q0,
                           integrator=integrator)
        # the servos' clock is the plant's until wall_clock(); no byte timeout until wire_clock()
        self._servo_clock = lambda: self.plant.time
        self.bus = VirtualBus(self.servos, clock=lambda: self._servo_clock(), byte_timeout=None)
        self.small_time_step = small_time_step
        self.period = config.control_period      # s: one tick of the host (lock-step)
        self.wire: WireFault | None = None      # a fault of the wire, on every reply from then on

    # the plant's state, for tests and reports
    def advance(self, duration: float) -> None:
        """Run the plant; the servos' clocks (bus watchdog, Realtime Tick) follow."""
        self.plant.advance(duration)
        self.bus.tick()

    def handle(self, data: bytes) -> bytes:
        """Bytes from the host in, the servos' replies out."""
        reply = self.bus.handle(data)
        return reply if self.wire is None else self.wire.apply(reply)

    def wall_clock(self) -> None:
        """The servos' clocks (Bus Watchdog, Realtime Tick) follow the wall clock from now on (its
        seconds since this call plus the plant's time now), not the plant's."""
        offset = _time.monotonic() - self.plant.time
        self._servo_clock = lambda: _time.monotonic() - offset

    def wire_clock(self, clock=_time.monotonic) -> None:
        """The host's bytes come over a real-time wire: a frame whose bytes arrive more than
        BYTE_TIMEOUT apart on `clock` is dropped, as a servo does, so a truncated frame cannot
        swallow the next packet."""
        self.bus.reader.byte_timeout = BYTE_TIMEOUT
        self.bus.wire_clock = clock

    def lockstep(self, period: float | None = None) -> None:
        """Advance the plant by `period` (default the control period) at the end of each command
        transaction the host sends."""
        period = period or self.period
        self.bus.on_command = lambda: self.advance(period)

    def servo(self, servo_id: int) -> Servo:
        return self.bus.servo(servo_id)

    def inject_fault(self, servo_id: int, fault: str | int = "silent") -> None:
        """A servo fault from now on: "silent" (it stops answering), "pushed" (an external push
        moves its joint PUSHED rad beyond the configuration's upper limit), Hardware Error Status
        bits by name ("overload", "overheating", ...) or as an int, or a fault of the wire
        (sim/faults.py: "flipped_byte", "garbage", "delayed_reply", "wrong_id", "stall")."""
        servo = self.servo(servo_id)
        if fault == "silent":
            servo.silent = True
            return
        if fault == "pushed":
            j = self.servos.index(servo)
            self.plant.push(j, self.joints[j].position_limits[1] + PUSHED)
            return
        if fault in WIRE_FAULTS:
            self.wire = WireFault(fault, len(self.servos), seed=servo_id)
            return
        if isinstance(fault, str):
            if fault not in FAULTS:
                raise ValueError(f"unknown fault {fault!r} (one of {', '.join(FAULTS)})")
            fault = HARDWARE_FAULTS[fault]
        servo.set_hardware_error(int(fault))

    def clear_faults(self) -> None:
        """Every servo answers again (hardware errors stay until a reboot, as on a real servo)."""
        for servo in self.servos:
            servo.silent = False
        self.wire = None
