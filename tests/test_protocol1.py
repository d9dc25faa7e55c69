"""Dynamixel Protocol 1.0 (AX-12A; MX-28/64/106 with their 1.0 firmware): servodyn's 1.0 codec
against dynamixel-sdk's Protocol1PacketHandler byte for byte (instruction and status packets, the
checksum at its edges), the SDK's GroupBulkRead TypeError on 1.0 and the bus's own BULK READ in its
place, the simulated 1.0 servos answering the SDK through a pseudo-terminal, bad configurations
refused in one line, and a swing of the replica on MX servos (replica_mx)."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from servodyn.errors import ServodynError
from servodyn.hal.config import load_config
from servodyn.hal.dynamixel import protocol1
from servodyn.hal.dynamixel.protocol1 import ErrorBit, Instruction, Packet, PacketReader
from servodyn.hal.dynamixel.table1 import AX_12A, MX_28, MX_64, MX_106, SERVOS1, item
from servodyn.sim.dynamixel.servo1 import Dynamixel1Servo
from servodyn.sim.dynamixel.wire1 import Dynamixel1Wire

sdk = pytest.importorskip("dynamixel_sdk")
REPLICA_MX = Path(__file__).resolve().parent.parent / "hal" / "configs" / "replica_mx.toml"


class CapturePort:
    """The SDK's port, as far as its packet builders use it: what they write is kept; a read
    returns the bytes queued (a status packet to parse)."""

    def __init__(self, incoming: bytes = b""):
        self.is_using, self.sent, self.incoming = False, [], bytearray(incoming)

    def clearPort(self):
        pass

    def writePort(self, packet):
        self.sent.append(bytes(packet))
        return len(packet)

    def readPort(self, length):
        out, self.incoming = list(self.incoming[:length]), self.incoming[length:]
        return out

    def setPacketTimeout(self, length):
        pass

    def isPacketTimeout(self):
        return not self.incoming


def sdk_bytes(call) -> bytes:
    port, handler = CapturePort(), sdk.PacketHandler(1.0)
    call(port, handler)
    assert len(port.sent) == 1, "one packet per call"
    return port.sent[0]


# ------------------------------------------------------------------------------ the codec vs the SDK

def test_instruction_packets_match_the_sdk_byte_for_byte():
    """PING, READ, WRITE (1 and 2 bytes), SYNC WRITE and BULK READ as the SDK's 1.0 handler builds
    them, over IDs and addresses at their edges, and the e-manual's worked example (checksum 0xDC)."""
    assert protocol1.frame(1, Instruction.WRITE, bytes((0x0C, 0x64, 0xAA))) == bytes.fromhex("FFFF0105030C64AADC")
    rng = random.Random(33)
    for servo_id in (0, 1, 7, 0x7F, 0xFD):
        assert protocol1.ping(servo_id) == sdk_bytes(
            lambda p, h: h.txPacket(p, [0, 0, servo_id, 2, Instruction.PING, 0]))
        for address, length in ((0, 1), (36, 8), (36, 34), (71, 2), (255, 255)):
            assert protocol1.read(servo_id, address, length) == sdk_bytes(
                lambda p, h: h.readTx(p, servo_id, address, length))
        for size, name in ((1, "write1ByteTxOnly"), (2, "write2ByteTxOnly")):
            value = rng.randrange(1 << (8 * size))
            assert protocol1.write(servo_id, 30, value.to_bytes(size, "little")) == sdk_bytes(
                lambda p, h: getattr(h, name)(p, servo_id, 30, value))
    for ids in ([1], [1, 2, 3, 4, 5, 6, 7], list(range(0, 0xFD, 9))):
        data = {i: rng.randrange(2048).to_bytes(2, "little") for i in ids}

        def group_write(p, h):
            g = sdk.GroupSyncWrite(p, h, 71, 2)
            for i, d in data.items():
                g.addParam(i, list(d))
            g.txPacket()
        assert protocol1.sync_write(71, 2, data) == sdk_bytes(group_write)
        spans = [(i, 36, 8 + (i % 3) * 13) for i in ids]
        param = [b for i, a, n in spans for b in (n, i, a)]
        assert protocol1.bulk_read(spans) == sdk_bytes(lambda p, h: h.bulkReadTx(p, param, len(param)))


@pytest.mark.parametrize("body_sum", [0xFF, 0x100, 0x1FF, 0x200, 0x2FF, 0x300])
def test_status_packets_parse_alike_with_checksums_at_their_edges(body_sum):
    """A status packet whose body sums to the checksum's edges (checksum 0x00 at a sum of 0x..FF,
    0xFF at 0x..00, sums carried past one and two bytes): servodyn's reader and the SDK's rxPacket
    take the same ID, error and parameters; one bit of the checksum flipped and both refuse it."""
    need = body_sum - (5 + 5 + ErrorBit.OVERLOAD)       # ID 5, LEN 5 (3 parameters), error byte
    params = bytes(min(255, max(0, need - 255 * k)) for k in range(3))
    assert 5 + 5 + ErrorBit.OVERLOAD + sum(params) == body_sum
    frame = protocol1.status(5, ErrorBit.OVERLOAD, bytes(params))
    ours = PacketReader().feed(frame)
    assert ours == [Packet(5, ErrorBit.OVERLOAD, bytes(params))]
    rx, result = sdk.PacketHandler(1.0).rxPacket(CapturePort(frame))
    assert result == sdk.COMM_SUCCESS and bytes(rx) == frame
    bad = frame[:-1] + bytes((frame[-1] ^ 1,))
    assert not any(isinstance(e, Packet) for e in PacketReader().feed(bad))
    assert sdk.PacketHandler(1.0).rxPacket(CapturePort(bad))[1] == sdk.COMM_RX_CORRUPT
    assert protocol1.error_faults(ErrorBit.OVERLOAD | ErrorBit.INPUT_VOLTAGE) == ("input voltage", "overload")


# ------------------------------------------------------------------------------ the SDK's bulk read bug

def test_sdk_group_bulk_read_still_raises_on_protocol_1():
    """dynamixel-sdk's GroupBulkRead.txPacket passes the fast-read flag to a 1.0 handler whose
    bulkReadTx takes none: a TypeError, before any byte is sent. When this fails upstream has fixed
    it, and the bus may use the SDK's group again."""
    port = CapturePort()
    group = sdk.GroupBulkRead(port, sdk.PacketHandler(1.0))
    assert group.addParam(1, 36, 8)
    with pytest.raises(TypeError, match="bulkReadTx"):
        group.txPacket()
    assert port.sent == []


def test_the_bulk_read_workaround_reads_every_mx_and_skips_the_ax():
    """servodyn's own BULK READ to three simulated MX servos: each answers its span in the order
    listed (MX-64/106 to Current(69), 34 bytes; MX-28 8); an AX-12A listed first silences the rest,
    as a real chain does (the AX has no BULK READ), so a bus with one reads servo by servo."""
    from servodyn.hal.dynamixel.spec1 import sequential
    servos = [Dynamixel1Servo(MX_106, 1), Dynamixel1Servo(MX_64, 2), Dynamixel1Servo(MX_28, 3)]
    wire = Dynamixel1Wire(servos)
    spans = [(1, 36, 34), (2, 36, 34), (3, 36, 8)]
    replies = [e for e in PacketReader().feed(wire.handle(protocol1.bulk_read(spans))) if isinstance(e, Packet)]
    assert [(p.id, len(p.params)) for p in replies] == [(1, 34), (2, 34), (3, 8)]
    assert all(p.params[68 - 36] | p.params[69 - 36] << 8 == 2048 for p in replies[:2])    # no current: 2048
    wire = Dynamixel1Wire([Dynamixel1Servo(AX_12A, 4), *servos])
    assert wire.handle(protocol1.bulk_read([(4, 36, 8), *spans])) == b""

    class Joint:
        def __init__(self, servo):
            self.servo = servo
    assert sequential([Joint(AX_12A), Joint(MX_64)]) and not sequential([Joint(MX_28), Joint(MX_64)])


# ------------------------------------------------------------------------------ the simulated servos

def test_simulated_servos_answer_the_sdk_through_a_pty():
    """replica_mx's simulated bus behind a pseudo-terminal, spoken to by the SDK's 1.0 handler: PING
    with each model number (MX-106 320, MX-64 310, MX-28 29), a READ of P Gain (32), a WRITE the
    servo takes, a range error for a value over an item's range, a SYNC WRITE of Goal Torque, and
    an overload injected shown in the error byte."""
    from servodyn.sim.robot import SimulatedRobot
    from servodyn.sim.transport.pty import PtyServer

    config = load_config(REPLICA_MX)
    robot = SimulatedRobot(config)
    with PtyServer(robot.port("arm"), "lockstep") as server:
        port, handler = sdk.PortHandler(server.path), sdk.PacketHandler(1.0)
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            assert handler.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT        # the servos listen at 3 Mbps only
            assert port.setBaudRate(config.buses["arm"].baud)
            models = [handler.ping(port, i) for i in range(1, 8)]
            assert models == [(m, sdk.COMM_SUCCESS, 0) for m in (320, 320, 310, 310, 29, 29, 29)]
            assert handler.read1ByteTxRx(port, 5, 28)[:2] == (32, sdk.COMM_SUCCESS)
            assert handler.write1ByteTxRx(port, 3, 70, 1) == (sdk.COMM_SUCCESS, 0)
            assert handler.write1ByteTxRx(port, 3, 24, 2) == (sdk.COMM_SUCCESS, ErrorBit.RANGE)
            group = sdk.GroupSyncWrite(port, handler, 71, 2)
            assert group.addParam(3, [0x10, 0x04]) and group.txPacket() == sdk.COMM_SUCCESS   # 16 units CW
            assert handler.ping(port, 3)[1] == sdk.COMM_SUCCESS          # the write has been taken
            assert robot.servo(3).get("goal_torque") == -16
            robot.inject_fault(4, "overload")
            assert handler.ping(port, 4)[2] == ErrorBit.OVERLOAD
            with pytest.raises(ValueError, match="no 'electrical shock' fault"):
                robot.inject_fault(4, "electrical shock")
            assert handler.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT
        finally:
            port.closePort()


def test_factory_state_and_the_torque_mode_current_loop():
    """A factory-fresh MX-64: ID 1 at 57 600 baud (Baud Rate 34), P 32; an AX-12A at 1 Mbps. In
    torque mode with Goal Torque 200 (0.9 A) at rest it drives 0.9 A, and a goal beyond what the
    supply less the back-EMF allows is capped at the motor's max duty (BAM's 0.9625)."""
    mx = Dynamixel1Servo.factory_fresh(MX_64, supply_voltage=12.0)
    assert (mx.id, mx.baud, mx.get("p_gain"), mx.get("model_number")) == (1, 57_600, 32, 310)
    assert Dynamixel1Servo.factory_fresh(AX_12A).baud == 1_000_000
    mx._put("torque_control_mode_enable", 1), mx._put("goal_torque", 200), mx._put("torque_enable", 1)
    assert mx.output_current(0.0, 0.0, 1e-3) == pytest.approx(0.9, abs=1e-9)
    mx._put("goal_torque", 1023)
    top = (0.9625 * 12.0 - MX_64.motor.torque_constant * 3.0) / MX_64.motor.resistance
    assert mx.output_current(0.0, 3.0, 1e-3) == pytest.approx(top, rel=1e-9)


# ------------------------------------------------------------------------------ configurations

def _config(tmp_path, servo="MX-64", protocol="1.0", baud=1_000_000, extra="current_limit = 4.0\n"):
    path = tmp_path / "bad.toml"
    path.write_text(f'name = "bad"\nmodel = "replica"\n[bus.arm]\nkind = "dynamixel"\nbaud = {baud}\n'
                    f'protocol = {protocol}\n' + "".join(
                        f'[[joint]]\ndof = "{d}"\nid = {k + 1}\nservo = "{servo}"\n{extra}'
                        for k, d in enumerate(load_config("replica").model.dof_names)))
    return path


@pytest.mark.parametrize("servo, protocol, baud, extra, message", [
    ("XM430-W350", "1.0", 1_000_000, "", "X-series servo, driven on Protocol 2.0 only"),
    ("MX-64", "2.0", 1_000_000, "", "speaks Protocol 1.0"),
    ("MX-64", "3.0", 1_000_000, "", "must be 2.0 or 1.0"),
    ("MX-64", "1.0", 4_000_000, "", "is not a Protocol 1.0 rate"),
    ("MX-106", "1.0", 1_000_000, "", "exceeds the MX-106's largest current limit"),    # 5.2 A stall > 4.6
    ("MX-28", "1.0", 1_000_000, 'drive = "pwm"\n', "does not apply to the MX-28 on Protocol 1.0"),
])
def test_bad_configurations_are_refused_in_one_line(tmp_path, servo, protocol, baud, extra, message):
    with pytest.raises(ServodynError) as err:
        load_config(_config(tmp_path, servo, protocol, baud, extra))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_bring_up_refuses_a_1_0_bus_in_one_line():
    """scan/setup/doctor/calibrate/monitor speak Protocol 2.0: on a 1.0 bus they refuse at once
    (rather than report every 1.0 servo as silent)."""
    from servodyn.hal.bringup import BadRequest, bringup_class
    with pytest.raises(BadRequest, match="protocol = 1.0: servodyn's bring-up") as err:
        bringup_class("dynamixel")(load_config("replica_mx"), "arm", "/dev/null")
    assert "\n" not in str(err.value)


def test_replica_mx_validates_its_forehand(tmp_path):
    """`servodyn validate replica_mx tennis_forehand` passes (exit 0): at its time scale every joint
    within its limits, the tick's BULK READ and SYNC WRITEs within the 2 ms period at 3 Mbps."""
    from helpers import run_cli
    proc = run_cli("validate", "replica_mx", "tennis_forehand", "-o", tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "PASS: every joint within every limit" in proc.stdout


def test_replica_mx_loads_and_every_table_is_once():
    """replica_mx: protocol 1.0, MX-106/64 in torque mode, the MX-28 through its position loop; the
    control tables' items never overlap, and Goal Torque sits at 71 on the torque-mode models only."""
    config = load_config(REPLICA_MX)
    assert config.buses["arm"].protocol == 1.0
    assert [j.servo.name for j in config.joints] == ["MX-106"] * 2 + ["MX-64"] * 2 + ["MX-28"] * 3
    for servo in SERVOS1.values():
        spans = sorted((i.address, i.address + i.size) for i in servo.items())
        assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:])), servo.name
    assert item(MX_106, "goal_torque").address == 71
    with pytest.raises(KeyError):
        item(MX_28, "goal_torque")


# ------------------------------------------------------------------------------ the bus on the simulated servos

def _with_ax(tmp_path) -> Path:
    """replica_mx with AX-12As for its MX-28s (a bus an AX-12A makes read servo by servo), at 1 Mbps
    (the AX's fastest rate) and a 5 ms period."""
    text = REPLICA_MX.read_text().replace('"MX-28"', '"AX-12A"').replace("baud = 3000000", "baud = 1000000")
    path = tmp_path / "replica_ax.toml"
    path.write_text(text.replace("period = 0.002", "period = 0.005"))
    return path


@pytest.mark.parametrize("with_ax", [False, True])
def test_the_bus_reads_each_tick_writes_goals_and_names_a_faulty_servo(tmp_path, with_ax):
    """Dynamixel1Bus on the simulated bus (BULK READ on replica_mx; READ per servo with AX-12As):
    q = 0 at the start pose within one position unit; a torque on an MX-106 reaches it as Goal
    Torque (tau / (kt x 4.5 mA), bit 10 for CW); a torque on an MX-28 / AX-12A as Goal Position
    offset from the present by duty / duty_per_tick; an overload in a servo's error byte is a
    ServoHardwareError naming its joint, a silent servo a ServoTimeoutError naming it."""
    from servodyn.hal.bus import JointCommand, make_bus
    from servodyn.hal.dynamixel.backend1 import POSITION_GAIN, Dynamixel1Bus
    from servodyn.hal.errors import ServoHardwareError, ServoTimeoutError
    from servodyn.sim.serve import serve
    config = load_config(_with_ax(tmp_path) if with_ax else REPLICA_MX)
    with serve(config, "lockstep", process=False) as served:
        bus = make_bus(config, **served.buses["arm"])
        assert isinstance(bus, Dynamixel1Bus) and bus.sequential == with_ax
        with bus:
            state = bus.read_state()
            steps = np.array([j.servo.step for j in config.joints])
            assert np.all(np.abs(state.q) <= steps), state.q
            tau = np.array([-1.0, 0, 0, 0, 0.2, 0, 0])
            bus.write(JointCommand.torque(tau))
            bus.read_state()            # answered after the write's bytes (no reply) were taken in
            shoulder, forearm = config.joints[0], config.joints[4]
            expected = round(-1.0 / shoulder.torque_constant / 4.5e-3)
            assert served.robot.servo(1).get("goal_torque") == expected < 0
            motor = forearm.servo.motor_model
            duty = motor.duty_for_current(0.2 / forearm.direction / forearm.torque_constant, 12.0, 0.0)
            offset = served.robot.servo(5).get("goal_position") - bus._ticks[4]
            assert offset == pytest.approx(duty / forearm.servo.duty_per_tick(POSITION_GAIN), abs=1.0)
            served.inject_fault(2, "overload")
            with pytest.raises(ServoHardwareError, match="r_shoulder_abduction"):
                bus.read_state()
            served.clear_faults()
            served.robot.servo(2).error = 0
            served.inject_fault(6, "silent")
            with pytest.raises(ServoTimeoutError, match="r_wrist_flexion"):
                bus.read_state()
            served.clear_faults()


@pytest.mark.parametrize("fault", ["flipped_byte", "garbage", "wrong_id", "delayed_reply"])
def test_wire_faults_on_the_1_0_bus_end_in_a_timeout_naming_a_joint(fault):
    """The 2.0 simulator's wire faults on 1.0 frames: a reply with a flipped bit, garbage, every
    status packet under its neighbour's ID, or the tick's reply held back 0.5 s (past the 0.1 s
    patience given here) fail every try of the read: a ServoTimeoutError naming a joint, after the
    bus's retries (reads_retried counts one). Cleared, the next read succeeds."""
    import time
    from servodyn.hal.bus import make_bus
    from servodyn.hal.errors import ServoTimeoutError
    from servodyn.sim.serve import serve
    config = load_config(REPLICA_MX)
    with serve(config, "lockstep", process=False) as served:
        with make_bus(config, **served.buses["arm"]) as bus:
            bus.read_state()
            served.inject_fault(1, fault)
            served.robot.wire["arm"].delay = 0.5
            bus.reply_timeout = 0.1          # the faulty tries (the simulator's own patience: 1 s)
            with pytest.raises(ServoTimeoutError, match="r_"):
                bus.read_state()
            assert bus.stats.reads_retried == 1
            served.clear_faults()
            time.sleep(1.6)                  # the held-back replies have come and gone
            bus.reply_timeout = served.buses["arm"]["reply_timeout"]
            assert bus.read_state().q.shape == (7,)


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_swing_learns_the_simulated_1_0_bus_clock(mode):
    """A swing given the pseudo-terminal of `servodyn sim --config replica_mx` asks the 1.0 bus which
    clock its plant keeps (a one-byte READ past every 1.0 table) and gets it."""
    from servodyn.hal.served_clock import served_clock
    from servodyn.sim.robot import SimulatedRobot
    from servodyn.sim.transport.pty import PtyServer
    config = load_config("replica_mx")
    with PtyServer(SimulatedRobot(config).port("arm"), mode) as server:
        assert served_clock(config, "arm", server.path) == mode


@pytest.mark.slow
def test_swing_on_replica_mx_tracks(tmp_path):
    """`servodyn swing --config replica_mx` on the simulated 1.0 bus completes with every joint
    within 0.5 deg of the motion, the swing's own goal (0.29 deg measured; the MX-28's
    position-offset drive quantises its duty to one position unit, ~0.8 % at P = 32)."""
    from runs import run_swing
    summary = run_swing("replica_mx", tmp_path, figure=False)
    assert summary["completed"] and summary["error"] is None, summary.get("error")
    assert summary["tracking_max_rad"] < np.radians(0.5), np.degrees(summary["tracking_max_rad"])
