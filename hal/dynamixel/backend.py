"""The Dynamixel backend of the servo bus, over dynamixel-sdk and pyserial.

Torque feed-forward mode: every servo runs in Current Control Mode (Operating Mode 0) and the
host closes the joint PD itself, so the torque the controller computes — feed-forward plus PD —
is exactly what it asks of the motor (as current through the configured torque constant). In
Current-based Position Mode the Goal Current is only a limit on the servo's own position loop,
so the feed-forward could not be added (see the notes on what users struggle with).

A tick is two transactions: one sync read of Present Current, Velocity and Position (addresses
126..135, one read), one sync write of Goal Current. At open: Return Delay Time 0, Current
Control Mode, Hardware Error Status checked, the Bus Watchdog armed so the servos stop if the
host dies. dynamixel-sdk 4.1.0 sends instruction packets without byte stuffing; servodyn frames
its packets itself (hal.dynamixel.protocol), so data that contains FF FF FD arrives intact.
"""

from __future__ import annotations

import time

import numpy as np

from ..bus import (JointCommand, JointState, ServoBus, ServoHardwareError, ServoInitializationError,
                   ServoOperationError, ServoTimeoutError)
from .protocol import encode_frame

ADDR_MODEL_NUMBER = 0
ADDR_RETURN_DELAY = 9
ADDR_OPERATING_MODE = 11
ADDR_TORQUE_ENABLE = 64
ADDR_HARDWARE_ERROR = 70
ADDR_BUS_WATCHDOG = 98
ADDR_GOAL_CURRENT = 102
ADDR_PRESENT = 126                  # Present Current (2), Velocity (4), Position (4)
PRESENT_LENGTH = 10
CURRENT_MODE = 0
WATCHDOG_UNIT = 0.02                # s per Bus Watchdog unit


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


class DynamixelBus(ServoBus):
    kind = "dynamixel"

    def __init__(self, config, bus=None, *, port: str | None = None, retries: int = 2,
                 watchdog: float = 0.1, **kwargs):
        super().__init__(config, bus, **kwargs)
        self.port_name = port or self.bus.port
        if self.port_name in (None, "", "auto"):
            raise ServoInitializationError(f"bus '{self.bus.name}': no serial port (port = 'auto' means "
                                           "the simulated bus: start it with `servodyn sim`)")
        self.retries = retries
        self.watchdog = watchdog
        self.ids = [j.id for j in self.joints]
        self._last: JointState | None = None

    # ---------------------------------------------------------------- set-up
    def _open(self) -> None:
        import dynamixel_sdk as sdk
        self._sdk = sdk
        self.port = sdk.PortHandler(self.port_name)
        try:
            opened = self.port.openPort()
        except Exception as err:      # pyserial raises its own kinds
            raise ServoInitializationError(f"{self.port_name}: cannot open ({err})") from None
        if not opened or not self.port.setBaudRate(int(self.bus.baud)):
            raise ServoInitializationError(f"{self.port_name}: cannot open at {self.bus.baud} baud")
        self.packets = _stuffing_packet_handler()
        for joint in self.joints:
            number = self._read_item(joint, ADDR_MODEL_NUMBER, 2)
            if number != joint.servo.model_number:
                raise ServoInitializationError(f"joint '{joint.dof}': servo {joint.id} is model {number}, "
                                               f"the configuration says {joint.servo.name}")
            self._check_hardware(joint)
            self._write_item(joint, ADDR_TORQUE_ENABLE, 1, 0)      # EEPROM writes need torque off
            self._write_item(joint, ADDR_RETURN_DELAY, 1, 0)
            self._write_item(joint, ADDR_OPERATING_MODE, 1, CURRENT_MODE)
            self._write_item(joint, ADDR_BUS_WATCHDOG, 1, 0)       # clear a tripped watchdog
        self._reader = sdk.GroupSyncRead(self.port, self.packets, ADDR_PRESENT, PRESENT_LENGTH)
        for servo_id in self.ids:
            self._reader.addParam(servo_id)
        self._writer = sdk.GroupSyncWrite(self.port, self.packets, ADDR_GOAL_CURRENT, 2)

    def _close(self) -> None:
        self.port.closePort()

    def _enable_torque(self, on: bool) -> None:
        units = max(1, int(round(self.watchdog / WATCHDOG_UNIT)))
        for joint in self.joints:
            if on:
                self._write_item(joint, ADDR_GOAL_CURRENT, 2, 0)
                self._write_item(joint, ADDR_TORQUE_ENABLE, 1, 1)
                self._write_item(joint, ADDR_BUS_WATCHDOG, 1, units)
            else:
                self._write_item(joint, ADDR_BUS_WATCHDOG, 1, 0)
                self._write_item(joint, ADDR_TORQUE_ENABLE, 1, 0)

    def disable_torque_now(self) -> bool:
        """Best effort, for the safe stop: torque off on every servo that answers; True if all did."""
        ok = True
        for joint in self.joints:
            for _ in range(self.retries + 1):
                result, error = self.packets.write1ByteTxRx(self.port, joint.id, ADDR_TORQUE_ENABLE, 0)
                if result == self._sdk.COMM_SUCCESS:
                    break
            else:
                ok = False
        return ok

    # ---------------------------------------------------------------- one tick
    def _read(self) -> JointState:
        """One sync read; the replies are taken servo by servo so that each one's error byte is
        seen (an alert means a hardware error) and a missing reply names its servo."""
        sdk = self._sdk
        for attempt in range(self.retries + 1):
            result = self._reader.txPacket()
            rows, errors, missing = [], [], None
            if result == sdk.COMM_SUCCESS:
                for joint in self.joints:
                    data, result, error = self.packets.readRx(self.port, joint.id, PRESENT_LENGTH)
                    if result != sdk.COMM_SUCCESS:
                        missing = joint
                        break
                    rows.append(bytes(data))
                    errors.append(error)
            if missing is None and result == sdk.COMM_SUCCESS:
                break
        else:
            if missing is not None:
                raise ServoTimeoutError(missing.dof, missing.id, self.packets.getTxRxResult(result))
            raise self._diagnose(self.packets.getTxRxResult(result))
        for joint, error in zip(self.joints, errors):
            if error & 0x80:
                self._check_hardware(joint)
        current = np.array([int.from_bytes(r[0:2], "little", signed=True) for r in rows])
        velocity = np.array([int.from_bytes(r[2:6], "little", signed=True) for r in rows])
        position = np.array([int.from_bytes(r[6:10], "little", signed=True) for r in rows])
        u = self.units
        state = JointState(t=time.monotonic(), q=u.from_ticks(position), qd=u.from_velocity_units(velocity),
                           current=u.current_from_units(current), tau=u.from_current_units(current))
        self._last = state
        return state

    def _write(self, command: JointCommand) -> None:
        if self._last is None:
            raise ServoOperationError("write before the first read_state: the PD needs a measured state")
        tau = command.torque_at(self._last.q, self._last.qd)
        limit = np.array([j.current_limit for j in self.joints])
        current = np.clip(self.units.current(tau), -limit, limit)
        self.limited += current != self.units.current(tau)
        units = np.rint(self.units.direction * current / self.units.current_unit).astype(np.int64)
        self._writer.clearParam()
        for servo_id, value in zip(self.ids, units):
            self._writer.addParam(servo_id, list(int(value).to_bytes(2, "little", signed=True)))
        result = self._writer.txPacket()
        if result != self._sdk.COMM_SUCCESS:
            raise ServoOperationError(f"bus '{self.bus.name}': goal write failed "
                                      f"({self.packets.getTxRxResult(result)})")

    # ---------------------------------------------------------------- helpers
    def _diagnose(self, detail: str) -> ServoTimeoutError:
        """After a failed read, ping each servo to name the one that stopped answering."""
        for joint in self.joints:
            _, result, _ = self.packets.ping(self.port, joint.id)
            if result != self._sdk.COMM_SUCCESS:
                return ServoTimeoutError(joint.dof, joint.id, detail)
        return ServoTimeoutError(self.joints[0].dof, self.joints[0].id, f"{detail} (every servo answers a ping)")

    def _check_hardware(self, joint) -> None:
        status = self._read_item(joint, ADDR_HARDWARE_ERROR, 1)
        if status:
            raise ServoHardwareError(joint.dof, joint.id, status)

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
