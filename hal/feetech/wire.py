"""The tick's wire of a bus with Protocol 1.0 framing (a Feetech STS bus, a Dynamixel 1.0 bus): a
frame sent on a clean line, the status packets of the servos asked collected until each has
answered once or the reply's time-out, a port that fails named in one line, and the safe stop
(torque off servo by servo). The bus that mixes this in opens `serial` (pyserial), `_fd` (its
descriptor) and `_reader` (a PacketReader), has ServoBus's `bus`, `joints`, `port_name`,
`reply_timeout` and `lost`, and writes a servo's item by `write_item(joint, name, value)`."""

from __future__ import annotations

import os
import select
import time

from ..bus import BITS_PER_BYTE, PORT_ERRORS, port_gone
from ..errors import ServoHardwareError, ServoOperationError, ServoTimeoutError
from .protocol import Packet

PACKET_TIMEOUT = 0.05     # s beyond the wire time a reply may take (the SDK's LATENCY_TIMER, 50 ms)


class StatusWire:
    def _timeout(self, nbytes: int) -> float:
        """s a reply of `nbytes` (the request's too) may take: its wire time and PACKET_TIMEOUT, or
        the bus's reply_timeout where that is longer."""
        return max(self.reply_timeout or 0.0, nbytes * BITS_PER_BYTE / self.bus.baud + PACKET_TIMEOUT)

    def _send(self, frame: bytes) -> None:
        try:
            self.serial.reset_input_buffer()
            os.write(self._fd, frame)
        except PORT_ERRORS as err:
            raise self._gone(err) from None

    def _receive(self, ids, nbytes: int) -> dict[int, Packet]:
        """The status packets of `ids` that arrive within the reply's time-out (the first of each)."""
        got: dict[int, Packet] = {}
        deadline = time.monotonic() + self._timeout(nbytes)
        self._reader.expire()
        while len(got) < len(ids):
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                if not select.select([self._fd], [], [], left)[0]:
                    break
                data = os.read(self._fd, 4096)
            except PORT_ERRORS as err:
                raise self._gone(err) from None
            for event in self._reader.feed(data):
                if isinstance(event, Packet) and event.id in ids and event.id not in got:
                    got[event.id] = event
        return got

    def _gone(self, err: Exception) -> ServoOperationError:
        reason = port_gone(err)
        self.lost = self.lost or reason
        return ServoOperationError(f"bus '{self.bus.name}': the port {self.port_name} "
                                   f"{'is gone' if reason else 'failed'} ({reason or err})")

    def _stop(self) -> bool:
        """Torque off on every servo that answers; True if all did. A port that fails ends it at
        once: no servo can be told."""
        ok = True
        for joint in self.joints:
            try:
                self.write_item(joint, "torque_enable", 0)
            except ServoOperationError:
                return False
            except (ServoTimeoutError, ServoHardwareError):
                ok = False
        return ok
