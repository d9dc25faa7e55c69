"""`make bench`, the CAN tick: seven simulated Damiao motors (replica_can) driven by the CAN
backend, one tick = seven command frames out and seven replies back, timed

  - on python-can's in-process virtual bus, the motors answering from a server thread, and in the
    loop's own thread (the lock-step swing's transport);
  - through the SLCAN adapter on a pseudo-terminal, served by `servodyn sim --config replica_can
    --lockstep` in another process;
  - beside python-can's own raw slcan round trip (one frame out, one reply in) on that same
    pseudo-terminal, in the same run: its byte-at-a-time reader is the transport's limit there;
  - beside the wire ceiling: an 8-byte standard frame is 111-135 bits, 14 frames a tick.

The transports are timed interleaved (each repetition times each once), medians and ranges over
the repetitions; absolute times on a shared machine drift, read the ratios. Writes
out/bench/can.json and out/bench/can.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ...hal.bus import JointCommand, make_bus
from ...hal.can.spec import FRAME_BITS
from ...hal.config import load_config
from ...sim.robot import SimulatedRobot
from ...sim.transport.can import VirtualCanServer

ROOT = Path(__file__).resolve().parents[2]
HOLD = JointCommand.position(np.full(7, 0.2), kp=3.0, kd=0.03)
PATIENT = 2.0


def _ticks(bus, n: int) -> float:
    """Open the bus, switch torque on, then seconds per tick over n ticks (write, then read the
    replies); the bus is stopped whatever happens."""
    try:
        bus.open()
        bus.enable_torque(True)
        bus.read_state()
        start = time.perf_counter()
        for _ in range(n):
            bus.write(HOLD)
            bus.read_state()
        return (time.perf_counter() - start) / n
    finally:
        bus.stop()


def _virtual(config, threaded: bool, n: int) -> float:
    robot = SimulatedRobot(config)
    server = VirtualCanServer(robot.port(), f"bench-{id(robot):x}", threaded=threaded)
    server.start()
    host = server.host_bus() if not threaded else __import__("can").Bus(interface="virtual", channel=server.channel)
    try:
        return _ticks(make_bus(config, can_bus=host, reply_timeout=PATIENT), n)
    finally:
        server.stop()
        host.shutdown()


def _slcan_tick(config, path: str, n: int) -> float:
    return _ticks(make_bus(config, port=path, reply_timeout=PATIENT), n)


def _slcan_raw(path: str, n: int) -> float:
    """python-can alone: one special frame (motor 1 exits motor mode) and its reply, n times."""
    import can
    bus = can.Bus(interface="slcan", channel=path, bitrate=1_000_000)
    frame = can.Message(arbitration_id=1, data=bytes([0xFF] * 7 + [0xFD]), is_extended_id=False)
    try:
        start = time.perf_counter()
        for _ in range(n):
            bus.send(frame)
            while bus.recv(PATIENT) is None:
                pass
        return (time.perf_counter() - start) / n
    finally:
        bus.shutdown()


def measure(reps: int, ticks: int) -> dict:
    config = load_config("replica_can")
    sim = subprocess.Popen([sys.executable, "-m", "servodyn.tools.cli", "sim", "--config", "replica_can", "--lockstep"],
                           stdout=subprocess.PIPE, text=True)
    try:
        line = sim.stdout.readline()
        path = line.rsplit(" on ", 1)[-1].strip()
        if not path.startswith("/dev/"):
            sys.exit(f"bench: servodyn sim did not print its pseudo-terminal: {line!r}")
        rows = {"virtual, server thread": [], "virtual, in the loop's thread": [], "SLCAN pty, another process": [],
                "python-can raw slcan round trip": []}
        for r in range(reps):
            print(f"  repetition {r + 1} of {reps} ...", flush=True)
            rows["virtual, server thread"].append(_virtual(config, True, ticks))
            rows["virtual, in the loop's thread"].append(_virtual(config, False, ticks))
            rows["SLCAN pty, another process"].append(_slcan_tick(config, path, ticks // 4))
            rows["python-can raw slcan round trip"].append(_slcan_raw(path, ticks // 4))
    finally:
        sim.terminate()
        sim.wait(timeout=10)
    return {name: float(np.median(v)) for name, v in rows.items()} | {
        f"{name} range": [float(min(v)), float(max(v))] for name, v in rows.items()}


def table(result: dict) -> str:
    frames = 14
    lo, hi = (frames * b / 1e6 for b in FRAME_BITS)
    raw = result["python-can raw slcan round trip"]
    lines = ["| transport | per tick (ms) | ticks/s | vs the wire ceiling | vs 7 raw slcan round trips |",
             "|---|---|---|---|---|"]
    for name in ("virtual, server thread", "virtual, in the loop's thread", "SLCAN pty, another process"):
        t = result[name]
        a, b = result[f"{name} range"]
        lines.append(f"| {name} | {t * 1e3:.3f} ({a * 1e3:.3f}-{b * 1e3:.3f}) | {1 / t:.0f} | {t / hi:.2f}x | "
                     f"{t / (7 * raw):.2f}x |")
    lines.append(f"| python-can raw slcan round trip (1 frame) | {raw * 1e3:.3f} | {1 / raw:.0f} | | 1/7 |")
    lines.append(f"| wire: 14 frames x {FRAME_BITS[0]}-{FRAME_BITS[1]} bits at 1 Mbit/s | {lo * 1e3:.2f}-{hi * 1e3:.2f} "
                 f"| {1 / hi:.0f}-{1 / lo:.0f} | 1 | |")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--ticks", type=int, default=400)
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"))
    args = parser.parse_args(argv)
    print(f"== the CAN tick, 7 motors (replica_can), {os.cpu_count()} CPUs; medians of {args.reps} repetitions",
          flush=True)
    result = measure(args.reps, args.ticks)
    text = table(result)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "can.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "can.md").write_text(text + "\n")


if __name__ == "__main__":
    main()
