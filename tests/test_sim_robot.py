"""One simulated robot for every configuration (sim/robot.py): its devices set up as the
configuration says, every fault class of both buses on one class, and one way to serve it
(servodyn.sim.serve.serve)."""

from __future__ import annotations

import pytest

from servodyn.hal.config import load_config
from servodyn.hal.dynamixel.control_table import BAUD_RATES
from servodyn.sim.can import CanMotor
from servodyn.sim.dynamixel import Servo
from servodyn.sim.faults import CAN_WIRE_FAULTS, WIRE_FAULTS
from servodyn.sim.robot import FAULTS, SimulatedRobot
from servodyn.sim.serve import SimProcess, serve


@pytest.mark.parametrize("name", ["replica", "replica_can", "replica_mixed"])
def test_every_configuration_is_one_simulated_robot(name):
    config = load_config(name)
    robot = SimulatedRobot(config)
    kinds = {j.dof: config.buses[j.bus].kind for j in config.joints}
    for joint, drive in zip(robot.joints, robot.drives):
        expected = Servo if kinds[joint.dof] == "dynamixel" else CanMotor
        assert isinstance(drive, expected), f"{joint.dof}: a {expected.__name__} on its {kinds[joint.dof]} bus"
    for bus_name, bus in config.buses.items():
        port = robot.port(bus_name)
        if bus.kind == "dynamixel":
            for servo in port.servos:
                assert servo.get("baud_rate") == BAUD_RATES.index(bus.baud), \
                    f"servo {servo.id}'s Baud Rate register reads its bus's {bus.baud} baud, not a new servo's 57600"
    assert robot.status()["torque_off"] == [True] * len(robot.drives), "every device starts with torque off"


def test_one_robot_takes_every_fault_class_of_both_buses():
    """replica_mixed: CAN motors 1-4, Dynamixel servos 5-7; each fault lands where it belongs."""
    robot = SimulatedRobot(load_config("replica_mixed"))
    assert set(WIRE_FAULTS) <= set(FAULTS) and set(CAN_WIRE_FAULTS) <= set(FAULTS), "both buses' wire faults"
    robot.inject_fault(6, "flipped_byte")
    wrist = next(name for name, bus in robot.config.buses.items() if bus.kind == "dynamixel")
    assert robot.wire[wrist] is not None, "a Dynamixel wire fault on the servos' bus"
    robot.inject_fault(2, "error_frame")
    assert robot.motor(2) and any(n.wire for n in robot.networks.values()), "a CAN wire fault on the motors' bus"
    robot.inject_fault(5, "overload")
    assert robot.servo(5).get("hardware_error_status") != 0, "a servo's hardware error bits"
    robot.inject_fault(3, "overheat")
    assert robot.motor(3).temperature > robot.motor(3).spec.temperature_limit, "a motor over its limit"
    with pytest.raises(ValueError, match="takes no 'overheat'"):
        robot.inject_fault(7, "overheat")
    with pytest.raises(ValueError, match="unknown fault"):
        robot.inject_fault(7, "melted")
    robot.clear_faults()
    assert robot.wire[wrist] is None and not any(n.wire for n in robot.networks.values()), "clean wires again"


def test_serve_puts_each_bus_behind_its_transport():
    """A configuration file of one Dynamixel bus: a process of its own; CAN or several buses: this
    process, each bus's backend options (a pty path, a python-can bus) given."""
    single = serve(load_config("replica"), "lockstep")
    try:
        assert isinstance(single, SimProcess) and single.buses[single.bus]["port"].startswith("/dev/pts/")
        assert single.status()["time"] == 0.0, "the plant at rest until the host commands"
    finally:
        single.stop()
    mixed = serve(load_config("replica_mixed"), "lockstep")
    try:
        kinds = {name: bus.kind for name, bus in mixed.robot.config.buses.items()}
        for name, options in mixed.buses.items():
            assert ("can_bus" in options) == (kinds[name] == "can"), f"bus '{name}': {options}"
            assert options["reply_timeout"] > 0
        assert len(mixed.status()["torque_off"]) == 7
    finally:
        mixed.stop()
