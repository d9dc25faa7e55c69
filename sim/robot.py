"""The simulated robot of any configuration: one plant, and behind each bus of the configuration the
devices that speak its wire — a chain of Dynamixel servos answering packets (sim/dynamixel, the
servos' per-tick work in C where their tables allow), or a network of CAN motors answering frames
(sim/can).

    robot = SimulatedRobot(load_config("replica_mixed"))
    port = robot.port("wrist")                      # a Dynamixel bus: what a PtyServer serves
    reply = port.handle(request_bytes)              # what its servos put on the wire
    replies = robot.port("shoulder").handle(0x001, command_bytes)   # a CAN bus: [(id, data)]
    robot.advance(1e-3)                             # the plant runs; the devices' registers follow
    robot.inject_fault(4, "silent")                 # device 4 stops answering (or "overload", ...)

Each simulated servo starts as the configuration sets it up (its ID, its bus's baud rate in its
Baud Rate register), unless a bench (sim/lab.py: `SimulatedRobot(config, bench=Lab(...))`)
says otherwise: factory-fresh devices, some of them not wired, memories kept in a store file, horns
mounted otherwise than the configuration says. `power_cycle()` switches every device off and on. Two clocks, chosen by whoever serves the robot (sim/transport): `lockstep()`
advances the plant by one control period once every bus has had the tick's commands (each CAN
network its full round of command frames, each Dynamixel chain its sync write; the last one moves
the plant), so a run is deterministic and as fast as the host can go; otherwise the server advances
it by the wall clock, and `wall_clock()` puts the servos' own clocks (Bus Watchdog, Realtime Tick)
on it too, so a host that dies is noticed in real time even when the plant falls behind. A port's
`wire_clock()` times the bytes as a servo's receiver does (a frame with a gap over 1.5 ms between
bytes is dropped). Every transport serving the robot takes `robot.lock` around it.

The arm it runs is the configuration's unless its `[sim]` table says otherwise (hal/plant_spec.py's
PlantSpec, hal/README.md): then the plant's model is `[sim]`'s (masses scaled, armatures, a
payload), and each joint's device gives `torque_constant_scale` × the configured torque constant
per ampere (while it reports the current it draws), has the joint's friction instead of its own
small built-in one (sim/plant.py's JointFriction), and its winding the thermal constants given.
Dynamixel servos heat by the validator's winding model (hal/thermal.py) once a control period on
their mean I², and report it in Present Temperature; CAN motors heat themselves every step.

Contact (sim/contact.py): obstacles there from the start (`SimulatedRobot(config, obstacles=[...])`)
and pushes scheduled on the plant's clock (`schedule_push(push, origin)`); `status()["contact"]`
summarizes what was applied (None when the robot has neither), `contact_log()` gives it row by row.
"""

from __future__ import annotations

import dataclasses
import threading
import time as _time

import numpy as np

from servodyn.control.timing import plant_step
from servodyn.errors import InputError
from servodyn.hal.config import RobotConfig
from servodyn.hal.dynamixel.control_table import HARDWARE_FAULTS
from servodyn.hal.dynamixel.reader import BYTE_TIMEOUT
from servodyn.hal.thermal import AMBIENT

from .lab import Lab, require
from .can import CanMotor, CanNetwork
from .contact import LOG_COLUMNS, Contacts
from .dynamixel import Servo, ServoChain, DynamixelWire
from .feetech import FeetechServo, FeetechWire
from .feetech.servo import FAULT_BITS as FEETECH_FAULTS
from .dynamixel.servo1 import Dynamixel1Servo
from .dynamixel.wire1 import Dynamixel1Wire, Wire1Fault
from servodyn.hal.dynamixel.protocol1 import HARDWARE_FAULTS as PROTOCOL1_FAULTS
from .faults import CAN_WIRE_FAULTS, WIRE_FAULTS, WireFault
from .plant import JointFriction, Plant, PlantView

PUSHED = 0.5     # rad beyond its upper limit an external push moves a joint ("pushed"): past
                 # the host's and the firmware's range margins (0.05, 0.35 rad)
HEAT_PERIOD = 0.01   # s: the Dynamixel servos' windings are stepped on their mean I² this often (their
                     # time constants are minutes; Present Temperature counts whole degrees)
FAULTS = tuple(dict.fromkeys(("silent", "pushed", "overheat", *HARDWARE_FAULTS, *FEETECH_FAULTS, *PROTOCOL1_FAULTS,
                               *WIRE_FAULTS,
                               *CAN_WIRE_FAULTS)))


class SimulatedRobot(PlantView):
    """Every device and the plant of a robot configuration; q in the model's dof order."""

    def __init__(self, config: RobotConfig, *, small_time_step: float | None = None, q0=None,
                 integrator: str = "rk4", bench: Lab | None = None, obstacles=()):
        kinds = {bus.kind for bus in config.buses.values()}
        if not kinds <= {"can", "dynamixel", "feetech"}:
            raise InputError(f"'{config.name}': the simulator serves Dynamixel, Feetech and CAN buses "
                             f"(this configuration has {', '.join(sorted(kinds))})")
        self.config = config
        self.model = config.plant.model if config.plant is not None else config.model
        self.joints = [next(j for j in config.joints if j.dof == name) for name in self.model.dof_names]
        voltage = config.supply.voltage if config.supply else None
        self.bench = bench.set_up(config, self.joints) if bench is not None else None
        self.drives = [self._device(j, config.buses[j.bus], voltage, self.bench) for j in self.joints]
        for joint, drive in zip(self.joints, self.drives):
            self._as_plant(joint, drive)
        self.servos = [d for d in self.drives if isinstance(d, Servo)]
        self._heated = [(d, k) for k, d in enumerate(self.drives) if isinstance(d, (Servo, FeetechServo, Dynamixel1Servo))]   # heat()ed
        self._unheated = 0.0               # s the plant ran since the servos' windings were stepped
        self.motors = [d for d in self.drives if isinstance(d, CanMotor)]
        wired = lambda j: self.bench is None or j.dof in self.bench.connected
        on_bus = lambda name: [d for d, j in zip(self.drives, self.joints) if j.bus == name and wired(j)]
        # the fast chain: the plant's drives and a bus's servos at once, when one bus holds them all
        chain = ServoChain.of(self.drives) if len(self.servos) == len(self.drives) else None
        small_time_step = small_time_step or plant_step(config.control_period)   # RK4 step
        # the plant turns each horn as it is mounted: the bench's mounting, else the configuration's
        mounted = self.joints if self.bench is None else [
            dataclasses.replace(j, direction=self.bench.mounting[j.dof].direction,
                                zero_offset=self.bench.mounting[j.dof].zero_offset) for j in self.joints]
        self.plant = Plant(self.model, mounted, self.drives, small_time_step=small_time_step, q0=q0,
                           integrator=integrator, chain=chain if chain is not None and chain.covers(self.drives)
                           else None, friction=self._friction())
        # the servos' clock is the plant's until wall_clock(); no byte timeout until a port's wire_clock()
        self._servo_clock = lambda: self.plant.time
        self.chains = {name: DynamixelWire(on_bus(name), clock=lambda: self._servo_clock(), byte_timeout=None,
                                        chain=chain if chain is not None and chain.covers(on_bus(name)) else None)
                       for name, b in config.buses.items() if b.kind == "dynamixel" and b.protocol != 1.0}
        self.chains.update({name: Dynamixel1Wire(on_bus(name)) for name, b in config.buses.items()
                            if b.kind == "dynamixel" and b.protocol == 1.0})
        self.chains.update({name: FeetechWire(on_bus(name)) for name, b in config.buses.items() if b.kind == "feetech"})
        self.networks = {name: CanNetwork(on_bus(name)) for name, b in config.buses.items() if b.kind == "can"}
        self.wire: dict[str, WireFault | None] = {name: None for name in self.chains}   # a Dynamixel wire's fault
        self.small_time_step = small_time_step
        self.period = config.control_period      # s: one tick of the host (lock-step)
        self.lock = threading.RLock()
        self._round: set[str] = set()
        if self.bench is not None:
            self.bench.attach({j.dof: d for j, d in zip(self.joints, self.drives)},
                              {j.dof: config.buses[j.bus].kind for j in self.joints})
        self.contacts: Contacts | None = None
        if obstacles:
            self.contacts = self.plant.wrenches = Contacts(self.model, obstacles)

    def _contacts(self) -> Contacts:
        """The plant's contact models, made and hooked to the plant on first use."""
        if self.contacts is None:
            self.contacts = self.plant.wrenches = Contacts(self.model)
        return self.contacts

    def schedule_push(self, push, origin: float = 0.0) -> None:
        """A push (hal/contact_spec.Push) from `origin` + push.start on the plant's clock (s)."""
        self._contacts().schedule(push, origin)

    def contact_log(self) -> dict:
        """Every contact applied so far, row by row (Contacts.table); no rows without contact."""
        return self.contacts.table() if self.contacts is not None else {"columns": list(LOG_COLUMNS), "rows": []}

    @staticmethod
    def _device(joint, bus, voltage, bench=None):
        """A joint's device, set up as the configuration says (its id; a servo's bus baud rate),
        or as the bench has it (factory-fresh, or the store's memory)."""
        if bus.kind == "can":
            def configured():
                return CanMotor(joint.servo, joint.id, dialect=joint.options["dialect"],
                                feedback_id=joint.options["feedback_id"], ranges=joint.options["ranges"],
                                supply_voltage=voltage)

            def fresh():
                return CanMotor.factory_fresh(joint.servo, dialect=joint.options["dialect"], supply_voltage=voltage)
            kind, what = CanMotor, "CAN motors"
        elif bus.kind == "feetech":
            def configured():
                return FeetechServo(joint.servo, joint.id, baud=bus.baud, supply_voltage=voltage, temperature=AMBIENT)

            def fresh():
                return FeetechServo.factory_fresh(joint.servo, supply_voltage=voltage, temperature=AMBIENT)
            kind, what = FeetechServo, "Feetech servos"
        elif bus.protocol == 1.0:
            def configured():
                return Dynamixel1Servo(joint.servo, joint.id, baud=bus.baud, supply_voltage=voltage,
                                       temperature=AMBIENT)

            def fresh():
                return Dynamixel1Servo.factory_fresh(joint.servo, supply_voltage=voltage, temperature=AMBIENT)
            kind, what = Dynamixel1Servo, "Dynamixel 1.0 servos"
        else:
            def configured():
                return Servo(joint.servo, joint.id, position=0.0, zero_ticks=0, baud=bus.baud, temperature=AMBIENT,
                             supply_voltage=voltage or 12.0)

            def fresh():
                return Servo.factory_fresh(joint.servo, position=0.0, zero_ticks=0, temperature=AMBIENT,
                                           supply_voltage=voltage or 12.0)
            kind, what = Servo, "Dynamixel servos"
        if bench is None:
            return configured()
        return bench.device(joint.dof, bus.kind, what, fresh, configured, kind)

    def _as_plant(self, joint, drive) -> None:
        """The device as the plant's joint really is ([sim.joint.<dof>]); without [sim], as it is made."""
        plant = self.config.plant
        if plant is None:
            return
        spec = plant.joints[joint.dof]
        torque_constant = spec.torque_constant_scale * joint.configured_torque_constant
        thermal = (spec.thermal_resistance, spec.thermal_time_constant) if spec.thermal_resistance is not None \
            else drive.thermal
        drive.thermal = thermal
        if isinstance(drive, CanMotor):
            drive.torque_constant = torque_constant
            if spec.has_friction:
                drive.viscous = drive.coulomb = 0.0
        else:
            # an X-series servo's k_t is the configured one; a servo with an identified motor (Feetech,
            # Protocol 1.0) keeps its own: each as [sim] scales it
            kt = spec.torque_constant_scale * drive.mechanics.torque_constant \
                if isinstance(drive, (FeetechServo, Dynamixel1Servo)) else torque_constant
            friction = {"viscous_friction": 0.0, "coulomb_friction": 0.0} if spec.has_friction else {}
            drive.mechanics = dataclasses.replace(drive.mechanics, torque_constant=kt, **friction)

    def _friction(self) -> JointFriction | None:
        """The joints' friction of a [sim] plant that gives any (None: the devices' own only)."""
        plant = self.config.plant
        if plant is None or not any(plant.joints[d].has_friction for d in self.model.dof_names):
            return None
        specs = [plant.joints[d] for d in self.model.dof_names]
        coulomb = np.array([s.friction_coulomb or 0.0 for s in specs])
        static = np.array([s.friction_static if s.friction_static is not None else c for s, c in zip(specs, coulomb)])
        return JointFriction(coulomb=coulomb, viscous=np.array([s.friction_viscous or 0.0 for s in specs]),
                             static=static, stribeck=np.array([s.stribeck_velocity for s in specs]))

    # --- the buses --------------------------------------------------------------------------------

    def port(self, bus: str | None = None) -> "DynamixelPort | CanPort":
        """One bus of the robot as its transport serves it (default: the only bus, or the first)."""
        name = bus or next(iter(self.config.buses))
        if name in self.chains:
            return DynamixelPort(self, name)
        if name in self.networks:
            return CanPort(self, name)
        raise KeyError(f"'{self.config.name}' has no bus {name!r} (buses: {', '.join(self.config.buses)})")

    def advance(self, duration: float) -> None:
        """Run the plant; the servos' clocks (bus watchdog, Realtime Tick) follow."""
        self.plant.advance(duration)
        self._unheated += duration
        if self._unheated >= HEAT_PERIOD:
            elapsed, self._unheated = self._unheated, 0.0
            heat = self.plant.take_heat() / elapsed                   # mean I² meanwhile
            for servo, k in self._heated:
                servo.heat(heat[k], elapsed)
        self.tick()

    def tick(self) -> None:
        """The servos' clocks to now (the plant's or the wall clock's), the plant held."""
        for chain in self.chains.values():
            chain.tick()

    def wall_clock(self) -> None:
        """The servos' clocks (Bus Watchdog, Realtime Tick) follow the wall clock from now on (its
        seconds since this call plus the plant's time now), not the plant's."""
        offset = _time.monotonic() - self.plant.time
        self._servo_clock = lambda: _time.monotonic() - offset

    def lockstep(self, period: float | None = None) -> None:
        """Advance the plant by `period` (default the control period) once every bus has ended a
        tick's commands (a Dynamixel chain its command transaction, a CAN network its round)."""
        period = period or self.period
        buses = len(self.networks) + len(self.chains)

        def tick(name):
            self._round.add(name)
            if len(self._round) == buses:
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

    def status(self) -> dict:
        """The plant's time (s), whether each device's torque is off (in the model's dof order), and
        the contact applied so far (Contacts.status; None without pushes or obstacles)."""
        return {"time": self.time, "torque_off": [not d.torque_enabled for d in self.drives],
                "contact": self.contacts.status() if self.contacts is not None else None}

    def power_cycle(self) -> None:
        """Every device switched off and on (the bench's Device.power_cycle: volatile state to its
        defaults, torque off, the non-volatile memory kept); a frame a receiver was taking in is
        lost. The plant goes on: the arm falls limp. ValueError (one line) for a kind of device
        that cannot."""
        for drive in self.drives:
            require(type(drive), "CAN motors" if isinstance(drive, CanMotor) else type(drive).__name__)
        for drive in self.drives:
            drive.power_cycle()
        for chain in self.chains.values():
            chain.reader.expire()

    def device(self, dof: str):
        """The device in `dof`'s slot (wired to its bus or not)."""
        for joint, drive in zip(self.joints, self.drives):
            if joint.dof == dof:
                return drive
        raise KeyError(f"'{self.config.name}' has no dof {dof!r}")

    # --- the devices --------------------------------------------------------------------------------

    def servo(self, servo_id: int, bus: str | None = None) -> Servo:
        for name, chain in self.chains.items():
            if bus in (None, name):
                try:
                    return chain.servo(servo_id)
                except (KeyError, ValueError, LookupError):
                    pass
        raise KeyError(f"no Dynamixel servo with id {servo_id}")

    def motor(self, can_id: int, bus: str | None = None) -> CanMotor:
        for name, network in self.networks.items():
            if bus in (None, name):
                try:
                    return network.motor(can_id)
                except KeyError:
                    pass
        raise KeyError(f"no motor with CAN id {can_id}")

    def inject_fault(self, device_id: int, fault: str | int = "silent") -> None:
        """From now on, on the device with this id (a Dynamixel servo first, then a CAN motor):
        "silent" (it stops answering); "pushed" (an external push moves its joint PUSHED rad beyond
        the configuration's upper limit); a Dynamixel servo: Hardware Error Status bits by name
        ("overload", "overheating", ...) or as an int, a Feetech servo its Status bits by name ("voltage",
        "encoder", "temperature", "current", "overload", or the Dynamixel names) or "overheat" (its
        winding past its limit), either a fault of its bus's wire (sim/faults.py:
        "flipped_byte", "garbage", "delayed_reply", "wrong_id", "stall"); a CAN motor: "overheat"
        (the winding over its limit: its own over-temperature fault on its next step), a status or
        error code as an int, or a fault of its wire ("garbage", "wrong_id", "error_frame", "bus_off")."""
        if isinstance(fault, str) and fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r} (one of {', '.join(FAULTS)})")
        k = next((k for k, j in enumerate(self.joints) if j.id == device_id), None)
        if fault == "pushed":
            if k is None:
                raise KeyError(f"no device with id {device_id}")
            self.plant.push(k, self.joints[k].position_limits[1] + PUSHED)
            return
        try:
            servo = self.servo(device_id)
        except KeyError:
            servo = None
        if servo is not None:
            bus = next(name for name, chain in self.chains.items() if servo in chain.servos)
            if fault == "silent":
                servo.silent = True
            elif fault in WIRE_FAULTS:
                if isinstance(servo, Dynamixel1Servo):
                    self.wire[bus] = Wire1Fault(fault, len(self.chains[bus].servos), seed=device_id)
                else:
                    self.wire[bus] = WireFault(fault, len(self.chains[bus].servos), seed=device_id,
                                               protocol=self.config.buses[bus].kind)
            elif isinstance(fault, int) and not isinstance(fault, bool):
                servo.set_hardware_error(fault)
            elif isinstance(servo, FeetechServo) and fault == "overheat":
                servo.overheat()
            elif fault in (bits := FEETECH_FAULTS if isinstance(servo, FeetechServo) else
                           PROTOCOL1_FAULTS if isinstance(servo, Dynamixel1Servo) else HARDWARE_FAULTS):
                servo.set_hardware_error(bits[fault])
            else:
                raise ValueError(f"a {type(servo).__name__} takes no {fault!r} fault")
            return
        motor = self.motor(device_id)
        if fault == "silent":
            motor.silent = True
        elif fault == "overheat":
            motor.temperature = motor.spec.temperature_limit + 1.0
        elif fault in CAN_WIRE_FAULTS:
            network = next(n for n in self.networks.values() if motor in n.motors)
            network.inject(device_id, fault, seed=device_id * 1_000_003 + round(self.time / self.small_time_step))
        elif isinstance(fault, int) and not isinstance(fault, bool):
            motor.fault = fault
        else:
            raise ValueError(f"a CAN motor takes no {fault!r} fault")

    def clear_faults(self) -> None:
        """Every device answers again, every wire is clean (hardware errors stay until a reboot,
        as on a real servo)."""
        for drive in self.drives:
            drive.silent = False
        for name in self.wire:
            self.wire[name] = None
        for network in self.networks.values():
            network.wire.clear()


class _Port(PlantView):
    """One bus of a SimulatedRobot, as a transport serves it; the rest is the robot's."""

    def __init__(self, robot: SimulatedRobot, bus: str):
        self.robot, self.name, self.plant = robot, bus, robot.plant
        self.small_time_step, self.period, self.lock = robot.small_time_step, robot.period, robot.lock

    def __getattr__(self, name):          # advance, tick, lockstep, wall_clock, inject_fault, status, ...
        return getattr(self.robot, name)


class DynamixelPort(_Port):
    """A Dynamixel bus: bytes in, the servos' replies out (with its wire's fault, if any)."""

    @property
    def bus(self) -> DynamixelWire:
        return self.robot.chains[self.name]

    @property
    def servos(self) -> list[Servo]:
        return self.bus.servos

    def servo(self, servo_id: int) -> Servo:
        return self.robot.servo(servo_id, self.name)

    @property
    def baud(self) -> int:
        """The bus's speed as the configuration gives it (bit/s)."""
        return self.robot.config.buses[self.name].baud

    def hear_at(self, speed: int | None) -> None:
        """The host's bytes come at `speed` (bit/s) from now on: only the servos listening at it hear
        them (DynamixelWire.line_speed; None: every servo)."""
        self.bus.line_speed = speed

    def handle(self, data: bytes) -> bytes:
        reply = self.bus.handle(data)
        wire = self.robot.wire[self.name]
        return reply if wire is None else wire.apply(reply)

    def wire_clock(self, clock=_time.monotonic) -> None:
        """The host's bytes come over a real-time wire: a frame whose bytes arrive more than
        BYTE_TIMEOUT apart on `clock` is dropped, as a servo does, so a truncated frame cannot
        swallow the next packet."""
        self.bus.reader.byte_timeout = BYTE_TIMEOUT
        self.bus.wire_clock = clock


class CanPort(_Port):
    """A CAN bus: a frame in, the frames the motors answer out."""

    @property
    def network(self) -> CanNetwork:
        return self.robot.networks[self.name]

    @property
    def motors(self) -> list[CanMotor]:
        return self.network.motors

    def handle(self, arbitration_id: int, data: bytes) -> list[tuple[int, bytes]]:
        return self.network.handle(arbitration_id, data)
