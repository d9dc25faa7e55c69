"""The fuzz targets' seed corpora (fuzz/dynamixel/corpus/TARGET/), from the e-manual's example
packets in tests/test_dynamixel_protocol.py, each framed as its target reads its input:

    reader       a chunk-size byte, then the packet
    build        the arguments that make dxl_packet build the packet again
    fast_reply   the block count and sizes, then the reply

Run `python fuzz/dynamixel/seeds.py` to write them; tests/test_fuzz.py checks the corpus in the
repository is what this gives."""

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent / "tests"))

from test_dynamixel_protocol import (EMANUAL_FAST_BULK_REPLY, EMANUAL_FAST_SYNC_REPLY,  # noqa: E402
                                     EMANUAL_INSTRUCTIONS, EMANUAL_STATUS)

from servodyn.hal.dynamixel import decode_frame  # noqa: E402

STATUS = 0x55


def frames() -> dict[str, bytes]:
    """Every e-manual packet by a file name."""
    out = {}
    for name, _, expected in EMANUAL_INSTRUCTIONS:
        out[name.replace(" ", "_").replace(",", "")] = bytes.fromhex(expected)
    for k, (_, expected) in enumerate(EMANUAL_STATUS):
        out[f"status_{k}"] = bytes.fromhex(expected)
    return out


def build_args(frame: bytes) -> bytes:
    """build.c's input for dxl_packet: which=0, capacity, id, instruction, address, width,
    count=0, mode, then the params (a status packet's ERR first). The frame's own params are
    unstuffed by the Python decoder."""
    packet = decode_frame(frame)
    params = bytes(packet.params)
    instruction = getattr(packet, "instruction", STATUS)
    if instruction == STATUS:
        params = bytes([packet.error]) + params
    cap = len(frame) + 8
    return bytes([0, cap & 0xFF, cap >> 8, packet.id, instruction, 0, 0, 0, 0, 0]) + params


def corpus() -> dict[str, dict[str, bytes]]:
    seeds = {"reader": {}, "build": {}, "fast_reply": {}}
    for name, frame in frames().items():
        seeds["reader"][name] = b"\x00" + frame
        seeds["build"][name] = build_args(frame)
    everything = b"".join(frames().values())
    seeds["reader"]["all_packets"] = b"\x07" + everything
    for name, reply, sizes in (("fast_sync_reply", EMANUAL_FAST_SYNC_REPLY, [4, 4, 4]),
                               ("fast_bulk_reply", EMANUAL_FAST_BULK_REPLY, [4, 2, 1])):
        frame = bytes.fromhex(reply)
        seeds["reader"][name] = b"\x00" + frame
        seeds["fast_reply"][name] = bytes([0, len(sizes), *sizes]) + frame
    return seeds


if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parent))
    from write_corpus import write_corpus
    write_corpus(HERE, corpus())
