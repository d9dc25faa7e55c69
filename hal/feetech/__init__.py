"""Feetech STS/SMS servos (FT-SCS protocol, Protocol 1.0 framing): the packet codec and reader
(``protocol``), the memory table, baud table and the servos' data sheets with their motor model
(``table``), the bus described for the configuration and the validator (``spec``) and the
run-time bus (``backend``, ``FeetechBus``), which drives every joint by PWM (mode 2)."""

from . import protocol
from .protocol import (BROADCAST_ID, MAX_ID, BadFrame, Instruction, Packet, PacketError, PacketReader, StatusBit,
                       decode_sign_magnitude, encode_sign_magnitude, status_faults)
from .table import BAUD_RATES, ITEM, ITEMS, SERVOS, FeetechSpec, Mode

__all__ = ["BAUD_RATES", "BROADCAST_ID", "ITEM", "ITEMS", "MAX_ID", "SERVOS", "BadFrame", "FeetechSpec", "Instruction",
           "Mode", "Packet", "PacketError", "PacketReader", "StatusBit", "decode_sign_magnitude",
           "encode_sign_magnitude", "protocol", "status_faults"]
