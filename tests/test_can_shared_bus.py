"""A real CAN bus is shared and imperfect: what another node or the adapter puts on it is never
taken for a motor's reply. Against the simulated replica_can on python-can's virtual bus, with a
second node on the same channel that sends what a shared bus carries: 29-bit, CAN FD and remote
frames on the motors' reply ids (a fault status in their bytes), a controller's warning, no ACK."""

import itertools
import tomllib

import can
import numpy as np
import pytest

from servodyn.hal.bus import JointCommand, make_bus
from servodyn.hal.can import frames
from servodyn.hal.config import config_from_dict, load_config
from servodyn.hal.can.spec import interface_for
from servodyn.hal.errors import ConfigError, ServoInitializationError, ServoOperationError
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.can import VirtualCanServer

PATIENT = 0.5
CHANNELS = (f"test-can-shared-{k}" for k in itertools.count())
# a Damiao reply of motor 1 on its feedback id 0x11 whose status nibble says "overcurrent" (0x9):
# taken for a reply, it would stop a swing with a fault the motor never sent
FAULTY = bytes([0x91, 0x80, 0x00, 0x80, 0x08, 0x00, 30, 30])


@pytest.fixture
def shared():
    config = load_config("replica_can")
    robot = SimulatedRobot(config)
    channel = next(CHANNELS)
    server = VirtualCanServer(robot.port(), channel, mode="lockstep")
    server.start()
    host = can.Bus(interface="virtual", channel=channel)
    other = can.Bus(interface="virtual", channel=channel)
    bus = make_bus(config, can_bus=host, reply_timeout=PATIENT)
    bus.open()
    yield bus, other
    bus.stop()
    server.stop()
    other.shutdown()
    host.shutdown()


def tick(bus):
    state = bus.read_state()
    bus.write(JointCommand.torque(np.zeros(bus.n)))
    return state


def test_extended_fd_and_remote_frames_are_never_a_reply(shared):
    bus, other = shared
    tick(bus)
    for message in (can.Message(arbitration_id=0x11, data=FAULTY, is_extended_id=True),
                    can.Message(arbitration_id=0x11, data=FAULTY, is_fd=True, is_extended_id=False),
                    can.Message(arbitration_id=0x11, is_remote_frame=True, dlc=8, is_extended_id=False)):
        other.send(message)
    for _ in range(5):
        state = tick(bus)
    assert np.isfinite(state.q).all(), "the run goes on: none of the three frames stopped it as a fault"
    assert bus.foreign == 3, f"each counted as no motor's reply ({bus.foreign})"


def test_a_warning_is_counted_and_no_ack_stops_with_what_to_check(shared):
    bus, other = shared
    tick(bus)
    other.send(can.Message(arbitration_id=frames.CAN_ERR_CRTL, data=bytes([0, 0x08, 0, 0, 0, 0, 0, 0]),
                           is_error_frame=True))
    tick(bus)
    tick(bus)
    assert bus.warnings == 1, "a controller's tx warning is counted, the run goes on"
    other.send(can.Message(arbitration_id=frames.CAN_ERR_ACK, data=bytes(8), is_error_frame=True))
    with pytest.raises(ServoOperationError, match=r"no ACK .*unpowered.*bitrate.*terminators"):
        for _ in range(3):
            tick(bus)


def test_error_frame_classes():
    stops, text = frames.error_frame(frames.CAN_ERR_BUSOFF | frames.CAN_ERR_CRTL, bytes([0, 0x20, 0, 0, 0, 0, 0, 0]))
    assert stops and "bus-off" in text and "tx error-passive" in text, text
    stops, text = frames.error_frame(frames.CAN_ERR_CRTL, bytes([0, 0x04, 0, 0, 0, 0, 0, 0]))
    assert not stops and text == "controller: rx warning", "a warning alone does not stop a run"
    assert frames.error_frame(0, b"")[0], "an error frame of no known class stops (nothing vouches for the bus)"


def test_a_bus_without_joints_is_refused_at_load():
    """It passed the validator and ended a swing in an IndexError in the CAN backend."""
    config = load_config("replica_can")
    data = tomllib.loads(config.path.read_text())
    (name,) = data["bus"]
    for joint in data["joint"]:
        joint["bus"] = name
    data["bus"]["spare"] = {"kind": "can", "channel": "can1"}
    with pytest.raises(ConfigError, match=r"bus 'spare' has no joint"):
        config_from_dict(data, "spare.toml", base=config.path.parent)


@pytest.mark.parametrize("channel, configured, expected", [
    ("can0", "slcan", "socketcan"), ("vcan3", None, "socketcan"), ("/dev/ttyACM0", "socketcan", "slcan"),
    ("PCAN_USBBUS1", "pcan", "pcan"), ("servodyn-x", "virtual", "virtual"), (None, None, "slcan")])
def test_the_channel_names_its_interface(channel, configured, expected):
    """`swing --config replica_can --port can0` opened a file named can0 (slcan won)."""
    assert interface_for(channel, configured) == expected


def test_port_can0_opens_socketcan_not_a_file():
    bus = make_bus(load_config("replica_can"), port="can0")
    assert bus.interface == "socketcan", bus.interface
    with pytest.raises(ServoInitializationError, match=r"^socketcan can0: cannot open"):
        bus.open()          # no can0 link on this machine: one line naming the interface and the link
