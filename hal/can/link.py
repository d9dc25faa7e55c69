"""One python-can bus as servodyn's CAN code speaks on it, shared by the run (backend.CanBus) and
bring-up (bringup): a frame sent, or a failed send as one line; the next frame that can be a motor's
answer, with error frames decoded into their classes (frames.error_frame) and 29-bit, CAN FD and
remote frames counted and skipped (no motor here sends them); a Damiao register transaction through
id 0x7FF matched to its echo."""

from __future__ import annotations

import os
import time

import can

from ..bus import port_gone
from ..errors import ServoInitializationError, ServoOperationError
from . import frames


def open_bus(channel: str, interface: str, bitrate: int):
    """python-can's bus on `channel` (spec.interface_for names its interface), or one line saying
    why not, with the OS's reason."""
    try:
        return can.Bus(interface=interface, channel=channel, bitrate=int(bitrate))
    except (can.CanError, OSError, ValueError, ImportError) as err:
        # the OS's reason, on the error or under python-can's own
        errno = next((e.errno for e in (err, err.__cause__, err.__context__)
                      if isinstance(getattr(e, "errno", None), int)), None)
        reason = os.strerror(errno) if errno is not None else err
        raise ServoInitializationError(f"{interface} {channel}: cannot open ({reason})") from None


class CanLink:
    """`name`: the bus's name in messages; `can_bus`: an open python-can bus (set later if None);
    `timeout`: s a send may wait for room and a register transaction for its answer; `errors`:
    None, a stopping error frame raises ServoOperationError; a list, each error frame's
    (arbitration id, data) is appended to it and skipped (bring-up's doctor reports them)."""

    def __init__(self, name: str, can_bus=None, *, timeout: float, errors: list | None = None):
        self.name, self.can, self.timeout, self.errors = name, can_bus, timeout, errors
        self.warnings = 0           # error frames of a controller's warning or passive state alone
        self.foreign = 0            # 29-bit, CAN FD and remote frames: no motor's reply, skipped
        self.lost = None            # why the port itself is gone (hal.bus.port_gone), once it is

    def send(self, arbitration_id: int, data: bytes) -> None:
        try:
            self.can.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False),
                          timeout=self.timeout)
        except can.CanError as err:
            self.lost = self.lost or port_gone(err)
            raise ServoOperationError(f"bus '{self.name}': CAN send failed ({err})") from None

    def recv(self, timeout: float):
        """The next frame that can be a motor's reply, or None at the timeout. An error frame that
        stops (no ACK, bus-off, a protocol violation, ...) is a ServoOperationError naming its
        classes with what to check (or, with an `errors` list, recorded there); a controller's
        warning or passive state is counted (`warnings`); a 29-bit, CAN FD or remote frame is no
        motor's reply: counted (`foreign`) and skipped. A line the adapter's driver cannot parse
        (python-can's ValueError on a malformed SLCAN line) is a corrupt reply on this bus."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                msg = self.can.recv(max(0.0, deadline - time.monotonic()))
            except can.CanError as err:
                self.lost = self.lost or port_gone(err)
                raise ServoOperationError(f"bus '{self.name}': CAN receive failed ({err})") from None
            except (ValueError, IndexError, UnicodeDecodeError) as err:
                raise ServoOperationError(f"bus '{self.name}': the adapter sent a line that is no frame "
                                          f"({type(err).__name__}: {err}): a corrupt reply") from None
            if msg is None:
                return None
            if msg.is_error_frame:
                if self.errors is not None:
                    self.errors.append((msg.arbitration_id, bytes(msg.data)))
                    continue
                stops, text = frames.error_frame(msg.arbitration_id, bytes(msg.data))
                if stops:
                    raise ServoOperationError(f"bus '{self.name}': error frame: {text}")
                self.warnings += 1
                continue
            if msg.is_extended_id or msg.is_remote_frame or getattr(msg, "is_fd", False):
                self.foreign += 1
                continue
            return msg

    def drain(self, limit: int = 1000) -> list:
        """The frames waiting now, taken without waiting (at most `limit`: a flooding bus cannot
        hold the caller)."""
        taken = []
        for _ in range(limit):
            msg = self.recv(0.0)
            if msg is None:
                break
            taken.append(msg)
        return taken

    def register(self, can_id: int, cmd: int, rid: int, value: int = 0, *, reply_ids=None, answer_ids=None,
                 timeout: float | None = None):
        """One Damiao register transaction (frames.REG_READ or REG_WRITE) with the motor at `can_id`:
        (its echo decoded, the id it came on), or None at the timeout. The echo names the motor's
        CAN ID, the command and the register; `reply_ids`: the ids it may come on (None: any, for a
        motor whose Master ID is not known); `answer_ids`: the CAN IDs the echo may name (default
        `can_id`; a write of ESC_ID may be echoed under the new one). Other frames are dropped."""
        answer_ids = {can_id} if answer_ids is None else set(answer_ids)
        self.send(frames.REGISTER_ID, frames.pack_register(frames.Register(can_id, cmd, rid, value)))
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while (left := deadline - time.monotonic()) > 0:
            msg = self.recv(left)
            if msg is None:
                break
            if len(msg.data) != 8 or (reply_ids is not None and msg.arbitration_id not in reply_ids):
                continue
            data = bytes(msg.data)
            if data[0] | (data[1] << 8) in answer_ids and data[2] == cmd and data[3] == rid:
                return frames.unpack_register(data), msg.arbitration_id
        return None
