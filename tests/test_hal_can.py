"""The CAN backend (hal/can/backend.py) against the simulated Damiao motors (sim/can/) on
python-can's virtual bus, in lock-step: the open sequence (registers read and checked, the CAN
timeout written), enable and stop, the tick's frames as the motors decode them, a silent motor, a
fault status, an over-temperature, the motors' CAN timeout, an explicit zero, a bus error frame;
and the simulated motor's physics (back-EMF, I²R heating)."""

import itertools
import math

import can
import numpy as np
import pytest

from servodyn.hal.bus import JointCommand, make_bus
from servodyn.hal.can import dialects, frames
from servodyn.hal.can.backend import MOTOR_CAN_TIMEOUT
from servodyn.hal.can.motors import DM_J4310, DM_J4340
from servodyn.hal.config import config_from_dict, load_config
from servodyn.hal.errors import (ConfigError, ServoHardwareError, ServoInitializationError, ServoOperationError,
                                 ServoTimeoutError)
from servodyn.sim.can import CanMotor
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.transport.can import VirtualCanServer

PATIENT = 0.5          # s: a loaded machine can hold a thread back far beyond a real bus's deadline
CHANNELS = (f"test-hal-can-{k}" for k in itertools.count())
# N m/rad, N m s/rad: replica_dm's 2.5 kg arm, behind its motors' rotors (armature 0.16 kg m² at a
# J4340: about 0.3 kg m² at the shoulder, damping ratio 0.4), within 0.05 rad in 0.3 s (measured
# 0.043; kp 10, kd 0.1 held the bare links within 0.08 rad, but ring for seconds behind the rotors)
HOLD = dict(kp=20.0, kd=2.0)


@pytest.fixture
def rig():
    """(arm, server, bus), the bus open on the simulated replica_can in lock-step."""
    config = load_config("replica_can")
    arm = SimulatedRobot(config)
    channel = next(CHANNELS)
    server = VirtualCanServer(arm.port(), channel, mode="lockstep")
    server.start()
    host = can.Bus(interface="virtual", channel=channel)
    bus = make_bus(config, can_bus=host, reply_timeout=PATIENT)
    yield arm, server, bus
    bus.stop()
    server.stop()
    host.shutdown()


def hold(bus, q, ticks):
    for _ in range(ticks):
        bus.read_state()
        bus.write(JointCommand.position(q, **HOLD))


def test_open_checks_the_registers_and_writes_the_can_timeout(rig):
    arm, _, bus = rig
    bus.open()
    units = round(MOTOR_CAN_TIMEOUT / dialects.TIMEOUT_UNIT)
    assert all(m.registers[dialects.REG_TIMEOUT] == units for m in arm.motors), \
        f"TIMEOUT register = {units} (x 50 us = {MOTOR_CAN_TIMEOUT} s) on every motor"
    assert not any(m.enabled for m in arm.motors), "open leaves the motors out of motor mode"
    assert all(m.zero == 0.0 for m in arm.motors), "open never sets a zero"


def test_a_motor_in_another_mode_is_named_at_open(rig):
    arm, _, bus = rig
    arm.motor(3).registers[dialects.REG_CTRL_MODE] = 2
    with pytest.raises(ServoInitializationError, match=r"r_shoulder_rotation.*position-velocity.*ignores MIT"):
        bus.open()


def test_ranges_that_differ_from_the_motor_registers_are_refused(rig):
    arm, _, bus = rig
    arm.motor(6).ranges = frames.Ranges(12.5, 30.0, 12.0)
    with pytest.raises(ServoInitializationError, match=r"r_wrist_flexion.*TMAX = 12.*says 10"):
        bus.open()


def test_enable_tick_and_stop(rig):
    arm, _, bus = rig
    bus.open()
    bus.enable_torque(True)
    assert all(m.enabled for m in arm.motors), "torque on: every motor in motor mode"
    q = np.array([0.1, 0.2, 0.0, 0.5, 0.0, 0.1, 0.0])
    hold(bus, q, round(0.3 / arm.period))       # 0.3 s of plant time at the configuration's period
    state = bus.read_state()
    assert np.abs(state.q - q).max() < 0.1, f"held near the target: {state.q}"
    assert arm.time == pytest.approx(0.3, abs=1e-9), "lock-step: one control period per command round"
    tau = np.array([1.0, -2.0, 0.0, 3.0, 0.0, 0.5, -0.5])
    bus.write(JointCommand.torque(tau))
    bus.read_state()          # every motor has answered, so every motor has taken its frame
    for k, motor in enumerate(arm.motors):
        step = motor.ranges.torque_step
        sign = bus.joints[k].direction
        assert motor.command.t == pytest.approx(bus.sent[k, 4]), "the motor decodes what the log records"
        assert abs(sign * motor.command.t - tau[k]) <= step, f"joint {k}: {tau[k]} N m within one code"
    assert abs(bus.sent_torque[2]) == pytest.approx(DM_J4340.ranges.t_max / 4095), \
        "a zero torque goes out as -TMAX/4095 (12-bit quantization)"
    assert bus.stop() is True and not any(m.enabled for m in arm.motors), "stop exits motor mode everywhere"


def test_a_silent_motor_names_its_joint_and_stop_still_reaches_the_others(rig):
    arm, server, bus = rig
    bus.open()
    bus.enable_torque(True)
    hold(bus, np.zeros(7) + 0.2, 5)
    server.inject_fault(5, "silent")
    with pytest.raises(ServoTimeoutError, match="r_forearm_pronation.*id 5") as err:
        hold(bus, np.zeros(7) + 0.2, 2)
    assert err.value.joint == "r_forearm_pronation"
    assert bus.stop() is False, "motor 5 never confirms"
    assert [m.enabled for m in arm.motors] == [True] * 4 + [True] + [False] * 2 or \
        [m.enabled for k, m in enumerate(arm.motors) if k != 4] == [False] * 6, "every answering motor is off"


@pytest.mark.parametrize("fault, name", [(0xA, "overcurrent"), (0xE, "overload"), (0x8, "overvoltage")])
def test_a_fault_status_raises_the_decoded_fault(rig, fault, name):
    arm, server, bus = rig
    bus.open()
    bus.enable_torque(True)
    hold(bus, np.zeros(7) + 0.2, 3)
    server.inject_fault(2, fault)
    with pytest.raises(ServoHardwareError) as err:
        hold(bus, np.zeros(7) + 0.2, 3)
    assert (err.value.joint, err.value.status, err.value.faults) == ("r_shoulder_abduction", fault, (name,))


def test_over_temperature_is_the_motors_own_fault(rig):
    arm, server, bus = rig
    bus.open()
    bus.enable_torque(True)
    hold(bus, np.zeros(7) + 0.2, 3)
    server.inject_fault(4, "overheat")
    with pytest.raises(ServoHardwareError) as err:
        hold(bus, np.zeros(7) + 0.2, 3)
    assert err.value.faults == ("coil over-temperature",) and err.value.joint == "r_elbow_flexion"
    assert bus.temperatures[3, 1] > DM_J4340.temperature_limit, "the coil temperature the motor reported"
    arm.advance(1e-3)
    assert arm.plant.current[3] == 0.0, "the faulted motor is limp"


def test_the_motors_go_limp_when_the_host_stops_sending(rig):
    """CAN timeout (TIMEOUT register, 0.1 s): the plant runs on without commands; within the
    timeout the torque is held, past it every motor is limp with status D."""
    arm, _, bus = rig
    bus.open()
    bus.enable_torque(True)
    hold(bus, np.zeros(7) + 0.3, 20)          # the motors' own PD holds the arm (kp, kd in the frames)
    bus.read_state()
    arm.advance(MOTOR_CAN_TIMEOUT - 0.01)
    assert all(m.status() == dialects.DAMIAO_ENABLED for m in arm.motors), "inside the timeout: enabled"
    assert np.all(np.abs(arm.plant.current[[0, 3]]) > 0.05), "and holding the shoulder and elbow against gravity"
    arm.advance(0.02)
    assert np.all(arm.plant.current == 0.0), f"past the timeout every current is zero: {arm.plant.current}"
    assert all(m.status() == 0xD for m in arm.motors), "status D, communication lost"
    with pytest.raises(ServoHardwareError, match="communication lost"):
        bus.read_state()


def test_zero_is_set_only_by_calibration(rig):
    arm, _, bus = rig
    arm.plant.q[:] = 0.0
    bus.open()
    bus.enable_torque(True)
    hold(bus, np.zeros(7) + 0.2, 50)
    assert all(m.zero == 0.0 for m in arm.motors), "no implicit zero"
    with pytest.raises(ServoOperationError, match="torque off"):
        bus.set_zero("r_elbow_flexion")
    bus.enable_torque(False)
    bus.set_zero("r_elbow_flexion")
    motor = arm.motor(4)
    assert motor.zero == pytest.approx(motor.position) and motor.zero != 0.0, "zero where the elbow stands"
    assert abs(bus.read_state().q[3]) < 2 * 25 / 65535, "the elbow now reads 0"


def test_an_error_frame_is_a_clear_error(rig):
    arm, server, bus = rig
    bus.open()
    bus.enable_torque(True)
    hold(bus, np.zeros(7) + 0.2, 2)
    bus.read_state()
    with can.Bus(interface="virtual", channel=server.channel) as other:
        other.send(can.Message(arbitration_id=0x20000080, is_error_frame=True, data=bytes(8)))
        with pytest.raises(ServoOperationError, match="error frame"):
            bus.write(JointCommand.position(np.zeros(7) + 0.2, **HOLD))
            bus.read_state()
        other.send(can.Message(arbitration_id=0x20000080, is_error_frame=True, data=bytes(8)))
    assert bus.stop() is True, "the safe stop, with another error frame waiting, still reaches every motor"
    assert not any(m.enabled for m in arm.motors), "every motor out of motor mode"


def test_back_emf_leaves_no_driving_torque_at_the_no_load_speed():
    motor = CanMotor(DM_J4310, 1)
    motor.enabled = True
    motor.command = frames.Command(0.0, 0.0, 0.0, 0.0, 5.0)
    w0 = DM_J4310.no_load_speed
    assert motor.output_current(0.0, 0.0, 1e-3) * DM_J4310.torque_constant == pytest.approx(5.0), "at rest: 5 N m"
    half = motor.output_current(0.0, 0.5 * w0, 1e-3) * DM_J4310.torque_constant
    assert half == pytest.approx(DM_J4310.stall_torque * 0.5), "at half the no-load speed, half the peak torque"
    assert motor.output_current(0.0, w0, 1e-3) == 0.0, "none at the no-load speed"
    assert motor.output_current(0.0, -w0, 1e-3) * DM_J4310.torque_constant == pytest.approx(5.0), "braking: all of it"


def test_the_winding_heats_as_a_first_order_body():
    motor = CanMotor(DM_J4340, 1)
    motor.enabled = True
    motor.command = frames.Command(0.0, 0.0, 0.0, 0.0, 9.0)       # the rated torque
    current = 9.0 / DM_J4340.torque_constant
    seconds = 200.0
    for _ in range(int(seconds / 0.01)):
        motor.output_current(0.0, 0.0, 0.01)
    rise = current ** 2 * DM_J4340.phase_resistance * DM_J4340.thermal_resistance
    expected = 25.0 + rise * (1 - math.exp(-seconds / DM_J4340.thermal_time_constant))
    assert motor.temperature == pytest.approx(expected, rel=2e-3), "T(t) = T_amb + I²R R_th (1 - exp(-t/τ))"


def test_can_configuration_errors_name_the_key():
    base = load_config("replica_can")
    import tomllib
    from servodyn.hal.config import builtin_configs
    data = tomllib.loads(builtin_configs()["replica_can"].read_text())
    data["joint"][2]["dialect"] = "robstride"
    with pytest.raises(ConfigError, match=r"joint 3 .*'dialect' must be one of mit, damiao, cubemars"):
        config_from_dict(data, "x.toml")
    data["joint"][2]["dialect"] = "damiao"
    data["joint"][2]["feedback_id"] = 3
    with pytest.raises(ConfigError, match=r"'feedback_id' 0x3 cannot be a damiao motor's reply id"):
        config_from_dict(data, "x.toml")
    data["joint"][2]["feedback_id"] = 0x13
    data["bus"]["arm"]["bitrate"] = 300000
    with pytest.raises(ConfigError, match=r"'bitrate' must be a can rate"):
        config_from_dict(data, "x.toml")
    assert base.buses["arm"].options == {"interface": "slcan"} and base.buses["arm"].baud == 1_000_000
    assert [j.options["feedback_id"] for j in base.joints] == list(range(0x11, 0x18)), "command id + 0x10"
    assert [j.servo.name for j in base.joints] == ["DM-J4340"] * 4 + ["DM-J4310"] * 3


@pytest.mark.parametrize("dialect", ["mit", "cubemars"])
def test_dialects_that_answer_on_one_shared_id_are_routed_by_motor_id(dialect):
    """mit and cubemars motors all answer on id 0; the backend routes each reply by its byte 0."""
    import tomllib
    from servodyn.hal.config import builtin_configs
    data = tomllib.loads(builtin_configs()["replica_can"].read_text())
    for joint in data["joint"]:
        joint["dialect"] = dialect
        del joint["feedback_id"]
    config = config_from_dict(data, "x.toml")
    assert {j.options["feedback_id"] for j in config.joints} == {0}, "every reply on id 0"
    arm = SimulatedRobot(config)
    server = VirtualCanServer(arm.port(), next(CHANNELS), threaded=False)
    server.start()
    host = server.host_bus()
    bus = make_bus(config, can_bus=host, reply_timeout=PATIENT)
    try:
        bus.open()
        bus.enable_torque(True)
        q = np.array([0.1, 0.2, -0.1, 0.5, 0.3, 0.1, -0.1])
        hold(bus, q, 200)
        state = bus.read_state()
        assert np.abs(state.q - arm.q).max() < 0.01, "each joint reads its own motor's position (one tick old)"
        assert np.abs(state.q - q).max() < 0.2, f"held near the target against gravity: {state.q}"
        server.inject_fault(3, 1 if dialect == "cubemars" else "silent")
        with pytest.raises(ServoHardwareError if dialect == "cubemars" else ServoTimeoutError,
                           match="r_shoulder_rotation"):
            hold(bus, q, 3)
    finally:
        bus.stop()
        server.stop()
        host.shutdown()
