"""The seed corpus of the host link's fuzz target (fuzz/link/corpus/stream/, shared by its double and
float builds), framed as fuzz/link/stream.c reads its input:

    [0][bytes from the line]                         op even: a stream through the decoder
    [1]([type - 0x02][len][payload])...              op odd: records loading one robot

The stream seeds are one frame of every message (tests/test_host_link.py's examples, built by the
Python codec, servodyn.hal.link, byte for byte the C codec), all of them in a row, and that row with
a byte corrupted, a byte lost and junk in front. The robot seeds load the replica (its model and
servos as the test sends them), committed, the same with a body without mass, and the mixed arm
(CAN motors beside Dynamixel servos: LOAD_JOINT's dialects, reply ids and MIT ranges).

Run `python fuzz/link/seeds.py` to write them; tests/test_fuzz.py checks the corpus in the
repository is what this gives."""

import sys
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent / "tests"))

from test_host_link import EXAMPLES, replica_messages  # noqa: E402

from servodyn.hal.link import frame, messages  # noqa: E402

STREAM, ROBOT = 0, 1


def _record(message) -> bytes:
    type_, payload = messages.pack(message)
    return bytes([type_ - messages.LOAD_ROBOT, len(payload)]) + payload


def corpus() -> dict[str, dict[str, bytes]]:
    seeds = {}
    frames = []
    for k, (name, message) in enumerate(EXAMPLES.items()):
        type_, payload = messages.pack(message)
        frames.append(frame.encode(k, k + 1, type_, payload))
        seeds[f"frame_{name}"] = bytes([STREAM]) + frames[-1]
    row = b"".join(frames)
    seeds["stream_all"] = bytes([STREAM]) + row
    seeds["stream_corrupt"] = bytes([STREAM]) + row[:40] + bytes([row[40] ^ 0x5A]) + row[41:]
    seeds["stream_lost_byte"] = bytes([STREAM]) + row[:57] + row[58:]
    seeds["stream_junk_first"] = bytes([STREAM]) + b"\x13\x37\xff\x01" + row
    robot = replica_messages()
    seeds["robot_replica"] = bytes([ROBOT]) + b"".join(map(_record, [*robot, messages.Commit()]))
    massless = [replace(m, mass=0.0) if isinstance(m, messages.Body) and m.index == 2 else m for m in robot]
    seeds["robot_massless_body"] = bytes([ROBOT]) + b"".join(map(_record, [*massless, messages.Commit()]))
    mixed = replica_messages("replica_mixed")
    seeds["robot_replica_mixed"] = bytes([ROBOT]) + b"".join(map(_record, [*mixed, messages.Commit()]))
    return {"stream": seeds}


if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parent))
    from write_corpus import write_corpus
    write_corpus(HERE, corpus())
