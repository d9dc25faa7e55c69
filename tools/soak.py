"""`make soak` (python -m servodyn.tools.soak): the fault-injection soak.

Many short swings on the simulated Dynamixel bus, each with one fault drawn at random at a random
tick of the motion: a silent servo, a hardware error bit, a flipped byte, a burst of garbage, a
reply delayed past the timeout, a reply from the wrong id, a NaN in the motion, a joint pushed
beyond its limit, the simulator paused past the host's patience (sim/faults.py STALL). Every run
must end in a safe stop: torque off on every servo within two plant ticks of the fault (in lock-step the plant moves one tick per
command, so this counts the commands sent after it), one line of error, the exit status of the
fault's class (servodyn.errors.ExitCode, the firmware's fault codes), and a log with every tick up to the
stop and a complete last line. No run may hang or raise. A subset runs through the firmware
under QEMU (the same faults, injected on the same simulated bus). Some runs play on the simulated
CAN motors of `replica_can`, a few on `replica_mixed` (CAN and Dynamixel buses, one robot), with
the faults of a CAN bus: a silent motor, a fault status (Damiao's nibble: overvoltage,
undervoltage, overcurrent, over-temperature, communication lost, overload; a Dynamixel servo's
Hardware Error Status on the mixed robot's serial bus), a garbage frame, a reply naming another
motor, an error frame, the host's controller going bus-off, a NaN in the motion, a joint pushed
beyond its limit. It prints the table fault class x runs x safe stops, and exits 1 when any run
fails a check.

The motions are short (0.3 s from the simulated arm's rest pose, the homing 20 ms) and the faults
early, so that hundreds of runs take minutes; the runs are spread over worker processes.
"""

from __future__ import annotations

import csv
import multiprocessing
import random
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

from ..control.timing import SMALL_TIME_STEP
from ..errors import ExitCode
from ..hal.config import load_config
from ..hal.dynamixel.control_table import HARDWARE_FAULTS
from ..loop.log import PER_DOF
from ..hil import run_qemu
from ..loop.run import RunOptions
from ..report.swing import play

SMALL = 1e-3                 # s, the swing's small_time_step (checked against timing below); a
                             # configuration's [control] period replaces it (replica_can: 2.5 ms)
MOTION_TIME = 0.3            # s of each run's motion
HOME_TIME = 0.02             # s of homing (the motion starts where the arm rests)
RUN_TIMEOUT = 120.0          # s before a run counts as hung
STOP_TICKS = 2               # plant ticks from the fault to torque off

# fault class: (the faults it draws from, the exit statuses its safe stop may have on the host,
# the fault names the firmware may report, None: not run there). A flipped bit that lands in an
# ID reads as another servo's reply (no answer from the one asked: 10), elsewhere as a bad CRC
# (12); garbage without a header is, to the firmware, no reply at all. Under QEMU's -icount the
# firmware's clock is the instruction count, which a wall-clock delay or pause does not move:
# those two classes run on the host only.
CLASSES = {
    "silent servo": (("silent",), {10}, {"timeout"}),
    "hardware error": (tuple(HARDWARE_FAULTS), {11}, {"status"}),
    "flipped byte": (("flipped_byte",), {12, 10}, {"corrupt", "timeout"}),
    "garbage burst": (("garbage",), {12}, {"corrupt", "timeout"}),
    "delayed reply": (("delayed_reply",), {10}, None),
    "wrong id": (("wrong_id",), {10}, {"timeout", "corrupt"}),
    "nan in motion": (("nan_motion",), {13}, {"nonfinite"}),
    "beyond limit": (("pushed",), {15}, {"range"}),
    "bus stall": (("stall",), {10}, None),
}

# the CAN runs: fault class: (the faults it draws for a CAN motor, for a Dynamixel servo (None: the
# class draws CAN motors only), the exit statuses its safe stop may have). A garbage frame on a
# motor's reply id is refused as corrupt when it is no reply (12), but a random frame can read as
# a valid one with a fault status (11) or a position beyond the limits (15); a reply naming another
# motor is corrupt on the reply id (12). Damiao's status nibbles 8-E, and the winding overheated.
CAN_STATUSES = (0x8, 0x9, 0xA, 0xB, 0xC, 0xD, 0xE, "overheat")
CAN_CLASSES = {
    "silent motor": (("silent",), ("silent",), {10}),
    "fault status": (CAN_STATUSES, tuple(HARDWARE_FAULTS), {11}),
    "garbage frame": (("garbage",), None, {12, 11, 15}),
    "wrong id": (("wrong_id",), None, {12}),
    "error frame": (("error_frame",), None, {12}),
    "bus-off": (("bus_off",), None, {12}),
    "nan in motion": (("nan_motion",), ("nan_motion",), {13}),
    "beyond limit": (("pushed",), ("pushed",), {15}),
}
MIXED_EVERY = 4               # every 4th CAN run plays on replica_mixed


def _motion(path: Path, rng: random.Random, model, config) -> None:
    """A keyframe file: from rest (the simulated arm's start pose) to a random nearby pose."""
    rest = model.neutral_q()
    lines = [f'name = "soak"\nmodel = "{model.name}"\n']
    for t, q in ((0.0, rest), (MOTION_TIME, rest)):
        if t:
            q = [min(max(r + rng.uniform(-0.15, 0.15), j.position_limits[0] + 0.05), j.position_limits[1] - 0.05)
                 for r, j in zip(rest, (next(c for c in config.joints if c.dof == d) for d in model.dof_names))]
        angles = ", ".join(f"{d} = {float(v)!r}" for d, v in zip(model.dof_names, q))
        lines.append(f"[[keyframe]]\nt = {t}\nq = {{ {angles} }}\n")
    path.write_text("\n".join(lines))


def plan(runs: int, seed: int, firmware: int, can: int = 0) -> list[dict]:
    """Each run's fault class, fault, servo, tick and motion seed; classes in turn, the rest random."""
    rng = random.Random(seed)
    names = list(CLASSES)
    specs = []
    for k in range(runs):
        name = names[k % len(names)]
        specs.append({"run": k, "class": name, "fault": rng.choice(CLASSES[name][0]), "servo": rng.randint(1, 7),
                      "tick": rng.randint(5, int(MOTION_TIME / SMALL) - 60), "seed": rng.randrange(2**31),
                      "firmware": False, "config": "replica"})
    can_names = list(CAN_CLASSES)
    periods = {}
    for k in range(can):
        name = can_names[k % len(can_names)]
        on_can, on_dynamixel, _ = CAN_CLASSES[name]
        # the mixed runs move by one class each round, so every class gets some
        config = "replica_mixed" if (k + k // len(can_names)) % MIXED_EVERY == MIXED_EVERY - 1 else "replica_can"
        # replica_mixed: CAN motors 1-4 on one bus, Dynamixel servos 5-7 on the other
        servo = rng.randint(1, 7 if config == "replica_can" or on_dynamixel else 4)
        faults = on_can if config == "replica_can" or servo <= 4 else on_dynamixel
        if config not in periods:
            periods[config] = load_config(config).control_period
        ticks = int(round(MOTION_TIME / periods[config]))
        specs.append({"run": len(specs), "class": name, "fault": rng.choice(faults), "servo": servo,
                      "tick": rng.randint(5, ticks - ticks // 5), "seed": rng.randrange(2**31),
                      "firmware": False, "config": config})
    runs = len(specs)
    on_firmware = [name for name in names if CLASSES[name][2] is not None]
    for k in range(firmware):
        name = on_firmware[k % len(on_firmware)]
        specs.append({"run": runs + k, "class": name, "fault": rng.choice(CLASSES[name][0]),
                      "servo": rng.randint(1, 7), "tick": rng.randint(20, 200), "seed": rng.randrange(2**31),
                      "firmware": True, "config": "replica"})
    return specs


def run_host(spec: dict, folder: Path) -> dict:
    """One swing with its fault, checked; the checks that failed in 'problems'."""
    config = load_config(spec["config"])
    can = spec["config"] != "replica"
    motion = folder / f"motion_{spec['run']}.toml"
    _motion(motion, random.Random(spec["seed"]), config.model, config)
    out = folder / f"run_{spec['run']}"
    lines = []
    period = config.control_period
    fault_t = spec["tick"] * period
    options = RunOptions(motion=str(motion), time_scale=1.0, fault_at=(fault_t, spec["servo"], spec["fault"]),
                         home_duration=HOME_TIME)
    summary = play(config, options, out, say=lines.append, figure=False)
    problems = []
    error = summary.get("error")
    expected = CAN_CLASSES[spec["class"]][2] if can else CLASSES[spec["class"]][1]
    stopped = error is not None
    if not stopped:
        problems.append("no safe stop: the run completed")
    elif stopped and "\n" in error:
        problems.append("error in more than one line")
    if not all(summary.get("torque_off", [False])):
        problems.append("a servo left with torque on")
    late = round((summary.get("sim_time_at_stop_s", 0.0) - fault_t) / period)
    if stopped and late > STOP_TICKS:
        problems.append(f"torque off {late} plant ticks after the fault")
    code = summary.get("exit_code", ExitCode.OK)
    if stopped and code not in expected:
        problems.append(f"exit status {code}, expected {' or '.join(map(str, sorted(expected)))} "
                        f"({summary.get('error_class')}: {error})")
    problems += _check_log(out / "swing_log.csv", summary["ticks"], len(config.model.dof_names), period)
    return {**spec, "stopped": stopped, "code": code, "late_ticks": late, "error": error, "problems": problems}


def _check_log(path: Path, ticks: int, ndof: int, period: float = SMALL) -> list[str]:
    """The log has every tick from the first to the stop, one row each, the last one complete."""
    if not path.is_file():
        return ["no log"]
    text = path.read_text()
    if not text.endswith("\n"):
        return ["the log's last line is cut"]
    rows = list(csv.reader(text.splitlines()))
    width = 1 + len(PER_DOF) * ndof
    if any(len(r) != width for r in rows):
        return ["a log row with a wrong number of fields"]
    if len(rows) - 1 != ticks:
        return [f"the log has {len(rows) - 1} rows for {ticks} ticks"]
    times = [float(r[0]) for r in rows[1:]]
    if any(abs(b - a - period) > 1e-9 for a, b in zip(times, times[1:])):
        return ["a tick missing from the log"]
    return []


def run_firmware(spec: dict) -> dict:
    """The same fault through the firmware under QEMU: a fault report of the class, torque off."""
    fault = spec["fault"]
    args = f"ticks={spec['tick'] + 60}"

    def inject(k, arm):
        if k == spec["tick"]:
            arm.inject_fault(spec["servo"], fault)
    if fault == "nan_motion":
        args += f" nan_at={spec['tick']}"
    report, record, arm = run_qemu(args=args, on_tick=None if fault == "nan_motion" else inject)
    problems = []
    expected = CLASSES[spec["class"]][2]
    stopped = report.get("result") == "fault"
    if not stopped:
        problems.append(f"no safe stop: {report.get('result')}")
    elif report.get("fault") not in expected:
        problems.append(f"fault {report.get('fault')}, expected {' or '.join(sorted(expected))}")
    if not record.torque_off or any(s.torque_enabled for s in arm.servos):
        problems.append("a servo left with torque on")
    return {**spec, "stopped": stopped, "code": report.get("exit_code"), "late_ticks": None,
            "error": f"{report.get('result')} {report.get('fault')}", "problems": problems}


def _one(spec: dict) -> dict:
    began = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory(prefix="servodyn-soak-") as folder:
            result = run_firmware(spec) if spec["firmware"] else run_host(spec, Path(folder))
    except BaseException as err:            # a traceback is a failure of the soak, reported in one line
        import traceback
        where = traceback.extract_tb(err.__traceback__)[-1]
        result = {**spec, "stopped": False, "code": None, "late_ticks": None, "error": None,
                  "problems": [f"raised {type(err).__name__}: {err} ({Path(where.filename).name}:{where.lineno})"],
                  "traceback": True}
    result["seconds"] = time.perf_counter() - began
    return result


def _where(result: dict) -> str:
    """The table's column: host (replica, Dynamixel), firmware (under QEMU), can, mixed."""
    if result["firmware"]:
        return "firmware"
    return {"replica": "host", "replica_can": "can", "replica_mixed": "mixed"}[result["config"]]


def run(args) -> int:
    """The soak of `servodyn soak` (tools/cli/soak.py: its options)."""
    assert SMALL_TIME_STEP == SMALL, "the soak's tick is the swing's small_time_step"
    specs = plan(args.runs, args.seed, args.firmware, args.can)
    print(f"soak: {args.runs} swings on the simulated Dynamixel bus + {args.can} on simulated CAN motors + "
          f"{args.firmware} through the firmware under QEMU, "
          f"one random fault each, {args.jobs} workers (seed {args.seed})", flush=True)
    began = time.perf_counter()
    results, hung = [], []
    context = multiprocessing.get_context("spawn")
    with context.Pool(args.jobs, maxtasksperchild=40) as pool:
        pending = {spec["run"]: pool.apply_async(_one, (spec,)) for spec in specs}
        for run, handle in pending.items():
            try:
                results.append(handle.get(timeout=RUN_TIMEOUT + 10 * len(specs) / args.jobs))
            except multiprocessing.TimeoutError:
                hung.append(run)
                break
            done = len(results)
            if done % 25 == 0:
                print(f"  {done}/{len(specs)} runs, {time.perf_counter() - began:.0f} s", flush=True)
        if hung:
            pool.terminate()
    wall = time.perf_counter() - began
    table = defaultdict(Counter)
    for r in results:
        row = table[(r["class"], _where(r))]
        row["runs"] += 1
        row["safe stops"] += r["stopped"] and not r["problems"]
        row["failed"] += bool(r["problems"])
        row["tracebacks"] += bool(r.get("traceback"))
        if r["late_ticks"] is not None and r["stopped"]:
            row["worst late"] = max(row["worst late"], r["late_ticks"])
    print(f"\n  {'fault class':<16} {'where':<9} {'runs':>5} {'safe stops':>11} {'failed':>7}"
          f" {'tracebacks':>11} {'exit':>16} {'ticks to off':>13}")
    for name, where in [(n, w) for n in CLASSES for w in ("host", "firmware")] + \
            [(n, w) for n in CAN_CLASSES for w in ("can", "mixed")]:
        row = table.get((name, where))
        if row:
            codes = CLASSES[name][1 if where == "host" else 2] if where in ("host", "firmware") else \
                CAN_CLASSES[name][2]
            code = "/".join(map(str, sorted(codes)))
            print(f"  {name:<16} {where:<9} {row['runs']:>5} {row['safe stops']:>11} "
                  f"{row['failed']:>7} {row['tracebacks']:>11} {code:>16} "
                  f"{row['worst late'] if where != 'firmware' else '-':>13}")
    failed = [r for r in results if r["problems"]]
    total = Counter(runs=len(results), stops=sum(r["stopped"] and not r["problems"] for r in results))
    print(f"\n  {total['runs']} runs, {total['stops']} safe stops, {len(failed)} failed, {len(hung)} hung, "
          f"{sum(bool(r.get('traceback')) for r in results)} tracebacks in {wall:.0f} s "
          f"(2 busy cores: the wall time is this machine's)")
    for r in failed[:20]:
        print(f"  FAILED run {r['run']} ({r['class']}, {r['fault']} on servo {r['servo']} at tick {r['tick']}, "
              f"{_where(r)}): {'; '.join(r['problems'])}")
    if hung:
        print(f"  HUNG: run {hung[0]} did not finish within its time")
    return 1 if failed or hung or len(results) < len(specs) else 0

