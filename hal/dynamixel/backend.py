"""The Dynamixel backend of the servo bus, over dynamixel-sdk and pyserial.

Torque feed-forward mode: every servo runs in Current Control Mode (Operating Mode 0) and the
host closes the joint PD itself, so the torque the controller computes — feed-forward plus PD —
is exactly what it asks of the motor (as current through the configured torque constant). In
Current-based Position Mode the Goal Current is only a limit on the servo's own position loop,
so the feed-forward could not be added (see the notes on what users struggle with).

A tick is two transactions: one fast sync read (0x8A) of Present Current, Velocity and Position
(addresses 126..135) that every servo answers inside one status packet, and one sync write of
Goal Current. At open: Return Delay Time 0, Current Control Mode, Hardware Error Status checked,
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

import os
import select
import time
from collections.abc import Mapping

import numpy as np

from ...control.timing import BUS_WATCHDOG
from ..bringup import ERROR
from ..bus import PORT_ERRORS, JointCommand, JointState, ServoBus, port_gone
from ..errors import (BusStallError, ServoError, ServoHardwareError, ServoInitializationError,
                      ServoOperationError, ServoTimeoutError)
from ..port_access import claim_port, open_failure
from ..ports import is_pseudo_terminal
from . import bringup as bench
from .control_table import (TABLE_SIZE, ADDR_BUS_WATCHDOG, ADDR_GOAL_CURRENT, ADDR_HARDWARE_ERROR,
                            ADDR_OPERATING_MODE, ADDR_PRESENT, ADDR_RETURN_DELAY, ADDR_TORQUE_ENABLE,
                            PRESENT_LENGTH, PRESENT_WITH_TEMPERATURE_LENGTH, OperatingMode, hardware_faults,
                            watchdog_units)
from . import _dxl
from . import instructions
from .instructions import fast_reply_blocks
from .protocol import ALERT_BIT, BROADCAST_ID, HEADER, Instruction, encode_frame
from .units import ServoMap

# a fast sync read reply's data block: Present Current (2), Velocity (4), Position (4)
PRESENT = np.dtype([("current", "<i2"), ("velocity", "<i4"), ("position", "<i4")])
# ... and on to Present Temperature: velocity and position trajectories, input voltage, temperature
PRESENT_WITH_TEMPERATURE = np.dtype({"names": ["current", "velocity", "position", "temperature"],
                                     "formats": ["<i2", "<i4", "<i4", "u1"],
                                     "offsets": [0, 2, 6, PRESENT_WITH_TEMPERATURE_LENGTH - 1],
                                     "itemsize": PRESENT_WITH_TEMPERATURE_LENGTH})
# every this many reads, the tick's read runs on to Present Temperature: 11 more bytes a servo
# (at 4 Mbaud, 7 servos: 0.19 ms) on one tick in a hundred, no transaction of its own (a round
# trip through a USB adapter costs a millisecond); a winding's temperature changes over seconds
# and the servo reports it in whole degrees
TEMPERATURE_EVERY = 100
GOAL = np.dtype([("id", "u1"), ("current", "<i2")])      # one servo's part of the Goal Current sync write


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


NO_REPLY = "no fast sync read reply"


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
            self._write_item(joint, ADDR_OPERATING_MODE, 1, OperatingMode.CURRENT)
            self._write_item(joint, ADDR_BUS_WATCHDOG, 1, 0)       # clear a tripped watchdog
        # the tick's two packets, built once: the fast sync read is constant; the sync write's
        # parameters are a record array the goals are written into (its frame needs no stuffing:
        # FF FF FD would have to be a current's two bytes followed by ID 0xFD, and IDs end at 252)
        self._read_frames = {n: instructions.fast_sync_read(ADDR_PRESENT, n, self.ids).encode()
                             for n in (PRESENT_LENGTH, PRESENT_WITH_TEMPERATURE_LENGTH)}
        self._length = PRESENT_LENGTH          # the span of the read in flight
        self._temperature_in = 0               # reads until the next one that takes the temperature
        self.temperature = np.full(len(self.ids), np.nan)   # °C, as last read
        self._goal = np.zeros(len(self.ids), dtype=GOAL)
        self._goal["id"] = self.ids
        self._goal_head = bytes([Instruction.SYNC_WRITE]) + ADDR_GOAL_CURRENT.to_bytes(2, "little") + \
            (GOAL.itemsize - 1).to_bytes(2, "little")
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
            if on:
                self._write_item(joint, ADDR_GOAL_CURRENT, 2, 0)
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

    def _read_present(self) -> JointState:
        """One fast sync read of Present Current, Velocity and Position of every servo. A missing,
        short or corrupt reply is retried; after the last retry each servo is pinged and the one
        that does not answer is named. A block whose error byte carries the alert bit makes the
        backend read that servo's Hardware Error Status and raise ServoHardwareError. After a
        silence of over half the Bus Watchdog (the servos' clocks and this one's are not the same)
        the servos may have stopped themselves: they are asked, and a tripped watchdog is a
        BusStallError (their goals are refused until it is cleared). With torque on, a bus that
        said nothing for longer than the Bus Watchdog across a failed try is a BusStallError too
        (_check_silence): the servos have let go by themselves, and a reply that comes after such
        a silence may be an earlier request's, held back with it."""
        if self._armed and self._last_packet is not None and time.monotonic() - self._last_packet > self.watchdog / 2:
            self._check_watchdog(time.monotonic() - self._last_packet)
        silent = False                      # a try to which nothing at all came back
        self._length = PRESENT_WITH_TEMPERATURE_LENGTH if self._temperature_in <= 0 else PRESENT_LENGTH
        for _ in range(self.retries + 1):
            blocks, failure, suspect = self._fast_sync_read()
            if blocks is not None:
                break
            self.stats.reads_retried += 1
            if self._got:                   # cut or corrupt, but the bus spoke
                self._heard = time.monotonic()
            late = self._drain()
            if late and failure == NO_REPLY:
                # nothing in time, then the reply after its time-out: the whole bus held back
                # (a stall, or a chain waiting on a slow servo); retrying would take late replies
                silent = "" if self._heard is None else \
                    f" (the bus silent for {(self._late_at - self._heard) * 1e3:.0f} ms before them)"
                raise BusStallError(self.bus.name, f"{NO_REPLY} in time; {late} bytes came after the "
                                                   f"time-out and were dropped{silent}")
            if late:
                self._heard = self._late_at
            elif not self._got:             # only a wholly silent try counts: a drain is quiet by design
                silent = True
                self._check_silence(time.monotonic())
        else:
            raise self._corrupt_line(failure) or self._diagnose(failure, suspect)
        errors, data = blocks
        if any(errors):
            for joint, error in zip(self.joints, errors):
                if error & ALERT_BIT:
                    status = self._read_item(joint, ADDR_HARDWARE_ERROR, 1)
                    if status:
                        self._fault = (joint, status)          # write() refuses while it stands
                        raise ServoHardwareError(joint.dof, joint.id, status, hardware_faults(status))
                if error & ~ALERT_BIT:
                    raise ServoOperationError(f"joint '{joint.dof}': servo {joint.id} refused the read "
                                              f"({self.packets.getRxPacketError(error & ~ALERT_BIT)})")
        self._fault = None
        if self._length == PRESENT_LENGTH:
            rows = np.frombuffer(data, dtype=PRESENT)
            self._temperature_in -= 1
        else:
            rows = np.frombuffer(data, dtype=PRESENT_WITH_TEMPERATURE)
            self.temperature = rows["temperature"].astype(float)
            self._temperature_in = TEMPERATURE_EVERY - 1
        q, qd, current, tau = self.units.state_from_units(rows["position"], rows["velocity"], rows["current"])
        now = time.monotonic()
        if silent:              # the retry's reply, after a silence the servos may not have outlived
            self._check_silence(now)
        self._last_packet = self._heard = now
        state = JointState(t=now, q=q, qd=qd, current=current, tau=tau, temperature=self.temperature)
        self._last = state
        return state

    @property
    def reply_size(self) -> int:
        """Bytes of the whole fast sync read reply: header, ID, LEN, INST, then per servo
        ERR ID DATA CRC(2) (the last block's CRC is the packet's)."""
        return instructions.fast_reply_size([PRESENT_LENGTH] * len(self.ids))

    def _fast_sync_read(self):
        """Send the fast sync read (built once, framed by servodyn's codec) on the SDK's port and
        parse its one reply with the firmware's codec in C (servodyn.hal.dynamixel._dxl): the packet CRC, each
        block's running CRC, its ID. Returns ((error bytes, data bytes) in joint order, "", None)
        or (None, what went wrong, the joint first missing)."""
        if self.port.is_using:
            return None, self.packets.getTxRxResult(self._sdk.COMM_PORT_BUSY), None
        self.port.is_using = True
        self._got = 0
        try:
            self.port.clearPort()
            frame = self._read_frames[self._length]
            if self._send(frame) != len(frame):
                return None, self.packets.getTxRxResult(self._sdk.COMM_TX_FAIL), None
            if self.reply_timeout is None:      # the SDK's timeout, else _receive's own
                self.port.setPacketTimeout((11 + self._length) * len(self.ids))    # as the SDK's syncReadTx
            raw, failure = self._receive()
            self._got = len(raw)
        finally:
            self.port.is_using = False
        if raw is not None and failure is None:
            good, errors, data = self._reader.fast_split(self._length, self._id_bytes)
            if good == len(self.ids):
                return (errors, data), "", None
            failure = "corrupt fast sync read reply (block %d of %d: cut short, another ID or a bad CRC)" % (
                good + 1, len(self.ids))
            return None, failure, None
        suspect, detail = self._short_reply(raw)
        return None, failure or detail, suspect

    def _send(self, frame: bytes) -> int:
        """Write a frame to the port: straight to its file descriptor when it has one (pyserial's
        write adds a select() and timeout bookkeeping per call), else through the SDK."""
        if self._fileno is None:
            return self.port.writePort(frame)
        sent = 0
        try:
            while sent < len(frame):
                sent += os.write(self._fileno, frame[sent:])
        except BlockingIOError:
            select.select([], [self._fileno], [], 0.1)
            return sent + self._send(frame[sent:]) if sent < len(frame) else sent
        except OSError as err:
            self.lost = self.lost or port_gone(err)
            return sent
        return sent

    def _receive(self) -> tuple[bytes, str | None]:
        """Bytes from the port into the C reader until a status packet from 0xFE (the fast reply)
        is whole, or the reply timeout passes (by default the packet timeout set at the send).
        (the bytes, None) when it came; (the bytes, a failure or "" on a timeout) otherwise.
        Waits in select() rather than spinning, so the tick's CPU time is its work."""
        reader = self._reader
        reader.reset()
        raw = bytearray()
        if self.reply_timeout is None:
            timeout = (self.port.packet_timeout - self.port.getTimeSinceStart()) * 1e-3
        else:
            timeout = self.reply_timeout
        deadline = time.monotonic() + timeout
        read = self.port.ser.read if hasattr(self.port, "ser") else self.port.readPort
        fd = self._fileno
        while True:
            chunk = None
            if fd is not None:
                # wait first (the reply is never there the moment the request left), then read
                # the descriptor itself; pyserial's read (a select and its timeout bookkeeping
                # per call) only when that finds nothing, to report a port that is gone its way
                if select.select([fd], [], [], max(0.0, deadline - time.monotonic()))[0]:
                    try:
                        chunk = os.read(fd, 4096)
                    except OSError:
                        chunk = None
            if not chunk:
                chunk = read(4096)
            if chunk:
                raw += chunk
                chunk = bytes(chunk)
                while chunk:
                    status, used = reader.feed(chunk)
                    chunk = chunk[used:]
                    if status == _dxl.PACKET and reader.id == BROADCAST_ID:
                        return bytes(raw), None
                    if status == _dxl.BAD_CRC and reader.id == BROADCAST_ID:
                        return bytes(raw), "fast sync read reply with a bad CRC"
                continue
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return bytes(raw), ""
            if self._fileno is not None:
                select.select([self._fileno], [], [], remaining)

    def _drain(self) -> int:
        """After a failed read, drop what still arrives until the line has been quiet for a reply
        timeout: a reply that comes after its time-out must not be taken for the retry's (it
        would be a tick old, and every later one too). Returns the bytes dropped (the first came
        at self._late_at)."""
        quiet = max(1e-3, self.reply_timeout if self.reply_timeout is not None else self.port.packet_timeout * 1e-3)
        deadline = time.monotonic() + 4 * quiet
        dropped = 0
        while time.monotonic() < deadline:
            if self._fileno is not None:
                ready, _, _ = select.select([self._fileno], [], [], quiet)
                if not ready:
                    return dropped
            chunk = self.port.readPort(4096)
            if chunk and not dropped:
                self._late_at = time.monotonic()      # when the bus spoke again
            dropped += len(chunk)
            if not chunk and self._fileno is None:
                time.sleep(quiet)
                return dropped
        return dropped

    def _short_reply(self, raw: bytes):
        """(the first joint whose block is missing, a description) for a reply that did not
        complete: a chain answers in order, so the blocks that came are whole and checkable."""
        start = raw.find(HEADER)
        if start < 0:
            return None, NO_REPLY
        got = len(fast_reply_blocks(raw[start:], [self._length] * len(self.ids), self.ids))
        if got == len(self.ids):
            return None, "fast sync read reply incomplete"
        missing = self.joints[got]
        return missing, (f"the fast sync read reply stopped after {got} of {len(self.ids)} blocks, "
                         f"before servo {missing.id}'s")

    def _write(self, command: JointCommand) -> None:
        if self._fault is not None:         # a sync write gets no reply: the last read's alert stands
            joint, status = self._fault
            raise ServoHardwareError(joint.dof, joint.id, status, hardware_faults(status))
        if self._last is None:
            raise ServoOperationError("write before the first read_state: the PD needs a measured state")
        tau = command.torque_at(self._last.q, self._last.qd)
        units, limited = self.units.goal_current_units(tau, self.current_limit)
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

    # ---------------------------------------------------------------- helpers
    def _diagnose(self, detail: str, suspect=None) -> ServoTimeoutError | BusStallError:
        """After the retries, ping every servo (with as many tries) to find those that stopped
        answering. None answers: the bus stalled. Some did not: once the others have answered
        (the bus is alive), ping those again and name the first still silent. If every servo
        answers, name the one whose block the short reply lacked — or, when no byte of the reply
        came at all, the whole bus had stalled and came back."""
        silent = [joint for joint in self.joints if not self._answers_ping(joint)]
        pings = f"{self.retries + 1} pings"
        if len(silent) == len(self.joints):
            return BusStallError(self.bus.name, f"{detail}; no answer to {pings} of each servo")
        still = [joint for joint in silent if not self._answers_ping(joint)]
        if still:
            joint = still[0]
            return ServoTimeoutError(joint.dof, joint.id, f"{detail}; no answer to {pings}, twice, while the "
                                                          "others answered")
        if detail == NO_REPLY:
            return BusStallError(self.bus.name, f"{detail} to {self.retries + 1} tries, then every servo answered "
                                                "a ping")
        joint = suspect or (silent or self.joints)[0]
        return ServoTimeoutError(joint.dof, joint.id, f"{detail} (every servo answers a ping)")

    def _corrupt_line(self, detail: str) -> ServoOperationError | None:
        """After the retries, one ping of each servo: a servo whose answer comes but is corrupt
        (bad CRC, garbage, cut) is on a corrupt line, not silent. None when no answer is corrupt."""
        for joint in self.joints:
            if self.packets.ping(self.port, joint.id)[1] == self._sdk.COMM_RX_CORRUPT:
                return ServoOperationError(f"bus '{self.bus.name}': corrupt replies ({detail}; joint "
                                           f"'{joint.dof}' (id {joint.id}) answers a ping with a corrupt packet)")
        return None

    def _answers_ping(self, joint) -> bool:
        return any(self.packets.ping(self.port, joint.id)[1] == self._sdk.COMM_SUCCESS
                   for _ in range(self.retries + 1))

    def _check_watchdog(self, silence: float) -> None:
        """After `silence` s without a packet: raise BusStallError if a servo tripped its Bus
        Watchdog (it reads -1, 255 unsigned)."""
        tripped = [joint.id for joint in self.joints if self._read_item(joint, ADDR_BUS_WATCHDOG, 1) == 0xFF]
        if tripped:
            raise BusStallError(self.bus.name, f"{silence * 1e3:.0f} ms without a packet, over the servos' Bus "
                                f"Watchdog of {self.watchdog * 1e3:.0f} ms: servos {', '.join(map(str, tripped))} "
                                "tripped it and stopped")
        self._heard = time.monotonic()          # every servo answered

    def _check_silence(self, now: float) -> None:
        """With torque on, raise BusStallError once the bus has said nothing for longer than the
        servos' Bus Watchdog: on real servos it has tripped (torque off, goals refused), whether
        or not they can be asked now, so the run cannot go on; and a reply that ends such a
        silence may be the answer to an earlier try, held back with the bus, not the retry's. A
        short hiccup (a lost packet retried within the watchdog) goes on as a retry."""
        if not self._armed or self._heard is None or now - self._heard <= self.watchdog:
            return
        raise BusStallError(self.bus.name, f"silent for {(now - self._heard) * 1e3:.0f} ms, longer than the "
                                           f"servos' Bus Watchdog of {self.watchdog * 1e3:.0f} ms: they have "
                                           "switched their torque off by themselves")

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
