"""Simulated Feetech STS servos behind the real wire format: one servo (`servo`: its memory table,
the EEPROM lock, modes 0/1/2, overload protection, the plant's side on the voltage-level motor
model) and the bus answering the host's bytes (`wire`: framing, the baud gate, SYNC READ/WRITE).
The memory table and the servos' data sheets are the HAL's (servodyn.hal.feetech.table)."""

from .servo import FeetechServo
from .wire import FeetechWire

__all__ = ["FeetechServo", "FeetechWire"]
