"""The simulated robot of a configuration with CAN buses, alone or beside Dynamixel buses: one
plant, and behind each bus the devices that speak its wire — a network of CAN motors answering
frames, or a chain of Dynamixel servos answering packets (sim/dynamixel).

    robot = SimulatedRobot(load_config("replica_mixed"))
    replies = robot.handle("shoulder", 0x001, command_bytes)   # [(id, data)] the CAN motors answer
    port = robot.dynamixel_port("wrist")                       # what a PtyServer serves
    robot.inject_fault(4, "silent")                            # or "overheat", a status code, a bit name

Lock-step: the plant advances one control period once every bus has had the tick's commands (each
CAN network its full round of command frames, each Dynamixel chain its sync write); the last one
moves the plant. Every transport serving the robot takes `robot.lock` around it.
"""

from __future__ import annotations

import threading
import time as _time

from servodyn.control.timing import plant_step
from servodyn.hal.config import RobotConfig
from servodyn.hal.dynamixel.control_table import HARDWARE_FAULTS
from servodyn.hal.dynamixel.reader import BYTE_TIMEOUT

from .arm import PUSHED
from .can import CanMotor, CanNetwork
from .dynamixel import Servo, VirtualBus
from .faults import CAN_WIRE_FAULTS
from .plant import Plant, PlantView

FAULTS = ("silent", "overheat", "pushed", *HARDWARE_FAULTS, *CAN_WIRE_FAULTS)


class SimulatedRobot(PlantView):
    def __init__(self, config: RobotConfig, *, small_time_step: float | None = None, q0=None,
                 integrator: str = "rk4"):
        kinds = {bus.kind for bus in config.buses.values()}
        if not kinds <= {"can", "dynamixel"} or "can" not in kinds:
            raise ValueError(f"'{config.name}': this simulator serves CAN buses, alone or with Dynamixel buses "
                             f"(this configuration has {', '.join(sorted(kinds))})")
        self.config, self.model = config, config.model
        self.joints = [next(j for j in config.joints if j.dof == name) for name in self.model.dof_names]
        voltage = config.supply.voltage if config.supply else None
        self.drives = []
        for j in self.joints:
            if config.buses[j.bus].kind == "can":
                self.drives.append(CanMotor(j.servo, j.id, dialect=j.options["dialect"],
                                            feedback_id=j.options["feedback_id"], ranges=j.options["ranges"],
                                            supply_voltage=voltage))
            else:
                self.drives.append(Servo(j.servo, j.id, position=0.0, zero_ticks=0))
        self.motors = [d for d in self.drives if isinstance(d, CanMotor)]
        self.servos = [d for d in self.drives if isinstance(d, Servo)]
        small_time_step = small_time_step or plant_step(config.control_period)   # RK4 step
        self.plant = Plant(self.model, self.joints, self.drives, small_time_step=small_time_step, q0=q0,
                           integrator=integrator)
        on_bus = lambda name: [d for d, j in zip(self.drives, self.joints) if j.bus == name]
        self.networks = {name: CanNetwork(on_bus(name)) for name, b in config.buses.items() if b.kind == "can"}
        # the servos' clock is the plant's until wall_clock() (as sim/arm.py's)
        self._servo_clock = lambda: self.plant.time
        self.chains = {name: VirtualBus(on_bus(name), clock=lambda: self._servo_clock(), byte_timeout=None)
                       for name, b in config.buses.items() if b.kind == "dynamixel"}
        self.small_time_step = small_time_step
        self.period = config.control_period      # s: one tick of the host (lock-step)
        self.lock = threading.RLock()
        self._round: set[str] = set()

    def advance(self, duration: float) -> None:
        self.plant.advance(duration)
        for chain in self.chains.values():
            chain.tick()

    def wall_clock(self) -> None:
        """The Dynamixel servos' clocks (Bus Watchdog) follow the wall clock from now on."""
        offset = _time.monotonic() - self.plant.time
        self._servo_clock = lambda: _time.monotonic() - offset

    def handle(self, bus: str, arbitration_id: int, data: bytes) -> list[tuple[int, bytes]]:
        return self.networks[bus].handle(arbitration_id, data)

    def lockstep(self, period: float | None = None) -> None:
        period = period or self.period

        def tick(name):
            self._round.add(name)
            if len(self._round) == len(self.networks) + len(self.chains):
                self._round.clear()
                self.advance(period)

        for name, network in self.networks.items():
            network.on_tick = (lambda n=name: tick(n))
        for name, chain in self.chains.items():
            chain.on_command = (lambda n=name: tick(n))

    def free_running(self) -> None:
        """No lock-step: the plant moves only when advance() is called (a real-time clock)."""
        for network in self.networks.values():
            network.on_tick = None
        for chain in self.chains.values():
            chain.on_command = None

    def dynamixel_port(self, bus: str) -> "DynamixelPort":
        return DynamixelPort(self, bus)

    def motor(self, can_id: int, bus: str | None = None) -> CanMotor:
        networks = [self.networks[bus]] if bus else self.networks.values()
        for network in networks:
            try:
                return network.motor(can_id)
            except KeyError:
                pass
        raise KeyError(f"no motor with CAN id {can_id}")

    def inject_fault(self, device_id: int, fault: str | int = "silent") -> None:
        """From now on, on the CAN motor or Dynamixel servo with this id (the first found):
        "silent" (no answer); a CAN motor: "overheat" (the winding over its limit: the motor's own
        over-temperature fault on its next step) or a status / error code latched; a servo:
        Hardware Error Status bits by name ("overload", ...) or as an int; either: "pushed" (an
        external push moves its joint PUSHED rad beyond its upper limit); a CAN motor's bus: a fault
        of the wire (sim/faults.py: "garbage", "wrong_id", "error_frame", "bus_off")."""
        if fault == "pushed":
            k = next((k for k, j in enumerate(self.joints) if j.id == device_id), None)
            if k is None:
                raise KeyError(f"no device with id {device_id}")
            self.plant.push(k, self.joints[k].position_limits[1] + PUSHED)
            return
        if fault in CAN_WIRE_FAULTS:
            network = next((n for n in self.networks.values() if any(m.can_id == device_id for m in n.motors)), None)
            if network is None:
                raise KeyError(f"no CAN motor with id {device_id}")
            network.inject(device_id, fault, seed=device_id * 1_000_003 + round(self.time / self.small_time_step))
            return
        for chain in self.chains.values():
            try:
                servo = chain.servo(device_id)
            except (KeyError, ValueError, LookupError):
                continue
            if fault == "silent":
                servo.silent = True
            elif fault in HARDWARE_FAULTS:
                servo.set_hardware_error(HARDWARE_FAULTS[fault])
            elif isinstance(fault, int):
                servo.set_hardware_error(fault)
            else:
                raise ValueError(f"unknown fault {fault!r} (one of {', '.join(FAULTS)})")
            return
        motor = self.motor(device_id)
        if fault == "silent":
            motor.silent = True
        elif fault == "overheat":
            motor.temperature = motor.spec.temperature_limit + 1.0
        elif isinstance(fault, int) and not isinstance(fault, bool):
            motor.fault = fault
        else:
            raise ValueError(f"unknown fault {fault!r} (one of {', '.join(FAULTS[:2])}, or a status code)")

    def clear_faults(self) -> None:
        for drive in self.drives:
            drive.silent = False
        for network in self.networks.values():
            network.wire.clear()


class DynamixelPort:
    """One Dynamixel bus of a SimulatedRobot as sim/transport/pty.py's PtyServer serves an arm."""

    def __init__(self, robot: SimulatedRobot, bus: str):
        self.robot, self.chain = robot, robot.chains[bus]
        self.small_time_step, self.period, self.lock = robot.small_time_step, robot.period, robot.lock

    @property
    def time(self) -> float:
        return self.robot.time

    def handle(self, data: bytes) -> bytes:
        return self.chain.handle(data)

    def wall_clock(self) -> None:
        self.robot.wall_clock()

    def wire_clock(self, clock=_time.monotonic) -> None:
        """A frame whose bytes arrive more than BYTE_TIMEOUT apart on `clock` is dropped."""
        self.chain.reader.byte_timeout = BYTE_TIMEOUT
        self.chain.wire_clock = clock

    def advance(self, duration: float) -> None:
        self.robot.advance(duration)

    def lockstep(self, period: float | None = None) -> None:
        self.robot.lockstep(period)

    def inject_fault(self, device_id: int, fault="silent") -> None:
        self.robot.inject_fault(device_id, fault)

    def clear_faults(self) -> None:
        self.robot.clear_faults()
