"""The simulated arm of a configuration whose buses are CAN: one plant, and on each bus a network
of simulated motors that answer the real frames.

    arm = SimulatedCanArm(load_config("replica_can"))
    replies = arm.handle("arm", 0x001, command_bytes)   # [(id, data), ...] the motors put on the bus
    arm.advance(1e-3)
    arm.inject_fault(4, "silent")                        # or "overheat", or a status code

Lock-step: the plant advances one control period once every motor of the robot has had its
command for the tick (each bus's network reports its full round; the last one moves the plant).
"""

from __future__ import annotations

from servodyn.control.timing import SMALL_TIME_STEP
from servodyn.hal.config import RobotConfig

from ..plant import Plant
from .motor import CanMotor
from .network import CanNetwork

FAULTS = ("silent", "overheat", "fault")


class SimulatedCanArm:
    def __init__(self, config: RobotConfig, *, small_time_step: float = SMALL_TIME_STEP, q0=None,
                 integrator: str = "rk4"):
        kinds = {bus.kind for bus in config.buses.values()}
        if kinds != {"can"}:
            raise ValueError(f"'{config.name}': the CAN simulator serves CAN buses only "
                             f"(this configuration has {', '.join(sorted(kinds))})")
        self.config, self.model = config, config.model
        self.joints = [next(j for j in config.joints if j.dof == name) for name in self.model.dof_names]
        voltage = config.supply.voltage if config.supply else None
        self.motors = [CanMotor(j.servo, j.id, dialect=j.options["dialect"], feedback_id=j.options["feedback_id"],
                                ranges=j.options["ranges"], supply_voltage=voltage) for j in self.joints]
        self.plant = Plant(self.model, self.joints, self.motors, small_time_step=small_time_step, q0=q0,
                           integrator=integrator)
        self.networks = {name: CanNetwork([m for m, j in zip(self.motors, self.joints) if j.bus == name])
                         for name in config.buses}
        self.small_time_step = small_time_step
        self._round: set[str] = set()

    @property
    def time(self) -> float:
        return self.plant.time

    @property
    def q(self):
        return self.plant.q

    @property
    def qd(self):
        return self.plant.qd

    def advance(self, duration: float) -> None:
        self.plant.advance(duration)

    def handle(self, bus: str, arbitration_id: int, data: bytes) -> list[tuple[int, bytes]]:
        return self.networks[bus].handle(arbitration_id, data)

    def lockstep(self, period: float | None = None) -> None:
        period = period or self.small_time_step

        def tick(name):
            self._round.add(name)
            if len(self._round) == len(self.networks):
                self._round.clear()
                self.advance(period)

        for name, network in self.networks.items():
            network.on_tick = (lambda n=name: tick(n))

    def motor(self, can_id: int, bus: str | None = None) -> CanMotor:
        networks = [self.networks[bus]] if bus else self.networks.values()
        for network in networks:
            try:
                return network.motor(can_id)
            except KeyError:
                pass
        raise KeyError(f"no motor with CAN id {can_id}")

    def inject_fault(self, can_id: int, fault: str | int = "silent") -> None:
        """From now on: "silent" (no answer), "overheat" (the winding over its limit: the motor's
        own over-temperature fault on its next step), or a status / error code latched."""
        motor = self.motor(can_id)
        if fault == "silent":
            motor.silent = True
        elif fault == "overheat":
            motor.temperature = motor.spec.temperature_limit + 1.0
        elif isinstance(fault, int) and not isinstance(fault, bool):
            motor.fault = fault
        else:
            raise ValueError(f"unknown fault {fault!r} (one of {', '.join(FAULTS[:2])}, or a status code)")

    def clear_faults(self) -> None:
        for motor in self.motors:
            motor.silent = False
