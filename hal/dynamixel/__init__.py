"""DYNAMIXEL X-series servos on Protocol 2.0: the packet codec (``protocol``), every instruction
(``instructions``), an incremental frame reader (``reader``), the servos' data sheets and control
table (``control_table``), joint <-> register units (``units``), the bus described for the
configuration and the validator (``spec``), the run-time bus (``backend``, ``DynamixelBus``) and
bring-up (``bringup``); ``c/`` is the codec in C, for the firmware and the run-time reads.
Protocol 1.0 (AX-12A, MX-28/64/106 on their 1.0 firmware, a bus with ``protocol = 1.0``): the codec
``protocol1``, the tables and data sheets ``table1``, the bus described ``spec1`` and run ``backend1``."""

from . import instructions
from .instructions import BadParameters, FastReadBlock, ResetOption, encode_fast_reply, split_fast_reply
from .protocol import (ALERT_BIT, BROADCAST_ID, HEADER, MAX_ID, CrcMismatch, ErrorNumber, FieldRangeError,
                       Instruction, InstructionPacket, PacketError, ProtocolError, StatusError, StatusPacket,
                       crc16, decode_frame, encode_frame, pack_field, stuff, unpack_field, unstuff)
from .reader import BadFrame, Fault, PacketReader

__all__ = [
    "ALERT_BIT", "BROADCAST_ID", "HEADER", "MAX_ID", "BadFrame", "BadParameters", "CrcMismatch",
    "ErrorNumber", "FastReadBlock", "Fault", "FieldRangeError", "Instruction", "InstructionPacket",
    "PacketError", "PacketReader", "ProtocolError", "ResetOption", "StatusError", "StatusPacket", "crc16",
    "decode_frame", "encode_fast_reply", "encode_frame", "instructions", "pack_field", "split_fast_reply",
    "stuff", "unpack_field", "unstuff",
]
