"""The clock of the simulator behind a pseudo-terminal, asked over the bus itself.

A swing and a simulated plant must keep one time: a loop that runs lock-step (as fast as the bus
answers) against a plant served in real time plays the motion faster than the plant moves (22°
of error instead of 0.6° on the replica). `servodyn sim` serves in real time by default and with
--lockstep one period per command transaction. A swing given a pseudo-terminal asks it:

- Dynamixel: a READ of one byte at SIMULATOR_CLOCK_ADDRESS (hal.dynamixel.control_table) from the
  bus's first servo; a simulated servo answers its simulator's clock, a real one an error;
- Feetech: a READ of one byte at hal.feetech.table's SIMULATOR_CLOCK_ADDRESS, past the STS table;
- CAN over SLCAN: the adapter's serial number (`N`), which the simulated adapter sets by its clock
  (hal.can.spec.SIMULATOR_SERIALS).

None when the answer says nothing (no answer, an error, a serial number of a real adapter): the
run then keeps real time, which is right against either clock.
"""

from __future__ import annotations

import os
import select
import time

import serial

from .can.spec import SIMULATOR_SERIALS
from .feetech import protocol as feetech
from .feetech.table import SIMULATOR_CLOCK_ADDRESS as FEETECH_CLOCK_ADDRESS, SIMULATOR_CLOCKS as FEETECH_CLOCKS
from .dynamixel import instructions
from .dynamixel.control_table import SIMULATOR_CLOCK_ADDRESS, SIMULATOR_CLOCKS
from .dynamixel.link import Link
from .errors import HalError
from .ports import PTY_REPLY_TIMEOUT


def served_clock(config, bus: str, path: str) -> str | None:
    """"lockstep" or "realtime": the clock the simulated `bus` of `config` on `path` serves on;
    None when it does not say."""
    spec = config.buses[bus]
    try:
        if spec.kind == "dynamixel" and spec.protocol == 1.0:    # 1.0 frames as the STS's
            return _feetech(path, spec.baud, config.joints_on(bus)[0].id)
        if spec.kind == "dynamixel":
            return _dynamixel(path, spec.baud, config.joints_on(bus)[0].id)
        if spec.kind == "can":
            return _slcan(path)
        if spec.kind == "feetech":
            return _feetech(path, spec.baud, config.joints_on(bus)[0].id)
    except (HalError, OSError):
        return None
    return None


def _dynamixel(path: str, baud: int, servo_id: int) -> str | None:
    with Link(path, baud, patience=PTY_REPLY_TIMEOUT["dynamixel"]) as link:
        packets, _ = link.exchange(instructions.read(servo_id, SIMULATOR_CLOCK_ADDRESS, 1))
    reply = next((p for p in packets if p.id == servo_id), None)
    if reply is None or reply.error_number or len(reply.params) != 1:
        return None
    return SIMULATOR_CLOCKS.get(reply.params[0])


def _slcan(path: str) -> str | None:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        os.write(fd, b"N\r")
        answer, deadline = b"", time.monotonic() + PTY_REPLY_TIMEOUT["can"]
        while b"\r" not in answer and (left := deadline - time.monotonic()) > 0:
            if select.select([fd], [], [], left)[0]:
                answer += os.read(fd, 64)
    finally:
        os.close(fd)
    line = answer.split(b"\r")[0]
    serial = line[1:].decode("ascii", "replace") if line.startswith(b"N") else None
    return next((clock for clock, number in SIMULATOR_SERIALS.items() if number == serial), None)


def _feetech(path: str, baud: int, servo_id: int) -> str | None:
    with serial.Serial(path, baud, timeout=PTY_REPLY_TIMEOUT["feetech"]) as port:
        port.write(feetech.read(servo_id, FEETECH_CLOCK_ADDRESS, 1))
        reader, deadline = feetech.PacketReader(), time.monotonic() + PTY_REPLY_TIMEOUT["feetech"]
        while time.monotonic() < deadline:
            data = port.read(max(1, port.in_waiting))
            found = [p for p in reader.feed(data) if isinstance(p, feetech.Packet) and p.id == servo_id]
            if found:
                reply = found[0]
                return FEETECH_CLOCKS.get(reply.params[0]) if len(reply.params) == 1 and not reply.error else None
    return None
