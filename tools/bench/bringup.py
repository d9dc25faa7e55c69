"""`make bench`, bring-up: how long a user waits for `servodyn scan --baud all` and `servodyn
doctor` on the replica's seven servos, served by the simulator in another process (as `servodyn
sim` serves them), measured

  - scan: servodyn's broadcast ping at each of the eight rates over the whole ID range, the
    wait at each ending when the line has been quiet for the rate (hal.dynamixel.bringup.scan);
    against, in the same run, dynamixel-sdk's own broadcastPing at each rate, which waits the
    whole window 252 servos could fill (what a scan with the SDK, or Wizard's, costs);
  - doctor: every servo pinged and its whole control table read and checked (in-process), and the
    command's wall time in a fresh process (Python's start-up and imports included).

Goals (issue 22): scan --baud all <= 2 s, doctor <= 1 s. Medians and ranges over the repetitions.
Writes out/bench/bringup.json and out/bench/bringup.md.
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

from ...hal.config import load_config
from ...hal.dynamixel import bringup as dxl
from ...hal.dynamixel.control_table import BAUD_RATES
from ...sim.serve import SimProcess

ROOT = Path(__file__).resolve().parents[2]
GOALS = {"scan": 2.0, "doctor": 1.0}


def _sdk_scan(path: str) -> tuple[float, int]:
    """dynamixel-sdk's broadcastPing at every rate: seconds and servos found."""
    import dynamixel_sdk as sdk
    port = sdk.PortHandler(path)
    port.openPort()
    packets = sdk.PacketHandler(2.0)
    found = 0
    start = time.perf_counter()
    try:
        for baud in dxl.SCAN_RATES:
            port.setBaudRate(baud)
            servos, result = packets.broadcastPing(port)
            found += len(servos)
    finally:
        port.closePort()
    return time.perf_counter() - start, found


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"))
    args = parser.parse_args(argv)
    config = load_config("replica")
    print(f"== bring-up on the replica's 7 simulated servos, {os.cpu_count()} CPUs; medians of {args.reps} "
          "repetitions", flush=True)
    scans, doctors, commands, found = [], [], [], set()
    with SimProcess(config.path, "lockstep") as sim:
        for r in range(args.reps):
            with dxl.Link(sim.path, dxl.FACTORY_BAUD) as link:
                result = dxl.scan(link)
                scans.append(result.seconds)
                found = {(f.id, f.baud) for f in result.found}
                start = time.perf_counter()
                findings = dxl.doctor(config, "arm", link)
                doctors.append(time.perf_counter() - start)
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "servodyn.tools.cli", "doctor", "--config", "replica", "--port",
                            sim.path], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
            commands.append(time.perf_counter() - start)
        print("  dynamixel-sdk's broadcastPing at every rate (once) ...", flush=True)
        sdk_seconds, sdk_found = _sdk_scan(sim.path)

    def stat(values):
        return {"median_s": float(np.median(values)), "min_s": float(np.min(values)), "max_s": float(np.max(values))}

    result = {"rates": list(dxl.SCAN_RATES), "servos_found": len(found), "scan": stat(scans),
              "sdk_scan_s": sdk_seconds, "sdk_servos_found": sdk_found, "doctor": stat(doctors),
              "doctor_command": stat(commands), "doctor_findings": len(findings), "goals_s": GOALS}
    scan_ratio = sdk_seconds / result["scan"]["median_s"]
    rows = [
        ("scan --baud all (8 rates, IDs 0-252)", result["scan"], GOALS["scan"]),
        ("doctor, 7 servos (in-process)", result["doctor"], GOALS["doctor"]),
        ("servodyn doctor (the command, fresh process)", result["doctor_command"], GOALS["doctor"]),
    ]
    lines = ["| what | median s | range s | goal s | met |", "|---|---|---|---|---|"]
    for name, s, goal in rows:
        lines.append(f"| {name} | {s['median_s']:.3f} | {s['min_s']:.3f}-{s['max_s']:.3f} | <= {goal:g} | "
                     f"{'yes' if s['median_s'] <= goal else 'NO'} |")
    lines.append(f"| dynamixel-sdk broadcastPing, 8 rates (reference, once) | {sdk_seconds:.3f} | - | - | - |")
    text = "\n".join(lines) + (f"\n\nscan finds {len(found)} servos ({len(BAUD_RATES)} rates tried); the SDK's "
                               f"broadcast ping {sdk_found}; servodyn's scan is {scan_ratio:.1f}x faster than the "
                               "SDK's in this run.")
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bringup.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "bringup.md").write_text(text + "\n")


if __name__ == "__main__":
    main()
