"""The Dynamixel backend of the servo bus, over dynamixel-sdk and pyserial.

Torque feed-forward mode: every servo runs in Current Control Mode (Operating Mode 0) and the
host closes the joint PD itself, so the torque the controller computes — feed-forward plus PD —
is exactly what it asks of the motor (as current through the configured torque constant). In
Current-based Position Mode the Goal Current is only a limit on the servo's own position loop,
so the feed-forward could not be added (see the notes on what users struggle with).

A tick is two transactions: one fast sync read (0x8A) of Present Current, Velocity and Position
(addresses 126..135) that every servo answers inside one status packet, and one sync write of
Goal Current. A joint driven in PWM Control Mode (a servo without current control: pwm.py) gets its
torque as Goal PWM through the motor model; a bus with one writes every goal in one bulk write
instead (Goal PWM at 100 or Goal Current at 102, each servo its own). At open: Return Delay Time 0, Current Control Mode, Hardware Error Status checked,
the Bus Watchdog armed so the servos stop if the host dies.

dynamixel-sdk 4.1.0 sends instruction packets without byte stuffing, and its fastSyncRead takes
the reply's blocks at fixed offsets and keeps only their data (no block CRC, no error byte, so
no alert). So the SDK is used for the port and to send: every packet goes out through
`StuffingPacketHandler`, which frames and stuffs it with servodyn's codec (hal.dynamixel.protocol),
so data that contains FF FF FD arrives intact. The fast reply is read from the port and parsed
by the codec: packet CRC, each block's running CRC, ID and error byte.
A missing or short reply is retried; then each servo is pinged to name the one that is silent
(ServoTimeoutError) — the silent ones twice, so a bus that went quiet as a whole and came back
while it was being pinged is a stall of the bus (BusStallError), not blamed on one servo. With
torque on, a bus silent for longer than the servos' Bus Watchdog across a failed try is a stall
at once: the servos have let go by themselves, and retrying would take a late reply for the
retry's. An error byte with the alert bit set makes the backend read that servo's
Hardware Error Status and raise ServoHardwareError with its bits.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from ...control.timing import BUS_WATCHDOG
from ..bringup import ERROR
from ..bus import PORT_ERRORS, JointCommand, JointState, ServoBus, port_gone
from ..errors import (ServoError, ServoHardwareError, ServoInitializationError, ServoOperationError,
                      ServoTimeoutError)
from ..port_access import claim_port, open_failure
from ..ports import is_pseudo_terminal
from . import bringup as bench
from .control_table import (TABLE_SIZE, ADDR_BUS_WATCHDOG, ADDR_GOAL_CURRENT, ITEMS,
                            ADDR_OPERATING_MODE, ADDR_PRESENT, ADDR_RETURN_DELAY, ADDR_TORQUE_ENABLE,
                            PRESENT_LENGTH, PRESENT_WITH_TEMPERATURE_LENGTH, OperatingMode, hardware_faults,
                            watchdog_units)
from . import _dxl
from . import instructions
from .diagnosis import Diagnosis
from .fast_read import FastRead
from .protocol import BROADCAST_ID, Instruction, encode_frame
from .pwm import PwmDrive, pwm_driven
from .units import ServoMap

ADDR_GOAL_PWM = ITEMS["goal_pwm"].address
GOAL = np.dtype([("id", "u1"), ("current", "<i2")])      # one servo's part of the Goal Current sync write
# one servo's part of the bulk write of a bus with joints in PWM mode: Goal PWM or Goal Current
BULK_GOAL = np.dtype([("id", "u1"), ("address", "<u2"), ("length", "<u2"), ("current", "<i2")])


def _patient(port, reply_timeout: float | None):
    """The SDK's port, whose every packet timeout (a ping, a register read or write) is at least
    reply_timeout: a pseudo-terminal under load holds a reply back longer than the SDK's 34 ms,
    and a register read then looked like a servo that stopped answering."""
    if reply_timeout is None:
        return port
    set_timeout = port.setPacketTimeout

    def at_least(packet_length):
        set_timeout(packet_length)
        port.packet_timeout = max(port.packet_timeout, reply_timeout * 1e3)
    port.setPacketTimeout = at_least
    return port


def _stuffing_packet_handler():
    """A Protocol 2.0 packet handler whose txPacket sends correctly stuffed frames."""
    from dynamixel_sdk import protocol2_packet_handler as p2
    from dynamixel_sdk.robotis_def import COMM_PORT_BUSY, COMM_SUCCESS, COMM_TX_ERROR, COMM_TX_FAIL

    class StuffingPacketHandler(p2.Protocol2PacketHandler):
        def txPacket(self, port, txpacket):
            if port.is_using:
                return COMM_PORT_BUSY
            port.is_using = True
            length = txpacket[5] | (txpacket[6] << 8)     # instruction, parameters, CRC
            frame = encode_frame(txpacket[4], bytes(txpacket[7:7 + length - 2]), stuffed=True)
            if len(frame) > p2.TXPACKET_MAX_LEN:
                port.is_using = False
                return COMM_TX_ERROR
            port.clearPort()
            if port.writePort(list(frame)) != len(frame):
                port.is_using = False
                return COMM_TX_FAIL
            return COMM_SUCCESS

    return StuffingPacketHandler()


class DynamixelBus(FastRead, Diagnosis, ServoBus):
    kind = "dynamixel"

    def __init__(self, config, bus=None, *, port: str | None = None, retries: int = 2,
                 watchdog: float = BUS_WATCHDOG, reply_timeout: float | None = None, realtime: bool = True,
                 **kwargs):
        """retries: tries after the first before a read fails; watchdog: s of bus silence after
        which the servos stop; reply_timeout: s to wait for the fast sync read reply, and at least
        that for any other reply (None: the SDK's packet timeout, wire time + 2 x 16 ms USB
        latency + 2 ms); realtime: the bus carries a real-time loop, so an adapter whose latency
        timer stays above 1 ms is refused at open (False: bring-up commands, which only ask)."""
        super().__init__(config, bus, **kwargs)
        self.realtime = realtime
        self.port_name = port or self.bus.port
        if self.port_name in (None, "", "auto"):
            raise ServoInitializationError(f"bus '{self.bus.name}': no serial port (port = 'auto' means "
                                           "the simulated bus: start it with `servodyn sim`)")
        self.units = ServoMap.from_joints(self.joints)
        self.retries = retries
        self.watchdog = watchdog
        self.reply_timeout = reply_timeout
        self.ids = [j.id for j in self.joints]
        self._last: JointState | None = None
        self._armed = False              # the servos' Bus Watchdog is set (torque on)
        self._last_packet = None         # time.monotonic() of the tick's last instruction packet
        self._heard = None               # time.monotonic() when the bus last answered (any bytes)
        self._got = 0                    # bytes the last fast sync read's try received
        self._late_at = None             # time.monotonic() of the first byte _drain dropped

    # ---------------------------------------------------------------- set-up
    def _open(self) -> None:
        import dynamixel_sdk as sdk
        self._sdk = sdk
        self.port = _patient(sdk.PortHandler(self.port_name), self.reply_timeout)
        try:
            opened = self.port.openPort()
        except Exception as err:      # pyserial raises its own kinds, most with the OS's errno
            reason = err.errno if isinstance(getattr(err, "errno", None), int) else err
            raise ServoInitializationError(open_failure(self.port_name, reason)) from None
        if not opened or not self.port.setBaudRate(int(self.bus.baud)):
            raise ServoInitializationError(f"{self.port_name}: cannot open at {self.bus.baud} baud")
        if not is_pseudo_terminal(self.port_name):      # a real adapter (the simulator's is a pty)
            try:                                        # ours alone, its latency timer at 1 ms
                claim_port(self.port.ser.fileno(), self.port_name, realtime=self.realtime)
            except ServoInitializationError:
                self.port.closePort()
                raise
        self.packets = _stuffing_packet_handler()
        for joint in self.joints:
            self._check_servo(joint)
            self._write_item(joint, ADDR_TORQUE_ENABLE, 1, 0)      # EEPROM writes need torque off
            self._write_item(joint, ADDR_RETURN_DELAY, 1, 0)
            self._write_item(joint, ADDR_OPERATING_MODE, 1,
                             OperatingMode.PWM if pwm_driven(joint) else OperatingMode.CURRENT)
            self._write_item(joint, ADDR_BUS_WATCHDOG, 1, 0)       # clear a tripped watchdog
        # the tick's two packets, built once: the fast sync read is constant; the sync write's
        # parameters are a record array the goals are written into (its frame needs no stuffing:
        # FF FF FD would have to be a current's two bytes followed by ID 0xFD, and IDs end at 252)
        self._read_frames = {n: instructions.fast_sync_read(ADDR_PRESENT, n, self.ids).encode()
                             for n in (PRESENT_LENGTH, PRESENT_WITH_TEMPERATURE_LENGTH)}
        self._length = PRESENT_LENGTH          # the span of the read in flight
        self._temperature_in = 0               # reads until the next one that takes the temperature
        self.temperature = np.full(len(self.ids), np.nan)   # °C, as last read
        self.pwm = PwmDrive(self.joints, self.config.supply.voltage if self.config.supply else None)
        if len(self.pwm):         # no stuffing either: FF FF FD would need ID 0xFD after a goal's bytes
            self._goal = np.zeros(len(self.ids), dtype=BULK_GOAL)
            self._goal["address"] = ADDR_GOAL_CURRENT
            self._goal["address"][self.pwm.index] = ADDR_GOAL_PWM
            self._goal["length"] = 2
            self._goal_head = bytes([Instruction.BULK_WRITE])
        else:
            self._goal = np.zeros(len(self.ids), dtype=GOAL)
            self._goal_head = bytes([Instruction.SYNC_WRITE]) + ADDR_GOAL_CURRENT.to_bytes(2, "little") + \
                (GOAL.itemsize - 1).to_bytes(2, "little")
        self._goal["id"] = self.ids
        self._id_bytes = bytes(self.ids)
        self._reader = _dxl.Reader()
        self._fault = None
        try:
            self._fileno = self.port.ser.fileno()      # to wait for the reply without spinning
        except (AttributeError, OSError, ValueError):
            self._fileno = None

    def _close(self) -> None:
        self.port.closePort()

    def _enable_torque(self, on: bool) -> None:
        for joint in self.joints:
            if on:         # PWM mode: Goal PWM 0 first, or the servo starts at its PWM Limit (e-manual)
                self._write_item(joint, ADDR_GOAL_PWM if pwm_driven(joint) else ADDR_GOAL_CURRENT, 2, 0)
                self._write_item(joint, ADDR_TORQUE_ENABLE, 1, 1)
            else:
                self._write_item(joint, ADDR_BUS_WATCHDOG, 1, 0)
                self._write_item(joint, ADDR_TORQUE_ENABLE, 1, 0)
        if on:
            # the watchdogs armed last, back to back: a servo does not hear packets to the others,
            # so one armed first would count a slow host's whole set-up as silence
            units = watchdog_units(self.watchdog)
            for joint in self.joints:
                self._write_item(joint, ADDR_BUS_WATCHDOG, 1, units)
        self._armed, self._last_packet = on, time.monotonic()
        self._heard = self._last_packet         # every write above was answered

    def _stop(self) -> bool:
        """Torque off on every servo that answers, each with its retries (one try once the port is
        known gone); True if all did. A port that fails ends it at once: no servo can be told. A
        transaction cut short (a signal in the middle of one) must not leave the port busy."""
        self.port.is_using = False
        ok = True
        tries = 1 if self.lost else self.retries + 1
        for joint in self.joints:
            for _ in range(tries):
                try:
                    result, error = self.packets.write1ByteTxRx(self.port, joint.id, ADDR_TORQUE_ENABLE, 0)
                except PORT_ERRORS as err:
                    self.lost = self.lost or port_gone(err) or str(err)
                    return False
                if result == self._sdk.COMM_SUCCESS:
                    break
            else:
                ok = False
        return ok

    def _gone(self, err: Exception) -> ServoOperationError:
        """The one-line error of a port that failed under a read or a write (pyserial's or the OS's
        error would end the run in a traceback); marks the bus lost when the port is gone."""
        reason = port_gone(err)
        self.lost = self.lost or reason
        return ServoOperationError(f"bus '{self.bus.name}': the port {self.port_name} "
                                   f"{'is gone' if reason else 'failed'} ({reason or err})")

    # ---------------------------------------------------------------- one tick
    def _read(self) -> JointState:
        try:
            return self._read_present()
        except ServoError:             # a TimeoutError, so an OSError too: the read's own verdict
            raise
        except PORT_ERRORS as err:     # the port itself failed: no retry or ping can reach a servo
            raise self._gone(err) from None

    def _write(self, command: JointCommand) -> None:
        if self._fault is not None:         # a sync write gets no reply: the last read's alert stands
            joint, status = self._fault
            raise ServoHardwareError(joint.dof, joint.id, status, hardware_faults(status))
        if self._last is None:
            raise ServoOperationError("write before the first read_state: the PD needs a measured state")
        tau = command.torque_at(self._last.q, self._last.qd)
        units, limited = self.units.goal_current_units(tau, self.current_limit)
        if len(self.pwm):
            k = self.pwm.index
            units[k], limited[k] = self.pwm.goal_pwm(tau, self._last.qd, self.temperature)
        self.stats.limited += limited
        self._goal["current"] = units
        frame = encode_frame(BROADCAST_ID, self._goal_head + self._goal.tobytes(), stuffed=False)
        sent = 0 if self.port.is_using else self._send(frame)
        self._last_packet = time.monotonic()
        if sent != len(frame):
            why = f"is gone: {self.lost}" if self.lost else "is busy" if self.port.is_using else "took part of it"
            raise ServoOperationError(f"bus '{self.bus.name}': goal write failed (the port {why})")

    def sync_write(self, address: int, data_by_id: Mapping[int, bytes]) -> None:
        """One sync write of equal-length table bytes at ``address``, by servo ID, framed and stuffed
        by servodyn's codec: for items the tick does not write (Goal Position in a position mode,
        limits, gains). No servo answers a sync write."""
        self._check_open()
        sizes = {len(data) for data in data_by_id.values()}
        if len(sizes) != 1:
            raise ValueError("sync_write: one data length for every servo")
        writer = self._sdk.GroupSyncWrite(self.port, self.packets, address, sizes.pop())
        for servo_id, data in data_by_id.items():
            writer.addParam(servo_id, list(data))
        result = writer.txPacket()
        if result != self._sdk.COMM_SUCCESS:
            raise ServoOperationError(f"bus '{self.bus.name}': sync write to address {address} failed "
                                      f"({self.packets.getTxRxResult(result)})")


    def _check_servo(self, joint) -> None:
        """At open: the servo answers, and its control table is one a run can accept (the checks
        `servodyn doctor` makes, hal.dynamixel.bringup.table_findings): the first that is not ends the
        open in one line with its fix. A latched hardware error is a ServoHardwareError."""
        for _ in range(self.retries + 1):
            data, result, error = self.packets.readTxRx(self.port, joint.id, 0, TABLE_SIZE)
            if result == self._sdk.COMM_SUCCESS:
                break
        if result != self._sdk.COMM_SUCCESS:
            raise ServoInitializationError(
                f"joint '{joint.dof}' (id {joint.id}) did not answer at {self.bus.baud} baud on {self.port_name} "
                f"({self.packets.getTxRxResult(result)}): check its power and cable, and that it was set up "
                f"(ID {joint.id}, {self.bus.baud} baud); `servodyn scan --port {self.port_name} --config "
                f"{self.config.argument}` looks at every ID and rate")
        table = bench.decode_table(bytes(data))
        if table["hardware_error_status"] and table["model_number"] == joint.servo.model_number:
            status = table["hardware_error_status"]
            raise ServoHardwareError(joint.dof, joint.id, status, hardware_faults(status))
        supply = self.config.supply.voltage if self.config.supply else None
        refused = [f for f in bench.table_findings(joint, table, supply, self.bus.name) if f.severity == ERROR]
        if refused:
            more = f" (and {len(refused) - 1} more: `servodyn doctor` lists them)" if len(refused) > 1 else ""
            raise ServoInitializationError(refused[0].line() + more)

    def _read_item(self, joint, address: int, size: int) -> int:
        read = {1: self.packets.read1ByteTxRx, 2: self.packets.read2ByteTxRx,
                4: self.packets.read4ByteTxRx}[size]
        for _ in range(self.retries + 1):
            value, result, error = read(self.port, joint.id, address)
            if result == self._sdk.COMM_SUCCESS:
                return value
        raise ServoTimeoutError(joint.dof, joint.id, self.packets.getTxRxResult(result))

    def _write_item(self, joint, address: int, size: int, value: int) -> None:
        write = {1: self.packets.write1ByteTxRx, 2: self.packets.write2ByteTxRx}[size]
        for _ in range(self.retries + 1):
            result, error = write(self.port, joint.id, address, value)
            if result == self._sdk.COMM_SUCCESS:
                if error & 0x7F:
                    raise ServoOperationError(f"joint '{joint.dof}': servo {joint.id} refused a write "
                                              f"to address {address} ({self.packets.getRxPacketError(error)})")
                return
        raise ServoTimeoutError(joint.dof, joint.id, self.packets.getTxRxResult(result))
