"""The host link: the protocol between servodyn on the host and the controller's firmware
(docs/host-link.md), the host's side. The firmware's side is C (firmware/link/), byte for byte the same
(tests/test_host_link.py).

    frame.py      COBS framing, CRC-16, the streaming decoder that resynchronises at every 00
    messages.py   every message's layout, pack and unpack; telemetry's fixed point; the bandwidth
    sender.py     the host's side of the acknowledge/retransmit rule
"""

from .frame import VERSION, Decoder, Frame, LinkError, encode
from .messages import pack, reason, unpack
from .sender import LinkTimeoutError, LinkVersionError, Sender

__all__ = ["VERSION", "Decoder", "Frame", "LinkError", "LinkTimeoutError", "LinkVersionError", "Sender", "encode",
           "pack", "reason", "unpack"]
