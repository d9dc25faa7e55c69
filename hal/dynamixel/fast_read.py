"""The tick's read of the Dynamixel backend: one fast sync read (0x8A) of Present Current, Velocity
and Position (and, one tick in TEMPERATURE_EVERY, on to Present Temperature), sent straight to
the port's file descriptor and parsed by the firmware's codec in C, retried when missing, short or
corrupt. Mixed into backend.DynamixelBus (what it does on a failure: hal/dynamixel/diagnosis.py;
the whole story: hal/dynamixel/backend.py's docstring)."""

from __future__ import annotations

import os
import select
import time

import numpy as np

from ..bus import JointState, port_gone
from ..errors import BusStallError, ServoHardwareError, ServoOperationError
from . import _dxl
from . import instructions
from .control_table import (ADDR_HARDWARE_ERROR, ADDR_PRESENT, ITEMS, PRESENT_LENGTH, PRESENT_WITH_TEMPERATURE_LENGTH,
                            hardware_faults)
from .instructions import fast_reply_blocks
from .protocol import ALERT_BIT, BROADCAST_ID, HEADER

# a fast sync read reply's data block: Present Current (2), Velocity (4), Position (4)
PRESENT = np.dtype([("current", "<i2"), ("velocity", "<i4"), ("position", "<i4")])
# ... and on to Present Temperature: velocity and position trajectories, input voltage (0.1 V: the
# supply a joint in PWM mode divides its torque's voltage by), temperature
PRESENT_WITH_TEMPERATURE = np.dtype({"names": ["current", "velocity", "position", "voltage", "temperature"],
                                     "formats": ["<i2", "<i4", "<i4", "<u2", "u1"],
                                     "offsets": [0, 2, 6, ITEMS["present_input_voltage"].address - ADDR_PRESENT,
                                                 PRESENT_WITH_TEMPERATURE_LENGTH - 1],
                                     "itemsize": PRESENT_WITH_TEMPERATURE_LENGTH})
# every this many reads, the tick's read runs on to Present Temperature: 11 more bytes a servo
# (at 4 Mbaud, 7 servos: 0.19 ms) on one tick in a hundred, no transaction of its own (a round
# trip through a USB adapter costs a millisecond); a winding's temperature changes over seconds
# and the servo reports it in whole degrees
TEMPERATURE_EVERY = 100

NO_REPLY = "no fast sync read reply"


class FastRead:
    """The fast sync read of backend.DynamixelBus."""

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
            if len(self.pwm):
                self.pwm.measured(rows["voltage"] / 10)
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
