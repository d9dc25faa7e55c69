"""`make bench`, the control loop: the swing on the simulated Dynamixel bus, timed.

What the test suite must not assert (it depends on the machine and its neighbours) is measured
here, in one run:
- lock-step (the plant advances one period per Goal Current write, as fast as the loop goes): the
  rate and CPU per tick of the Python loop (servodyn.loop), of the native loop (the firmware as a
  Linux process, `swing --native`) and of the raw transport — dynamixel-sdk alone, one sync write
  and one fast sync read of the 7 servos a transaction, nothing else — against the same simulator
  (its own process, `servodyn sim --lockstep`'s server), which bounds what any loop can reach;
- the simulator against a minimal responder (a canned fast sync read reply, nothing simulated)
  under the same raw client, and the simulator's CPU while it serves real time with nobody talking;
- the simulator's own CPU per transaction in this process, no pseudo-terminal (SimulatedRobot.port().handle
  of the same sync write + fast sync read, the plant advancing one period), torque on in Current
  Control Mode as in the swing and torque off as the raw client leaves it;
- real time at 1 kHz over the whole swing: the period's median, p99 and largest distance from
  1 ms and the missed deadlines, Python and native.
Each goal of the loop is printed met or not with its numbers. Writes out/bench/loop.json and
out/bench/loop.md.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import select
import sys
import tempfile
import time
import tty
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from ...control.timing import SMALL_TIME_STEP
from ...hal.config import load_config
from ...hal.dynamixel import instructions
from ...hal.dynamixel.control_table import (ADDR_GOAL_CURRENT, ADDR_OPERATING_MODE, ADDR_PRESENT,
                                           ADDR_TORQUE_ENABLE, PRESENT_LENGTH, OperatingMode)
from ...hal.dynamixel.units import ServoMap
from ...sim.robot import SimulatedRobot
from ...sim.serve import SimProcess
from ...loop.run import RunOptions
from ...report.swing import play

ROOT = Path(__file__).resolve().parents[2]
RAW_TRANSACTIONS = 3000
IDLE_SECONDS = 5.0
IN_PROCESS = (15, 200)       # batches, transactions a batch: the best batch is the figure


def _child_cpu(pid: int) -> float:
    """CPU seconds (user + system) a process has used, from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def raw_transport(path: str, ids, n: int = RAW_TRANSACTIONS) -> dict:
    """dynamixel-sdk alone on `path`: n × (sync write of Goal Current + fast sync read of Present
    Current..Position), its rate and CPU (this thread) per transaction."""
    import dynamixel_sdk as sdk
    port = sdk.PortHandler(path)
    if not port.openPort() or not port.setBaudRate(4_000_000):
        raise RuntimeError(f"cannot open {path}")
    handler = sdk.PacketHandler(2.0)
    writer = sdk.GroupSyncWrite(port, handler, ADDR_GOAL_CURRENT, 2)
    reader = sdk.GroupSyncRead(port, handler, ADDR_PRESENT, PRESENT_LENGTH)
    for i in ids:
        writer.addParam(i, [0, 0])
        reader.addParam(i)
    failed = 0
    began, cpu = time.perf_counter(), time.thread_time()
    for _ in range(n):
        writer.txPacket()
        failed += reader.fastSyncRead() != sdk.COMM_SUCCESS
    wall, cpu = time.perf_counter() - began, time.thread_time() - cpu
    port.closePort()
    return {"hz": n / wall, "cpu_ms": cpu / n * 1e3, "failed": failed}


def _responder(conn, reply: bytes) -> None:
    """The minimal responder: a pty that answers every fast sync read (0x8A) with `reply`."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    conn.send(os.ttyname(slave))
    while True:
        ready, _, _ = select.select([master, conn], [], [])
        if conn in ready:
            return
        data = os.read(master, 4096)
        if b"\x8a" in data:
            os.write(master, reply)


def minimal_responder_rate(ids) -> dict:
    blocks = [instructions.FastReadBlock(i, 0, bytes(PRESENT_LENGTH)) for i in ids]
    ctx = get_context("fork")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_responder, args=(child, instructions.encode_fast_reply(blocks)), daemon=True)
    proc.start()
    try:
        return raw_transport(parent.recv(), ids)
    finally:
        parent.send("stop")
        proc.join(2)
        if proc.is_alive():
            proc.kill()


def simulator_in_process(config, torque: bool) -> float:
    """µs of this thread's CPU per transaction of the simulator itself (SimulatedRobot.port().handle in
    lock-step: a sync write of Goal Current, the plant one period on, a fast sync read of Present
    Current..Position of the 7 servos), the best of IN_PROCESS batches. With torque on every servo
    is in Current Control Mode holding the arm's weight at its start (Goal Current ±1 unit from
    tick to tick, so the write's bytes change as the loop's do)."""
    arm = SimulatedRobot(config).port()
    arm.lockstep()
    ids = [j.id for j in arm.joints]
    hold = np.zeros(len(ids), dtype=np.int64)
    if torque:
        for i in ids:
            arm.handle(instructions.write(i, ADDR_OPERATING_MODE, bytes([OperatingMode.CURRENT])).encode())
            arm.handle(instructions.write(i, ADDR_TORQUE_ENABLE, b"\x01").encode())
        gravity = arm.model.inverse_dynamics(arm.q, np.zeros(arm.model.nv), np.zeros(arm.model.nv))
        hold, _ = ServoMap.from_joints(arm.joints).goal_current_units(gravity, [j.current_limit for j in arm.joints])
    writes = [instructions.sync_write(ADDR_GOAL_CURRENT, 2, {i: int(u + s).to_bytes(2, "little", signed=True)
                                                             for i, u in zip(ids, hold)}).encode() for s in (-1, 1)]
    read = instructions.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, ids).encode()
    batches, n = IN_PROCESS
    best = float("inf")
    gc.collect()
    gc.freeze()          # what is set up out of the collections, as the simulator's process has it
    try:
        for _ in range(batches):
            began = time.thread_time()
            for k in range(n):
                arm.handle(writes[k & 1])
                arm.handle(read)
            best = min(best, (time.thread_time() - began) / n)
    finally:
        gc.unfreeze()
    return best * 1e6


def simulator_figures(config) -> dict:
    ids = [j.id for j in config.joints]
    in_process = {"torque_on_us": simulator_in_process(config, True),
                  "torque_off_us": simulator_in_process(config, False)}
    print(f"  the simulator in this process: {in_process['torque_on_us']:.0f} µs a transaction torque on, "
          f"{in_process['torque_off_us']:.0f} µs torque off", flush=True)
    with SimProcess(config.path, "lockstep") as sim:
        raw = raw_transport(sim.path, ids)
    minimal = minimal_responder_rate(ids)
    with SimProcess(config.path, "realtime") as sim:
        time.sleep(0.5)
        before, began = _child_cpu(sim.process.pid), time.perf_counter()
        time.sleep(IDLE_SECONDS)
        idle = (_child_cpu(sim.process.pid) - before) / (time.perf_counter() - began)
    return {"in_process": in_process, "raw": raw, "minimal": minimal, "sim_vs_minimal": raw["hz"] / minimal["hz"],
            "realtime_idle_cores": idle}


def swing_figures(summary: dict) -> dict:
    cpu = summary.get("cpu_ms_per_tick") or {}
    return {"completed": summary["completed"], "ticks": summary["ticks"], "error": summary.get("error"),
            "loop_hz": summary.get("loop_hz"), "cpu_median_ms": cpu.get("median"), "cpu_p99_ms": cpu.get("p99"),
            "period_median_ms": summary.get("period_median_ms"), "error_p99_ms": summary.get("jitter_p99_ms"),
            "error_max_ms": summary.get("jitter_max_ms"), "missed": summary.get("missed_deadlines"),
            "cpu": summary.get("cpu"), "home_ticks": summary.get("home_ticks") or 0}


def measure() -> dict:
    config = load_config("replica")
    results = {"cpus": os.cpu_count(), "load_before": os.getloadavg()}
    print("  the simulator: raw transport, minimal responder, idle real time ...", flush=True)
    results["simulator"] = simulator_figures(config)
    with tempfile.TemporaryDirectory() as tmp:
        for name, options in (("python lock-step", {}), ("native lock-step", {"native": True}),
                              ("python real time", {"realtime": True}),
                              ("native real time", {"realtime": True, "native": True})):
            print(f"  {name} ...", flush=True)
            summary = play("replica", RunOptions(**options), Path(tmp) / name.replace(" ", "_"),
                           say=lambda *a, **k: None)
            results[name] = swing_figures(summary)
    results["load_after"] = os.getloadavg()
    return results


def _f(value, fmt="{:.3f}"):
    return "–" if value is None else fmt.format(value)


def goals(r: dict) -> list[tuple[str, bool, str]]:
    sim, raw = r["simulator"], r["simulator"]["raw"]
    py, nat = r["python lock-step"], r["native lock-step"]
    pyrt, natrt = r["python real time"], r["native real time"]
    run_ticks = lambda x: x["ticks"] + x.get("home_ticks", 0)     # homing's deadlines are the run's too
    py_missed = (pyrt["missed"] or 0) / max(1, run_ticks(pyrt))
    return [
        ("simulator ≥ 0.4 × a minimal responder (raw client)", sim["sim_vs_minimal"] >= 0.4,
         f"{raw['hz']:.0f} / {sim['minimal']['hz']:.0f} Hz = {sim['sim_vs_minimal']:.2f}"),
        ("simulator idle in real time well under half a core", sim["realtime_idle_cores"] < 0.25,
         f"{sim['realtime_idle_cores']:.2f} core"),
        ("Python loop ≥ 1 kHz lock-step", (py["loop_hz"] or 0) >= 1000, f"{_f(py['loop_hz'], '{:.0f}')} Hz"),
        ("Python loop CPU per tick ≤ 0.3 ms", (py["cpu_median_ms"] or 1) <= 0.3, f"{_f(py['cpu_median_ms'])} ms"),
        ("native loop ≥ 0.5 × the raw transport", (nat["loop_hz"] or 0) >= 0.5 * raw["hz"],
         f"{_f(nat['loop_hz'], '{:.0f}')} / {raw['hz']:.0f} Hz = {(nat['loop_hz'] or 0) / raw['hz']:.2f}"),
        ("native loop CPU per tick ≤ 0.05 ms", (nat["cpu_median_ms"] or 1) <= 0.05, f"{_f(nat['cpu_median_ms'])} ms"),
        ("native real time: p99 period error ≤ 0.1 ms, no missed deadline",
         natrt["completed"] and (natrt["error_p99_ms"] or 1) <= 0.1 and natrt["missed"] == 0,
         f"p99 {_f(natrt['error_p99_ms'])} ms, {natrt['missed']} missed of {run_ticks(natrt)} ticks"
         + (f", stopped: {natrt['error']}" if natrt["error"] else "")),
        ("Python real time: ≤ 1 % missed", pyrt["completed"] and py_missed <= 0.01,
         f"{100 * py_missed:.1f} % ({pyrt['missed']} of {run_ticks(pyrt)} ticks, homing's included)"
         + (f", stopped: {pyrt['error']}" if pyrt["error"] else "")),
    ]


def table(r: dict) -> str:
    sim = r["simulator"]
    lines = [f"{r['cpus']} cpus, load average {r['load_before'][0]:.1f} before and {r['load_after'][0]:.1f} after "
             "(a shared machine: other jobs ran beside this one)", "",
             "| lock-step | rate (Hz) | CPU per tick, median (ms) | p99 (ms) |", "|---|---:|---:|---:|",
             f"| raw transport: dynamixel-sdk sync write + fast sync read, the simulator | {sim['raw']['hz']:.0f} | "
             f"{sim['raw']['cpu_ms']:.3f} | – |",
             f"| raw transport against a minimal responder | {sim['minimal']['hz']:.0f} | "
             f"{sim['minimal']['cpu_ms']:.3f} | – |"]
    for name in ("python lock-step", "native lock-step"):
        x = r[name]
        lines.append(f"| {name.split()[0]} loop | {_f(x['loop_hz'], '{:.0f}')} | {_f(x['cpu_median_ms'])} | "
                     f"{_f(x['cpu_p99_ms'])} |")
    lines += ["", "| real time, 1 kHz | ticks | period median (ms) | error p99 (ms) | error max (ms) | missed | stop |",
              "|---|---:|---:|---:|---:|---:|---|"]
    for name in ("python real time", "native real time"):
        x = r[name]
        lines.append(f"| {name.split()[0]} loop | {x['ticks']} | {_f(x['period_median_ms'])} | {_f(x['error_p99_ms'])} | "
                     f"{_f(x['error_max_ms'])} | {x['missed']} | {x['error'] or 'completed'} |")
    placed = {name.split()[0]: r[name].get("cpu") for name in ("python real time", "native real time")}
    lines += ["", "real time, the loop, the simulator and the kernel's tty work on one CPU (hal.realtime."
              "one_cpu): " + ", ".join(f"{loop} on CPU {cpu}" if cpu is not None else f"{loop} not placed"
                                       for loop, cpu in placed.items()),
              "", f"simulator serving real time, nobody talking: {sim['realtime_idle_cores']:.2f} core",
              f"simulator's own CPU per transaction in this process (sync write + one period + fast sync read of "
              f"the 7 servos, best of {IN_PROCESS[0]} × {IN_PROCESS[1]}): {sim['in_process']['torque_on_us']:.0f} µs "
              f"torque on in Current Control Mode, {sim['in_process']['torque_off_us']:.0f} µs torque off", "",
              "| goal | met | numbers |", "|---|---|---|"]
    lines += [f"| {name} | {'yes' if ok else 'NO'} | {numbers} |" for name, ok, numbers in goals(r)]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.loop", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    print(f"servodyn control loop: the replica's swing on the simulated bus, {os.cpu_count()} cpus", flush=True)
    results = measure()
    results["goals"] = [{"goal": g, "met": ok, "numbers": n} for g, ok, n in goals(results)]
    publish(Path(args.out), "loop", table(results), results)
    return 0


def publish(out: Path, stem: str, text: str, data) -> None:
    """Print a bench section's table and write it as OUT/STEM.md with its numbers in OUT/STEM.json."""
    print("\n" + text)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(text + "\n")
    (out / f"{stem}.json").write_text(json.dumps(data, indent=1) + "\n")
    print(f"\nwrote {out / (stem + '.md')}, {out / (stem + '.json')}")


if __name__ == "__main__":
    sys.exit(main())
