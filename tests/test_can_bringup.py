"""CAN bring-up (hal/can/bringup.py) against simulated Damiao motors (sim/can/) served on python-can's
virtual interface and behind the SLCAN adapter on a pseudo-terminal: scan finds replica_can's seven
motors with their Master IDs, a factory-fresh motor is found on Master ID 0 and named with its fix,
setup gives a fresh motor its joint's ids, mode and ranges (kept across a power cycle only when
saved), doctor finds nothing on a healthy bus and exactly the fault on a sick one, and torque off,
clear errors and zero leave the motors as they say. The simulated motor's memory (RAM, flash, the
device protocol a bench calls: factory_fresh, nonvolatile, restore, power_cycle) is checked frame
by frame."""

import itertools
import json
import threading
import time
import tomllib

import can
import pytest

from servodyn.hal.bringup import ERROR
from servodyn.hal.can import bringup as bench, dialects, frames
from servodyn.hal.can.motors import DM_J4310, DM_J4340
from servodyn.hal.config import builtin_configs, config_from_dict, load_config
from servodyn.hal.errors import ServoInitializationError
from servodyn.sim.can import CanMotor, CanNetwork
from servodyn.sim.transport.can import SlcanServer, VirtualCanServer

pytestmark = pytest.mark.serial      # scans listen for the motors' answers for a wall-clock window

# s for one answer: a loaded machine can hold the motors' server thread back far beyond a real
# bus's millisecond (the simulated buses' patience elsewhere, hal/ports.py)
PATIENT = 0.5
CHANNELS = (f"test-can-bench-{k}" for k in itertools.count())
CONFIG = load_config("replica_can")
JOINT = {j.dof: j for j in CONFIG.joints}
ELBOW = JOINT["r_elbow_flexion"]          # id 4, Master ID 0x14, a DM-J4340


class Port:
    """What a transport serves: one network of motors behind a lock (SimulatedRobot.port's shape)."""

    def __init__(self, network: CanNetwork, name: str = "arm"):
        self.network, self.name, self.lock = network, name, threading.RLock()

    def handle(self, arbitration_id: int, data: bytes):
        return self.network.handle(arbitration_id, data)

    def lockstep(self, period) -> None:
        """No plant behind these motors: nothing to step."""


def replica_motors() -> list[CanMotor]:
    """replica_can's motors as set up (ids, Master IDs, ranges, MIT mode, all in flash)."""
    return [CanMotor(j.servo, j.id, dialect=j.options["dialect"], feedback_id=j.options["feedback_id"],
                     ranges=j.options["ranges"]) for j in CONFIG.joints]


class Served:
    """A network on a transport, and the host's python-can bus on it."""

    def __init__(self, motors, transport: str):
        self.network = CanNetwork(motors)
        port = Port(self.network)
        if transport == "virtual":
            self.server = VirtualCanServer(port, next(CHANNELS), mode="lockstep")
            self.server.start()
            self.bus = can.Bus(interface="virtual", channel=self.server.channel)
        else:
            self.server = SlcanServer(port, mode="lockstep")
            self.server.start()
            # the pseudo-terminal is ready at once: no wait for an adapter to boot (python-can waits 2 s)
            self.bus = can.Bus(interface="slcan", channel=self.server.path, bitrate=1_000_000, sleep_after_open=0)

    def close(self) -> None:
        self.bus.shutdown()
        self.server.stop()


@pytest.fixture(params=["virtual", "slcan"])
def transport(request):
    return request.param


@pytest.fixture
def serve():
    made = []

    def make(motors, transport="virtual") -> Served:
        made.append(Served(motors, transport))
        return made[-1]

    yield make
    for served in made:
        served.close()


def lines(findings) -> list[str]:
    return [f.line() for f in findings]


# ---------------------------------------------------------------- scan and compare
def test_scan_finds_the_replica_motors_with_their_master_ids(serve, transport):
    served = serve(replica_motors(), transport)
    start = time.monotonic()
    found = bench.scan(served.bus, timeout=PATIENT)
    elapsed = time.monotonic() - start
    assert [f.id for f in found] == list(range(1, 8)), "one Found per motor, by CAN ID"
    assert [f.extra["master_id"] for f in found] == list(range(0x11, 0x18)), "each Master ID register: id + 0x10"
    assert [f.extra["reply_id"] for f in found] == list(range(0x11, 0x18)), "each answered on its Master ID"
    assert [f.model for f in found] == ["DM-J4340"] * 4 + ["DM-J4310"] * 3, "the gear ratio register names the model"
    assert {(f.extra["status"], f.extra["ctrl_mode"], f.extra["answers"], f.kind, f.baud) for f in found} == \
        {("disabled", dialects.MIT_MODE, 1, "can", 1_000_000)}, "disabled, in MIT mode, one motor per id"
    assert all(f.extra["coil_temperature"] == 25 for f in found), "the coil temperature of a cold motor (25 °C)"
    assert json.loads(json.dumps([f.as_json() for f in found]))[0]["master_id"] == 0x11, "scan --json's objects"
    assert bench.compare(CONFIG, "arm", found) == [], "the bus is as configured"
    # 2046 register reads and seven motors' status: on the virtual bus a small fraction of a second
    # when the machine is idle; the bound only catches a scan that waits per id (2046 x a timeout)
    assert elapsed < 30, f"the whole id range in {elapsed:.1f} s"


def test_scan_is_fast_on_the_virtual_bus(serve):
    served = serve(replica_motors())
    start = time.monotonic()
    bench.scan(served.bus)
    # measured about 0.2 s; generous for a loaded shared machine: a per-id wait would be 100 s
    assert time.monotonic() - start < 5


def test_a_factory_fresh_motor_answers_on_master_id_0_and_is_named_with_the_fix(serve, transport):
    motors = replica_motors()
    motors[0] = CanMotor.factory_fresh(DM_J4340)          # the shoulder's motor replaced by a new one
    served = serve(motors, transport)
    found = bench.scan(served.bus, timeout=PATIENT)
    first = found[0]
    assert (first.id, first.extra["master_id"], first.extra["reply_id"]) == (1, 0, 0), \
        "a fresh motor: CAN ID 1, Master ID 0, so it answers on id 0"
    (finding,) = bench.compare(CONFIG, "arm", found)
    assert (finding.check, finding.joint, finding.id, finding.found, finding.expected, finding.severity) == \
        ("Master ID", "r_shoulder_flexion", 1, "0x0 (as from the factory)", "0x11", ERROR)
    assert "servodyn setup" in finding.fix and "r_shoulder_flexion" in finding.fix, finding.line()


def test_a_missing_motor_and_a_stranger_are_named(serve):
    motors = [m for m in replica_motors() if m.can_id != 4]
    motors.append(CanMotor(DM_J4310, 9, feedback_id=0x19))
    served = serve(motors)
    heard = []
    found = bench.scan(served.bus, timeout=PATIENT, heard=heard)
    findings = bench.compare(CONFIG, "arm", found)
    assert [(f.check, f.joint, f.id) for f in findings] == [("reply", "r_elbow_flexion", 4),
                                                            ("unexpected motor", None, 9)], lines(findings)
    assert findings[0].line().startswith("bus 'arm' joint 'r_elbow_flexion' id 4: reply: found no reply"), \
        findings[0].line()
    assert "power" in findings[0].fix and "terminators" in findings[0].fix
    assert findings[1].severity == "warning", "its Master ID 0x19 is no joint's: it disturbs nothing"
    assert heard == [], "every frame was a motor's answer"


def test_two_fresh_motors_on_one_id_are_one_finding(serve):
    served = serve([CanMotor.factory_fresh(DM_J4340), CanMotor.factory_fresh(DM_J4340)])
    found = bench.scan(served.bus, timeout=PATIENT)
    assert [(f.id, f.extra["answers"]) for f in found] == [(1, 2)], "two answers to one probe, on id 0"
    checks = [(f.check, f.joint) for f in bench.compare(CONFIG, "arm", found)]
    assert ("CAN ID", "r_shoulder_flexion") in checks and ("Master ID", "r_shoulder_flexion") in checks, checks


# ---------------------------------------------------------------- setup and flash
def config_with_elbow_tmax(t_max: float):
    data = tomllib.loads(builtin_configs()["replica_can"].read_text())
    data["joint"][3]["t_max"] = t_max
    return config_from_dict(data, "bench.toml", base=CONFIG.path.parent)


def test_setup_gives_a_fresh_motor_its_joints_ids_mode_and_ranges(serve, transport):
    config = config_with_elbow_tmax(20.0)
    elbow = config.joints[3]
    motor = CanMotor.factory_fresh(DM_J4340, ctrl_mode=2)     # shipped in position-velocity mode
    served = serve([motor], transport)
    asked = []

    def confirm(what):
        # asked once, with every change named, before anything was written
        asked.append(what)
        assert (motor.can_id, motor.feedback_id, motor.saves) == (1, 0, 0), "nothing written before the yes"
        return True
    done = bench.setup(served.bus, elbow, confirm=confirm, timeout=PATIENT)
    assert (motor.can_id, motor.feedback_id, motor.registers[dialects.REG_CTRL_MODE]) == (4, 0x14, 1), done
    assert motor.ranges == frames.Ranges(12.5, 8.0, 20.0), "PMAX/VMAX/TMAX from the joint's ranges"
    assert len(asked) == 1 and "flash" in asked[0] and "10,000" in asked[0], asked
    for change in ("CAN ID (ESC_ID): 1 -> 4", "Master ID: 0x0 -> 0x14", "CTRL_MODE: 2 (position-velocity) -> 1 (MIT)",
                   "TMAX: 28 -> 20"):
        assert change in asked[0] and change in done, (change, asked, done)
    assert "PMAX" not in asked[0], "a register already as the joint wants it is no change"
    assert done[0] == "found DM-J4340 at CAN ID 1, Master ID 0x0"
    assert done[-1] == "saved to flash (the motor confirmed)" and motor.saves == 1, done
    served.network.power_cycle()
    found = bench.scan(served.bus, timeout=PATIENT)
    assert [(f.id, f.extra["master_id"], f.extra["reply_id"], f.extra["ctrl_mode"]) for f in found] == \
        [(4, 0x14, 0x14, 1)], "after a power cycle it answers at its configured ids, in MIT mode"
    assert motor.ranges.t_max == 20.0, "and keeps the joint's TMAX"


def test_a_setup_declined_writes_nothing(serve):
    """The plan is shown, the question asked once: a no leaves the motor as it was, RAM and flash."""
    motor = CanMotor.factory_fresh(DM_J4340)
    served = serve([motor])
    done = bench.setup(served.bus, ELBOW, confirm=lambda what: False, timeout=PATIENT)
    assert done[-1] == "nothing written", done
    assert (motor.can_id, motor.feedback_id, motor.saves) == (1, 0, 0), "not even in RAM"


def test_a_set_up_motor_has_nothing_to_write(serve):
    served = serve(replica_motors()[3:4])
    asked = []
    done = bench.setup(served.bus, ELBOW, confirm=lambda what: asked.append(what) or True, timeout=PATIENT)
    assert done[-1] == "nothing to write" and asked == [], (done, asked)
    assert served.network.motors[0].saves == 0, "no flash cycle spent"


def test_setup_refuses_a_second_motor_and_a_wrong_model(serve):
    served = serve([CanMotor.factory_fresh(DM_J4340), CanMotor.factory_fresh(DM_J4340, can_id=2)])
    with pytest.raises(ServoInitializationError) as err:
        bench.setup(served.bus, ELBOW, confirm=lambda what: True, timeout=PATIENT)
    assert str(err.value) == ("joint 'r_elbow_flexion': 2 motors answer (CAN IDs 1, 2): connect only this joint's "
                              "motor and run setup again"), "one line, with its fix"
    assert all(m.can_id in (1, 2) and m.saves == 0 for m in served.network.motors), "nothing written"
    wrist = serve([CanMotor.factory_fresh(DM_J4340)])
    with pytest.raises(ServoInitializationError, match=r"configured for a DM-J4310, the motor found is a DM-J4340"):
        bench.setup(wrist.bus, JOINT["r_wrist_flexion"], confirm=lambda what: True, timeout=PATIENT)
    empty = serve([])
    with pytest.raises(ServoInitializationError, match=r"^joint 'r_elbow_flexion': no motor answered at any CAN ID: "
                                                       r"check its power"):
        bench.setup(empty.bus, ELBOW, confirm=lambda what: True, listen=0.01, timeout=0.01)


def register(motor: CanMotor, cmd: int, rid: int = 0, value: int = 0):
    return motor.receive(frames.REGISTER_ID, frames.pack_register(frames.Register(motor.can_id, cmd, rid, value)))[0]


def test_the_motor_saves_only_when_disabled_and_a_power_cycle_keeps_only_flash():
    motor = CanMotor.factory_fresh(DM_J4340)
    motor.receive(1, frames.pack_special(frames.ENTER))
    assert register(motor, frames.REG_WRITE, dialects.REG_MST_ID, 0x14) == \
        [(0x14, frames.pack_register(frames.Register(1, frames.REG_WRITE, dialects.REG_MST_ID, 0x14)))], \
        "a write goes to RAM at once: the echo already comes on the new Master ID"
    assert register(motor, frames.REG_STORE, 1) == [], "enabled: the save is ignored, without an answer"
    assert motor.flash[dialects.REG_MST_ID] == 0 and motor.saves == 0
    motor.power_cycle()
    assert (motor.feedback_id, motor.enabled) == (0, False), "RAM lost: Master ID 0 again, disabled"
    register(motor, frames.REG_WRITE, dialects.REG_MST_ID, 0x14)
    assert register(motor, frames.REG_STORE, 1) == [(0x14, frames.pack_register(frames.Register(1, 0xAA, 1)))], \
        "disabled: saved, and echoed"
    motor.fault = 0xA
    motor.power_cycle()
    assert (motor.feedback_id, motor.fault) == (0x14, 0), "flash kept; a latched fault does not survive a power cycle"


def test_a_motor_in_another_mode_ignores_mit_frames_silently():
    motor = CanMotor.factory_fresh(DM_J4340, ctrl_mode=3)
    motor.receive(1, frames.pack_special(frames.ENTER))
    command, _ = frames.pack_command(motor.ranges, 0.0, 0.0, 0.0, 0.0, 5.0)
    assert motor.receive(1, command) == ([], False), "no answer, and not taken as a command"
    assert motor.command.t == 0.0


def test_nonvolatile_state_is_json_and_restores_into_a_fresh_motor():
    motor = CanMotor.factory_fresh(DM_J4310)
    register(motor, frames.REG_WRITE, dialects.REG_ESC_ID, 6)
    register(motor, frames.REG_WRITE, dialects.REG_MST_ID, 0x16)
    register(motor, frames.REG_WRITE, dialects.REG_TMAX, frames.float_bits(9.0))
    register(motor, frames.REG_STORE, 1)
    motor.set_present(0.7, 0.0, 0.0)
    motor.receive(6, frames.pack_special(frames.SET_ZERO))
    state = json.loads(json.dumps(motor.nonvolatile()))
    assert state["zero"] == pytest.approx(0.7) and state["registers"][str(dialects.REG_ESC_ID)] == 6
    other = CanMotor.factory_fresh(DM_J4310)
    other.restore(state)
    assert (other.can_id, other.feedback_id, other.ranges.t_max, other.zero, other.enabled) == \
        (6, 0x16, pytest.approx(9.0), pytest.approx(0.7), False), "powered up with the saved registers and zero"
    assert other.nonvolatile() == state


# ---------------------------------------------------------------- doctor
def test_doctor_finds_nothing_on_a_healthy_bus(serve, transport):
    served = serve(replica_motors(), transport)
    assert bench.doctor(CONFIG, "arm", served.bus, timeout=PATIENT) == []


def test_doctor_names_a_latched_over_temperature_once_with_its_fix(serve):
    motors = replica_motors()
    motors[3].temperature = DM_J4340.temperature_limit + 1.0     # 101 °C coil, limit 100 °C
    motors[3].fault = 0xC
    served = serve(motors)
    (finding,) = bench.doctor(CONFIG, "arm", served.bus, timeout=PATIENT)
    assert (finding.check, finding.joint, finding.id) == ("status", "r_elbow_flexion", 4), finding.line()
    assert finding.found == "coil over-temperature (0xC) at MOS 96 °C, coil 101 °C, limit 100 °C", finding.found
    assert finding.fix == "let the motor cool, then run servodyn clear-errors"


def test_doctor_names_a_wrong_ctrl_mode_with_its_fix(serve):
    motors = replica_motors()
    motors[2].registers[dialects.REG_CTRL_MODE] = 2
    served = serve(motors)
    (finding,) = bench.doctor(CONFIG, "arm", served.bus, timeout=PATIENT)
    assert (finding.check, finding.joint, finding.found, finding.expected) == \
        ("CTRL_MODE", "r_shoulder_rotation", "2 (position-velocity)", "1 (MIT)"), finding.line()
    assert "ignores MIT frames" in finding.fix and "servodyn setup" in finding.fix


def test_doctor_names_wrong_ranges_and_a_warm_motor(serve):
    motors = replica_motors()
    motors[5].ranges = frames.Ranges(12.5, 30.0, 12.0)
    motors[6].temperature = DM_J4310.temperature_limit - 8.0    # coil 92 °C, MOS 87 °C: within 10 K of 100
    served = serve(motors)
    findings = bench.doctor(CONFIG, "arm", served.bus, timeout=PATIENT)
    assert [(f.check, f.joint, f.found, f.expected, f.severity) for f in findings] == [
        ("TMAX", "r_wrist_flexion", "12", "10", ERROR),
        ("coil temperature", "r_wrist_deviation", "92 °C", "below 100 °C (OT)", "warning")], lines(findings)


def test_doctor_reports_no_ack_with_what_to_check(serve):
    served = serve(replica_motors())
    with can.Bus(interface="virtual", channel=served.server.channel) as other:
        other.send(can.Message(arbitration_id=frames.CAN_ERR_ACK, data=bytes(8), is_error_frame=True))
        findings = bench.doctor(CONFIG, "arm", served.bus, timeout=PATIENT)
    (finding,) = findings
    assert (finding.check, finding.found, finding.bus) == ("error frame", "no ACK", "arm"), finding.line()
    assert "unpowered" in finding.fix and "bitrate" in finding.fix and "terminators" in finding.fix


# ---------------------------------------------------------------- torque off, clear errors, zero
def test_torque_off_leaves_every_motor_disabled(serve, transport):
    motors = replica_motors()
    served = serve(motors, transport)
    for motor in motors:
        motor.receive(motor.can_id, frames.pack_special(frames.ENTER))
    assert all(m.enabled for m in motors)
    states = bench.torque_off(served.bus, CONFIG.joints, timeout=PATIENT)
    assert list(states) == [j.dof for j in CONFIG.joints], "each joint's state, re-read after"
    assert {s.status for s in states.values()} == {dialects.DAMIAO_DISABLED}, "every motor reports disabled"
    assert not any(m.enabled for m in motors), "and is"


def test_clear_errors_clears_a_latched_fault_but_not_a_hot_motor(serve):
    motors = replica_motors()
    motors[0].fault = 0xA
    motors[3].temperature, motors[3].fault = DM_J4340.temperature_limit + 1.0, 0xC
    served = serve(motors)
    states = bench.clear_errors(served.bus, CONFIG.joints, timeout=PATIENT)
    assert states["r_shoulder_flexion"].status == dialects.DAMIAO_DISABLED, "overcurrent cleared"
    assert states["r_elbow_flexion"].status == 0xC, "still over its limit: the fault stays until it cools"


def test_zero_sets_the_motors_zero_only_when_confirmed(serve):
    motors = replica_motors()
    motors[3].set_present(0.3, 0.0, 0.0)
    served = serve(motors)
    state = bench.zero(served.bus, ELBOW, confirm=lambda what: False, timeout=PATIENT)
    assert state.p == pytest.approx(0.3, abs=1e-3) and motors[3].zero == 0.0, "declined: nothing changed"
    asked = []
    state = bench.zero(served.bus, ELBOW, confirm=lambda what: asked.append(what) or True, timeout=PATIENT)
    assert "r_elbow_flexion" in asked[0]
    assert abs(state.p) < 2 * 25 / 65535 and motors[3].zero == pytest.approx(0.3), "it reads 0 where it stood"
    motors[3].power_cycle()
    assert motors[3].zero == pytest.approx(0.3), "the motor keeps its zero"

