"""The virtual X-series servo and its bus: control-table rules, watchdog, hardware errors, the
drive model, the bus's replies, and dynamixel-sdk 4.1 talking to the bus through a pseudo-terminal."""

import math
import os
import random
import select
import threading
import tty

import pytest

from servodyn.hal.dynamixel import (ALERT_BIT, BROADCAST_ID, ErrorNumber, Fault, PacketReader, ResetOption,
                                    StatusError, pack_field, split_fast_reply)
from servodyn.hal.dynamixel import instructions as inst
from servodyn.sim.dynamixel import (XM430_W350, XM540_W270, HardwareError, OperatingMode, Servo,
                                    DynamixelWire)
from servodyn.hal.dynamixel.control_table import VELOCITY_UNIT
from servodyn.hal.dynamixel.backend import _patient
from servodyn.hal.ports import PTY_REPLY_TIMEOUT
from servodyn.hal.dynamixel.reader import BYTE_TIMEOUT

from helpers import wait_until

TICK = 2 * math.pi / 4096                  # rad per position unit
NO_LOAD_SPEED = 46 * 2 * math.pi / 60      # XM430-W350 at 12 V, rad/s


def h(text: str) -> bytes:
    return bytes.fromhex(text)


def refused(number: ErrorNumber, call, *args) -> bool:
    with pytest.raises(StatusError) as caught:
        call(*args)
    return caught.value.error_number == number


def le(value: int, size: int) -> bytes:
    return pack_field(value, size, signed=True)


# --- control table ---------------------------------------------------------------------------------

@pytest.mark.parametrize("model, number, current_limit", [(XM430_W350, 1020, 1193), (XM540_W270, 1120, 2047)])
def test_model_number_and_current_limit(model, number, current_limit):
    servo = Servo(model)
    assert servo.read(0, 2) == pack_field(number, 2), "Model Number(0), e-manual"
    assert servo.get("current_limit") == current_limit, "Current Limit(38) default = maximum"
    assert servo.get("goal_current") == current_limit, "Goal Current starts at the Current Limit"


def test_eeprom_is_locked_while_torque_is_on():
    servo = Servo()
    servo.write(9, bytes([0]))
    assert servo.get("return_delay_time") == 0, "EEPROM writable with torque off"
    servo.write(64, bytes([1]))
    assert refused(ErrorNumber.ACCESS, servo.write, 11, bytes([0])), "EEPROM with torque on: access error"
    assert servo.get("operating_mode") == OperatingMode.POSITION, "and nothing was written"


@pytest.mark.parametrize("address, data, number, reason", [
    (132, le(0, 4), ErrorNumber.ACCESS, "Present Position is read-only"),
    (14, h("00"), ErrorNumber.ACCESS, "address 14 is not defined"),
    (116, le(0, 2), ErrorNumber.DATA_LENGTH, "2 bytes of the 4-byte Goal Position"),
    (117, le(0, 4), ErrorNumber.DATA_LENGTH, "starting inside Goal Position"),
    (145, h("00 00 00"), ErrorNumber.ACCESS, "past the end of the table"),
    (11, h("06"), ErrorNumber.DATA_RANGE, "Operating Mode 6 does not exist"),
    (11, h("02"), ErrorNumber.DATA_RANGE, "Operating Mode 2 does not exist"),
    (63, h("02"), ErrorNumber.DATA_RANGE, "Shutdown bit 1 is unused"),
    (102, le(1194, 2), ErrorNumber.DATA_LIMIT, "Goal Current above Current Limit 1193"),
    (116, le(4096, 4), ErrorNumber.DATA_LIMIT, "Goal Position above Max Position Limit 4095"),
    (98, le(-1, 1), ErrorNumber.DATA_RANGE, "Bus Watchdog takes 0..127"),
])
def test_write_refusals(address, data, number, reason):
    servo = Servo()
    assert refused(number, servo.write, address, data), reason


def test_read_beyond_the_table_is_an_access_error():
    servo = Servo()
    assert servo.read(140, 7)[4:6] == pack_field(120, 2), "Present Input Voltage 12.0 V at 144"
    assert refused(ErrorNumber.ACCESS, servo.read, 140, 8), "byte 147 is past Present Temperature(146)"


def test_goal_position_range_follows_the_mode():
    servo = Servo()
    servo.write(11, bytes([OperatingMode.CURRENT_POSITION]))
    servo.write(116, le(-1_048_575, 4))
    assert servo.get("goal_position") == -1_048_575, "multi-turn: −256 rev is allowed"
    assert refused(ErrorNumber.DATA_RANGE, servo.write, 116, le(1_048_576, 4)), "beyond ±256 rev"


def test_switching_mode_resets_goal_current_gains_and_profile():
    servo = Servo(XM540_W270)
    servo.write(102, le(100, 2))
    servo.write(84, le(1000, 2))
    servo.write(112, le(50, 4))
    servo.write(11, bytes([OperatingMode.CURRENT]))
    assert servo.get("goal_current") == 2047, "Goal Current → Current Limit"
    assert servo.get("position_p_gain") == 800, "gains back to their defaults"
    assert servo.get("profile_velocity") == 0, "profile reset to 0"


def test_reg_write_waits_for_action():
    servo = Servo()
    servo.reg_write(116, le(1000, 4))
    assert (servo.get("goal_position"), servo.get("registered_instruction")) == (2048, 1), "registered only"
    servo.action()
    assert (servo.get("goal_position"), servo.get("registered_instruction")) == (1000, 0), "applied"
    assert refused(ErrorNumber.INSTRUCTION, servo.action), "action without reg write: instruction error"


def test_reboot_restores_ram_defaults():
    servo = Servo()
    servo.write(102, le(5, 2))
    servo.write(64, h("01"))
    servo.write(65, h("01"))
    servo.reboot()
    assert servo.read(64, 2) == h("00 00"), "torque and LED off"
    assert servo.get("goal_current") == 1193, "Goal Current back to the Current Limit"


@pytest.mark.parametrize("option, expected_id, expected_baud", [
    (ResetOption.ALL, 1, 1), (ResetOption.EXCEPT_ID, 5, 1), (ResetOption.EXCEPT_ID_AND_BAUD, 5, 3)])
def test_factory_reset_options(option, expected_id, expected_baud):
    servo = Servo(servo_id=5)
    servo.write(8, h("03"))
    servo.write(9, h("00"))
    servo.factory_reset(option)
    assert (servo.id, servo.get("baud_rate")) == (expected_id, expected_baud), f"option {option:#04x}"
    assert servo.get("return_delay_time") == 250, "every other EEPROM item back to its default"


def test_factory_reset_refuses_unknown_option():
    assert refused(ErrorNumber.DATA_RANGE, Servo().factory_reset, 0x03), "only 0xFF, 0x01, 0x02 exist"


# --- watchdog and hardware errors ------------------------------------------------------------------

def test_bus_watchdog_trips_and_locks_goals_until_written_zero():
    servo = Servo()
    servo.write(64, h("01"))
    servo.heard(10.0)
    servo.write(98, h("05"))                                   # 5 × 20 ms
    servo.clock(10.099)
    assert servo.get("bus_watchdog") == 5, "99 ms of silence: still armed"
    servo.clock(10.101)
    assert servo.read(98, 1) == h("FF"), "101 ms: tripped, reads −1"
    assert servo.get("goal_position") == servo.get("present_position"), "the servo holds where it is"
    assert refused(ErrorNumber.DATA_RANGE, servo.write, 116, le(100, 4)), "goals are read-only"
    assert refused(ErrorNumber.DATA_RANGE, servo.write, 98, h("05")), "only 0 clears the error"
    servo.write(98, h("00"))
    servo.write(116, le(100, 4))
    assert servo.get("goal_position") == 100, "cleared: goals writable again"


def test_watchdog_ignores_silence_while_torque_is_off():
    servo = Servo()
    servo.heard(0.0)
    servo.write(98, h("01"))
    servo.clock(5.0)
    assert servo.get("bus_watchdog") == 1, "the e-manual: monitored only with torque on"


def test_realtime_tick_counts_milliseconds_modulo_32768():
    servo = Servo()
    servo.clock(40.0)
    assert servo.get("realtime_tick") == 40000 % 32768, "1 ms units, 0..32767"


def test_shutdown_error_cuts_torque_until_reboot():
    servo = Servo()
    servo.write(64, h("01"))
    servo.set_hardware_error(HardwareError.OVERLOAD)
    assert (servo.torque_enabled, servo.alert) == (False, True), "overload is in Shutdown's default 0x34"
    assert refused(ErrorNumber.RESULT_FAIL, servo.write, 64, h("01")), "torque stays off"
    servo.reboot()
    servo.write(64, h("01"))
    assert (servo.torque_enabled, servo.alert) == (True, False), "reboot clears the error"


# --- present values and the drive model --------------------------------------------------------------

def test_present_values_in_table_units():
    servo = Servo()
    servo.set_present(math.pi / 2, 1.0, -0.00269)
    assert servo.get("present_position") == 2048 + 1024, "zero at 2048, 4096 per turn"
    assert servo.get("present_velocity") == round(1 / VELOCITY_UNIT) == 42, "0.229 rpm units"
    assert servo.get("present_current") == -1, "2.69 mA units"
    assert servo.get("moving") == 1, "42 > Moving Threshold 10"


def test_reverse_mode_and_homing_offset():
    servo = Servo()
    servo.write(10, h("01"))
    servo.write(20, le(100, 4))
    servo.set_present(math.pi / 2, 1.0, 0.0)
    assert servo.get("present_position") == 2048 - 1024 + 100, "reversed, offset not reversed"
    assert servo.get("present_velocity") == -42, "velocity reversed too"


def test_multi_turn_is_cleared_only_when_stopped():
    servo = Servo()
    servo.set_present(2.5 * 2 * math.pi, 0.0, 0.0)
    assert servo.get("present_position") == 2048 + 10240, "torque off: a continuous count"
    servo.clear_multi_turn()
    assert servo.get("present_position") == 0, "12288 back within one turn"
    servo.set_present(2.5 * 2 * math.pi, 1.0, 0.0)
    assert refused(ErrorNumber.RESULT_FAIL, servo.clear_multi_turn), "moving: result fail"


def test_current_mode_applies_goal_current_within_what_the_supply_reaches():
    servo = Servo()
    servo.write(11, bytes([OperatingMode.CURRENT]))
    assert servo.output_current(0.0, 0.0, 1e-3) == 0.0, "torque off: no current"
    servo.write(64, h("01"))
    servo.write(102, le(100, 2))
    assert servo.output_current(0.0, 0.0, 1e-3) == pytest.approx(0.269), "100 × 2.69 mA"
    servo.write(102, le(1193, 2))
    current = servo.output_current(0.0, NO_LOAD_SPEED / 2, 1e-3)
    assert current == pytest.approx(2.3 * 0.5), "half the no-load speed leaves half the stall current"


def test_position_mode_p_gain_drives_pwm():
    servo = Servo()
    servo.write(116, le(2058, 4))                              # 10 ticks ahead
    servo.write(64, h("01"))
    current = servo.output_current(0.0, 0.0, 1e-3)
    assert current == pytest.approx(2.3 * (800 / 128 * 10) / 885), "KP = P/128 → 62.5 PWM units"
    assert servo.get("present_pwm") == 62, "Present PWM reports it"
    servo.write(116, le(4095, 4))
    assert servo.output_current(0.0, 0.0, 1e-3) == pytest.approx(2.3), "saturated PWM: stall current"


def test_current_based_position_is_capped_by_goal_current():
    servo = Servo()
    servo.write(11, bytes([OperatingMode.CURRENT_POSITION]))
    servo.write(116, le(2048 + 4096, 4))
    servo.write(102, le(200, 2))
    servo.write(64, h("01"))
    assert servo.output_current(0.0, 0.0, 1e-3) == pytest.approx(200 * 0.00269), "Goal Current caps"


def test_position_i_and_d_gains():
    servo = Servo()
    servo.write(11, bytes([OperatingMode.CURRENT_POSITION]))
    servo.write(80, le(160, 2) + le(16383, 2) + le(0, 2))     # D 160 (KD 10), I 16383, P 0
    servo.write(116, le(2058, 4))
    servo.write(64, h("01"))
    for _ in range(3):
        servo.output_current(0.0, 0.0, 1e-3)
    current = servo.output_current(0.0, 0.0, 1e-3)
    assert current == pytest.approx(16383 / 65536 * 40 * 0.00269), "KI = I/65536 over 4 samples of 10"
    servo.write(82, le(0, 2))
    current = servo.output_current(0.0, 1.0, 1e-3)
    assert current == pytest.approx(-10 * 4096 / (2 * math.pi) * 1e-3 * 0.00269), "KD = D/16 on speed"


def test_reverse_mode_flips_the_output_current():
    servo = Servo()
    servo.write(10, h("01"))
    servo.write(11, bytes([OperatingMode.CURRENT]))
    servo.write(102, le(100, 2))
    servo.write(64, h("01"))
    assert servo.output_current(0.0, 0.0, 1e-3) == pytest.approx(-0.269), "reverse: shaft sign flipped"


def test_output_torque_from_stall_figures_and_friction():
    assert Servo(XM430_W350).output_torque(2.3, 0.0) == pytest.approx(4.1), "4.1 N·m at 2.3 A"
    assert Servo(XM540_W270).output_torque(4.4, 0.0) == pytest.approx(10.6), "10.6 N·m at 4.4 A"
    torque = Servo().output_torque(1.0, 0.5)
    assert torque == pytest.approx(4.1 / 2.3 - 0.01 * 0.5 - 0.02 * math.tanh(50)), "viscous + Coulomb"


def test_position_step_settles_on_a_simulated_link():
    """A 0.01 kg·m² link on the servo, commanded over the bus: no overshoot beyond 5 %, settled
    within 2 ticks after 1.5 s (back-EMF damps it near critically, Coulomb friction leaves < 1 tick)."""
    servo = Servo()
    bus = DynamixelWire([servo], clock=lambda: 0.0)
    bus.handle(inst.write(1, 116, le(2048 + 512, 4)).encode() + inst.write(1, 64, h("01")).encode())
    q = qd = peak = 0.0
    for _ in range(1500):
        current = servo.output_current(q, qd, 1e-3)
        qd += servo.output_torque(current, qd) / 0.01 * 1e-3
        q += qd * 1e-3
        servo.set_present(q, qd, current)
        peak = max(peak, q)
    assert peak < 1.05 * math.pi / 4, "overshoot under 5 %"
    reply = PacketReader().feed(bus.handle(inst.read(1, 132, 4).encode()))[0]
    assert abs(int.from_bytes(reply.params, "little") - 2560) <= 2, "Present Position within 2 ticks"


# --- the bus -------------------------------------------------------------------------------------------

def exchange(bus, *packets, now=0.0):
    return PacketReader().feed(bus.handle(b"".join(p.encode() for p in packets), now))


def test_broadcast_ping_answers_in_id_order():
    bus = DynamixelWire([Servo(XM540_W270, 3), Servo(XM430_W350, 1)])
    replies = exchange(bus, inst.ping())
    assert [(r.id, r.params) for r in replies] == [(1, h("FC 03 2E")), (3, h("60 04 2E"))], \
        "models 1020 and 1120, firmware 46, lowest ID first"


def test_status_return_level():
    servo = Servo()
    bus = DynamixelWire([servo])
    servo.write(68, h("01"))
    assert len(exchange(bus, inst.read(1, 0, 2))) == 1, "level 1 answers READ"
    assert exchange(bus, inst.write(1, 65, h("01"))) == [], "level 1 does not answer WRITE"
    servo.write(68, h("00"))
    assert exchange(bus, inst.read(1, 0, 2)) == [], "level 0 does not answer READ"
    assert len(exchange(bus, inst.ping(1))) == 1, "PING is always answered"


def test_broadcast_write_executes_silently():
    bus = DynamixelWire([Servo(servo_id=1), Servo(servo_id=2)])
    assert exchange(bus, inst.write(BROADCAST_ID, 65, h("01"))) == [], "no status for broadcast WRITE"
    assert [s.get("led") for s in bus.servos] == [1, 1], "both servos wrote it"
    assert exchange(bus, inst.read(BROADCAST_ID, 65, 1)) == [], "READ is not executed by broadcast"


@pytest.mark.parametrize("packet, number, reason", [
    (inst.InstructionPacket(1, 0x07), ErrorNumber.INSTRUCTION, "0x07 is not an instruction"),
    (inst.InstructionPacket(1, 0x02, h("84 00 04")), ErrorNumber.DATA_LENGTH, "READ with 3 parameters"),
    (inst.InstructionPacket(1, 0x82, h("84 00 04 00 01")), ErrorNumber.INSTRUCTION,
     "sync read is broadcast only"),
    (inst.InstructionPacket(1, 0x10, h("01 44 58 4C 23")), ErrorNumber.DATA_RANGE, "wrong Clear key"),
    (inst.write(1, 102, le(1500, 2)), ErrorNumber.DATA_LIMIT, "Goal Current beyond the limit"),
])
def test_bus_error_replies(packet, number, reason):
    reply = exchange(DynamixelWire([Servo()]), packet)
    assert [(r.id, r.error) for r in reply] == [(1, number)], reason


def test_bad_crc_gets_a_crc_error_and_garbage_is_survived():
    bus = DynamixelWire([Servo()])
    frame = bytearray(inst.write(1, 65, h("01")).encode())
    frame[-1] ^= 0xFF
    replies = PacketReader().feed(bus.handle(b"\x00\xFF\x13" + bytes(frame) + inst.ping(1).encode()))
    assert [(r.id, r.error) for r in replies] == [(1, ErrorNumber.CRC), (1, 0)], "CRC error, then the ping"
    assert (bus.faults[Fault.CRC], bus.faults[Fault.GARBAGE]) == (1, 2), \
        "one bad frame; garbage before it and its own body after its header"
    assert bus.servo(1).get("led") == 0, "the corrupted write was not executed"


def test_alert_bit_rides_on_every_status():
    servo = Servo()
    servo.set_hardware_error(HardwareError.MOTOR_ENCODER)
    reply = exchange(DynamixelWire([servo]), inst.read(1, 70, 1))[0]
    assert (reply.error, reply.params) == (ALERT_BIT, h("08")), "alert bit; encoder error in status 70"


def test_secondary_id_executes_without_answering():
    primary, shadow = Servo(servo_id=1), Servo(servo_id=2)
    shadow.write(12, h("01"))
    replies = exchange(DynamixelWire([primary, shadow]), inst.write(1, 65, h("01")))
    assert len(replies) == 1 and (primary.get("led"), shadow.get("led")) == (1, 1), "one answer, two LEDs"


def test_broadcast_factory_reset_all_is_ignored():
    servo = Servo(servo_id=7)
    exchange(DynamixelWire([servo]), inst.factory_reset(BROADCAST_ID, ResetOption.ALL))
    assert servo.id == 7, "e-manual: broadcast with option 0xFF is not executed"


def test_fast_sync_read_needs_every_listed_servo():
    bus = DynamixelWire([Servo(servo_id=1), Servo(servo_id=2)])
    assert exchange(bus, inst.fast_sync_read(132, 4, [1, 9])) == [], "ID 9 missing: no reply at all"
    packet = exchange(bus, inst.fast_sync_read(132, 4, [2, 1]))[0]
    blocks = split_fast_reply(packet, [4, 4])
    assert [(b.id, b.data) for b in blocks] == [(2, le(2048, 4)), (1, le(2048, 4))], "request order"


def test_on_instruction_reports_each_transaction():
    seen = []
    bus = DynamixelWire([Servo(servo_id=1)], on_instruction=seen.append)
    bus.handle(inst.ping(1).encode() + inst.sync_write(65, 1, {1: h("01")}).encode(), 2.5)
    assert [(e.request.instruction, len(e.replies), e.time) for e in seen] == [(1, 1, 2.5), (0x83, 0, 2.5)], \
        "one exchange per instruction packet, with its replies and time"
    assert seen[0].replies[0].delay == pytest.approx(500e-6), "Return Delay Time 250 × 2 µs"


def test_watchdog_runs_on_the_bus_clock():
    bus = DynamixelWire([Servo()])
    exchange(bus, inst.write(1, 64, h("01")), inst.write(1, 98, h("01")), now=1.0)
    bus.tick(1.019)
    assert bus.servo(1).get("bus_watchdog") == 1, "19 ms < 20 ms"
    bus.tick(1.021)
    assert bus.servo(1).get("bus_watchdog") == -1, "21 ms of silence trips it"


# --- dynamixel-sdk through a pseudo-terminal ---------------------------------------------------

sdk = pytest.importorskip("dynamixel_sdk")


class PtyBus:
    """A DynamixelWire behind a pseudo-terminal: a thread reads what the SDK writes to the slave side
    and writes the bus's answer back. The bus clock is ``self.now`` (seconds), set by the test."""

    def __init__(self, servos):
        self.now = 0.0
        self.exchanges = []
        self.bus = DynamixelWire(servos, clock=lambda: self.now, on_instruction=self.exchanges.append)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        # a pseudo-terminal on a busy machine holds a reply back past the SDK's 34 ms (a
        # serving thread that waits for a core): the backend's patience for a simulated bus
        self.port = _patient(sdk.PortHandler(os.ttyname(self.slave)), PTY_REPLY_TIMEOUT["dynamixel"])
        assert self.port.openPort() and self.port.setBaudRate(1_000_000), "the pty opens like a serial port"
        self.ph = sdk.PacketHandler(2.0)

    def _serve(self):
        while not self._stop.is_set():
            if select.select([self.master], [], [], 0.01)[0]:
                answer = self.bus.handle(os.read(self.master, 4096))
                if answer:
                    os.write(self.master, answer)

    def close(self):
        self._stop.set()
        self._thread.join()
        self.port.closePort()
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture
def pty_bus():
    served = PtyBus([Servo(XM430_W350, 1), Servo(XM540_W270, 2)])
    yield served
    served.close()


def test_sdk_ping_and_broadcast_ping(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    assert ph.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0), "XM430-W350 answers its model number"
    assert ph.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT, "no servo 9: timeout"
    assert ph.broadcastPing(port) == ({1: [1020, 46], 2: [1120, 46]}, sdk.COMM_SUCCESS), "both, with firmware"


def test_sdk_reads_and_writes(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    assert ph.read2ByteTxRx(port, 2, 0) == (1120, sdk.COMM_SUCCESS, 0), "Model Number of the XM540"
    assert ph.read1ByteTxRx(port, 1, 9) == (250, sdk.COMM_SUCCESS, 0), "Return Delay Time default"
    assert ph.read4ByteTxRx(port, 1, 132) == (2048, sdk.COMM_SUCCESS, 0), "Present Position at zero"
    assert ph.write1ByteTxRx(port, 1, 65, 1) == (sdk.COMM_SUCCESS, 0), "LED on"
    assert ph.write2ByteTxRx(port, 1, 102, 300) == (sdk.COMM_SUCCESS, 0), "Goal Current 300 ≤ 1193"
    assert ph.write4ByteTxRx(port, 1, 116, 3000) == (sdk.COMM_SUCCESS, 0), "Goal Position in 0..4095"
    assert ph.readTxRx(port, 1, 102, 18)[0][14:18] == list(pack_field(3000, 4)), "Goal Position written"
    assert ph.read1ByteTxRx(port, 1, 65)[0] == 1 and ph.read2ByteTxRx(port, 1, 102)[0] == 300, "LED, current"


def test_sdk_eeprom_write_with_torque_on_is_an_access_error(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (sdk.COMM_SUCCESS, 0), "torque on"
    result, error = ph.write1ByteTxRx(port, 1, 11, 0)
    assert (result, error) == (sdk.COMM_SUCCESS, ErrorNumber.ACCESS), "Operating Mode is EEPROM"
    assert "not available" in ph.getRxPacketError(error), "the SDK's access error text"


def test_sdk_reg_write_and_action(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    assert ph.regWriteTxRx(port, 1, 116, 4, list(pack_field(1000, 4))) == (sdk.COMM_SUCCESS, 0), \
        "registered without error"
    assert ph.read4ByteTxRx(port, 1, 116)[0] == 2048, "registered, not applied"
    # broadcast: the SDK never reads the status of ACTION, so a unicast answer would linger
    assert ph.action(port, BROADCAST_ID) == sdk.COMM_SUCCESS, "sent; broadcast gets no status"
    assert ph.read4ByteTxRx(port, 1, 116)[0] == 1000, "applied by ACTION"


def test_sdk_reboot_factory_reset_and_clear(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    ph.write1ByteTxRx(port, 1, 9, 0)
    ph.write1ByteTxRx(port, 1, 64, 1)
    assert ph.reboot(port, 1) == (sdk.COMM_SUCCESS, 0), "status before the reboot"
    assert ph.read1ByteTxRx(port, 1, 64)[0] == 0, "reboot: torque off"
    assert ph.factoryReset(port, 1, ResetOption.EXCEPT_ID) == (sdk.COMM_SUCCESS, 0), "option 0x01"
    assert ph.read1ByteTxRx(port, 1, 9)[0] == 250, "factory reset: Return Delay Time back to 250"
    pty_bus.bus.servo(1).set_present(2.5 * 2 * math.pi, 0.0, 0.0)
    assert ph.read4ByteTxRx(port, 1, 132)[0] == 12288, "two and a half turns from 2048"
    assert ph.clearMultiTurn(port, 1) == (sdk.COMM_SUCCESS, 0), "stopped: accepted"
    assert ph.read4ByteTxRx(port, 1, 132)[0] == 0, "back within one turn"


def test_sdk_group_sync_read_and_write(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    pty_bus.bus.servo(2).set_present(math.pi / 2, 0.0, 0.0)
    writer = sdk.GroupSyncWrite(port, ph, 116, 4)
    writer.addParam(1, list(pack_field(1111, 4)))
    writer.addParam(2, list(pack_field(2222, 4)))
    assert writer.txPacket() == sdk.COMM_SUCCESS, "broadcast write sent"
    for fast in (False, True):
        reader = sdk.GroupSyncRead(port, ph, 116, 20)            # Goal Position .. Present Position
        reader.addParam(1)
        reader.addParam(2)
        assert (reader.fastSyncRead() if fast else reader.txRxPacket()) == sdk.COMM_SUCCESS, f"fast={fast}"
        assert [reader.getData(i, 116, 4) for i in (1, 2)] == [1111, 2222], f"fast={fast}: goals written"
        assert [reader.getData(i, 132, 4) for i in (1, 2)] == [2048, 3072], f"fast={fast}: positions"
    reader.addParam(9)
    assert reader.txRxPacket() == sdk.COMM_RX_TIMEOUT, "one missing servo fails the whole sync read"


def test_sdk_group_bulk_read_and_write(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    writer = sdk.GroupBulkWrite(port, ph)
    writer.addParam(1, 65, 1, [1])
    writer.addParam(2, 116, 4, list(pack_field(1000, 4)))
    assert writer.txPacket() == sdk.COMM_SUCCESS, "broadcast write sent"
    reader = sdk.GroupBulkRead(port, ph)
    reader.addParam(1, 65, 1)
    reader.addParam(2, 116, 4)
    for read in (reader.txRxPacket, reader.fastBulkRead):
        assert read() == sdk.COMM_SUCCESS, read.__name__
        assert (reader.getData(1, 65, 1), reader.getData(2, 116, 4)) == (1, 1000), f"{read.__name__}: written"


def test_sdk_watchdog_and_alert(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    ph.write1ByteTxRx(port, 1, 64, 1)
    ph.write1ByteTxRx(port, 1, 98, 1)
    pty_bus.now = 0.05                                          # 50 ms of silence > 20 ms
    assert ph.read1ByteTxRx(port, 1, 98) == (255, sdk.COMM_SUCCESS, 0), "tripped watchdog reads 0xFF"
    assert ph.write4ByteTxRx(port, 1, 116, 100) == (sdk.COMM_SUCCESS, ErrorNumber.DATA_RANGE), "goals locked"
    pty_bus.bus.servo(2).set_hardware_error(HardwareError.OVERHEATING)
    assert ph.read1ByteTxRx(port, 2, 70) == (4, sdk.COMM_SUCCESS, ALERT_BIT), "alert bit, overheating bit"


def test_sdk_survives_garbage_on_the_line(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    noise = random.Random(7).randbytes(64).replace(b"\xFF", b"\x00")   # no header can start inside it
    port.writePort(noise)
    assert ph.ping(port, 2) == (1120, sdk.COMM_SUCCESS, 0), "the bus skips bytes that begin no frame"
    # a frame begun (LEN 0x140: it waits for 320 bytes) and never finished: a servo abandons it
    # after a gap of the byte timeout, and the next header is heard
    port.writePort(bytes([0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x40, 0x01]) + noise)
    assert wait_until(lambda: pty_bus.bus.reader.pending >= 71, timeout=5.0), "the bus holds the frame begun"
    pty_bus.now += 2 * BYTE_TIMEOUT
    assert ph.ping(port, 2) == (1120, sdk.COMM_SUCCESS, 0), "the bus resynchronises after the byte timeout"
    assert pty_bus.bus.faults[Fault.TRUNCATED] == 1, "the abandoned frame is counted as truncated"


# dynamixel-sdk 4.1.0 computes LEN and CRC over the bytes it sends but never stuffs them (txPacket
# drops addStuffing's result). A spec-following servo unstuffs every FF FF FD FD it receives, so the
# data is intact unless FF FF FD is followed by FD; then one byte is lost and the write is refused.

def test_sdk_write_with_header_pattern_arrives_unstuffed(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    # Goal PWM −1 and Goal Current 253: FF FF FD 00 goes through intact
    assert ph.write4ByteTxRx(port, 1, 100, 0x00FDFFFF) == (sdk.COMM_SUCCESS, 0), "accepted"
    assert pty_bus.exchanges[-1].request.params == h("64 00 FF FF FD 00"), "CRC matched, data intact"
    # Goal PWM −1 and Goal Current −515: FF FF FD FD loses an FD on the servo side
    assert ph.write4ByteTxRx(port, 1, 100, 0xFDFDFFFF) == (sdk.COMM_SUCCESS, ErrorNumber.DATA_LENGTH), \
        "3 data bytes left: Goal Current cut in half, a data length error"
    assert pty_bus.exchanges[-1].request.params == h("64 00 FF FF FD"), "what the servo saw"
    # the same write stuffed by servodyn's codec, through the SDK's own receive path
    port.clearPort()
    port.writePort(inst.write(1, 100, h("FF FF FD FD")).encode())
    port.setPacketTimeout(11)
    status, result = ph.rxPacket(port, False)
    assert (result, status[8]) == (sdk.COMM_SUCCESS, 0), "the stuffed write is accepted"
    assert ph.readTxRx(port, 1, 100, 4)[0] == list(h("FF FF FD FD")), "Goal PWM −1, Goal Current −515"


def test_sdk_unstuffs_status_with_present_current_minus_one(pty_bus):
    port, ph = pty_bus.port, pty_bus.ph
    pty_bus.bus.servo(1).set_present(0.0, -3 * VELOCITY_UNIT, -XM430_W350.current_unit)
    data, result, error = ph.readTxRx(port, 1, 126, 6)
    assert data == list(h("FF FF FD FF FF FF")), "current −1, velocity −3, unstuffed by the SDK"
    wire = pty_bus.exchanges[-1].replies[0].data
    assert wire[5:7] == h("0B 00") and wire[9:13] == h("FF FF FD FD"), "sent stuffed: LEN 11"
    reader = sdk.GroupSyncRead(port, ph, 126, 6)
    reader.addParam(1)
    assert reader.fastSyncRead() == sdk.COMM_SUCCESS, "one reply from 0xFE"
    assert (reader.getData(1, 126, 2), reader.getData(1, 128, 4)) == (0xFFFF, 0xFFFFFFFD), \
        "a fast reply is not stuffed, and the SDK does not unstuff it"


def test_sdk_fast_bulk_read_misparses_an_id_equal_to_an_earlier_parameter_byte():
    """dynamixel-sdk 4.1.0 finds each block's length with ``param.index(id)`` over the flattened
    (id, address, length) list: ID 4 matches the length byte 4 of ID 3's entry, so it takes 146 (the
    next byte) as the length, skips past ID 5's block and still reports success with stale data."""
    served = PtyBus([Servo(servo_id=3), Servo(servo_id=4), Servo(servo_id=5)])
    try:
        served.bus.servo(5).write(65, h("01"))
        reader = sdk.GroupBulkRead(served.port, served.ph)
        for servo_id, address, length in ((3, 132, 4), (4, 146, 1), (5, 65, 1)):
            reader.addParam(servo_id, address, length)
        reader.data_dict[5][0] = bytearray(h("07"))              # a stale value to be left alone
        assert reader.fastBulkRead() == sdk.COMM_SUCCESS, "the SDK reports success"
        assert reader.getData(5, 65, 1) == 7, "yet LED of ID 5 is the stale 7, not the 1 on the wire"
        reply = PacketReader().feed(served.exchanges[-1].replies[0].data)[0]
        blocks = split_fast_reply(reply, [4, 1, 1])
        assert [(b.id, b.data) for b in blocks] == [(3, le(2048, 4)), (4, h("1E")), (5, h("01"))], \
            "servodyn's codec splits the same reply correctly"
    finally:
        served.close()
