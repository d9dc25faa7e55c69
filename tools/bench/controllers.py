"""`make bench`, the controllers: every built-in configuration the general firmware application
drives × {the forehand, an excitation, a retargeted clip} × {native, qemu:an386, qemu:f405},
each run lock-stepped to the simulated arm with every bus exchange recorded, and each command's
distance from the host's double-precision controller fed the same measured state (servo units),
the controller's worst tick and how the run ended; then ten real-time runs of the forehand on the
native controller at 1 kHz and their missed deadlines, with the machine's load.

Writes out/bench/controllers.md and .json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ...hal.config import builtin_configs, load_config
from ...hil import link_agreement, run_link
from ...loop.link_controllers import QEMU_LINK_BOARDS
from ...loop.link_load import check_config
from ...loop.qemu import QEMU_ICOUNT_SHIFT, link_image, to_instructions
from ...loop.run import RunOptions
from ...report.swing import play
from .loop import publish

ROOT = Path(__file__).resolve().parents[2]
CLIP = Path("/usr/share/assimp/models/BVH/01_01.bvh")     # CMU 01_01 (`make mocap-clips`)
CLIP_WINDOW = (4.0, 8.0)             # s of the clip
CLIP_MARGIN = 1.1                    # x the time scale validate --fit finds for it
EXCITATION_S = 10.0
REALTIME_RUNS = 10


def _servodyn(*args) -> None:
    """A servodyn command, as a user runs it (the bench uses commands, not their modules)."""
    result = subprocess.run([sys.executable, "-m", "servodyn.tools.cli", *map(str, args)], capture_output=True,
                            text=True)
    if result.returncode not in (0, 1):
        raise RuntimeError(f"servodyn {' '.join(map(str, args))}: {result.stderr.strip()[-300:]}")


def motions(config, tmp: Path) -> dict:
    """name -> (motion, time scale or None) for `config`."""
    out = {"forehand": (config.swing_motion, None)}
    excitation = tmp / f"{config.name}_excitation.csv"
    _servodyn("excite", "--config", config.name, "--duration", EXCITATION_S, "-o", excitation)
    out["excitation"] = (str(excitation), 1.0)
    if CLIP.exists():
        clip, report = tmp / f"{config.name}_clip.csv", tmp / f"{config.name}_retarget"
        _servodyn("retarget", CLIP, "--config", config.name, "--time", f"{CLIP_WINDOW[0]:g}:{CLIP_WINDOW[1]:g}",
                  "-o", clip, "--report", report)
        fit = json.loads((report / "report.json").read_text())["validate"]["fit_time_scale"]
        out["clip"] = (str(clip), CLIP_MARGIN * fit)
    return out


def controllers() -> list[tuple[str, str]]:
    out = [("native", "posix")]
    for board in QEMU_LINK_BOARDS:
        try:
            link_image(board)
            out.append(("qemu", board))
        except Exception as err:       # an image not built: said in the table
            print(f"  qemu:{board}: {err}", flush=True)
    return out


def agreement_table(tmp: Path) -> list[dict]:
    rows = []
    for name in builtin_configs():
        config = load_config(name)
        try:
            check_config(config)
        except Exception as err:
            rows.append({"config": name, "skipped": str(err)})
            continue
        if any(bus.kind != "dynamixel" for bus in config.buses.values()):    # hil.run_link records a Dynamixel bus
            rows.append({"config": name, "skipped": "a CAN bus: its lock-step agreement is tests/test_fw_link_can.py's"})
            continue
        for motion, (spec, scale) in motions(config, tmp).items():
            for kind, board in controllers():
                if kind == "qemu" and len(config.buses) > 1:
                    continue
                label = "native" if kind == "native" else f"qemu:{board}"
                print(f"  {name} × {motion} × {label} ...", flush=True)
                began = time.perf_counter()
                try:
                    run = run_link(kind, name, spec, scale, board=board)
                    agreement = link_agreement(name, run)
                except Exception as err:       # a row that cannot run says why; the others still do
                    rows.append({"config": name, "motion": motion, "controller": label, "skipped": str(err)[:200]})
                    continue
                worst = run.report.get("worst_work")
                rows.append({"config": name, "motion": motion, "controller": label, "time_scale": scale,
                             "max_units": agreement["max_units"], "ticks": agreement["ticks"],
                             "motion_ticks": agreement["motion_ticks"], "stop": run.error or "completed",
                             "worst_tick_instructions": round(to_instructions(worst, board, QEMU_ICOUNT_SHIFT))
                             if kind == "qemu" and worst else None,
                             "wall_s": round(time.perf_counter() - began, 1)})
    return rows


def realtime_runs(tmp: Path) -> dict:
    load_before = os.getloadavg()
    runs = []
    for k in range(REALTIME_RUNS):
        try:
            summary = play("replica", RunOptions(controller="native", realtime=True), tmp / f"rt{k}",
                           say=lambda *a, **kw: None, figure=False)
        except Exception as err:       # a run the host could not finish is a run that missed
            runs.append({"completed": False, "missed": None, "stop": str(err)[:200]})
            continue
        report = summary.get("controller_report") or {}
        runs.append({"completed": summary["completed"], "missed": report.get("missed"),
                     "stop": summary.get("error") or "completed"})
        print(f"  real time {k + 1}/{REALTIME_RUNS}: {runs[-1]}", flush=True)
    return {"load_before": load_before, "load_after": os.getloadavg(), "runs": runs}


def table(r: dict) -> str:
    lines = ["| configuration | motion | controller | commands vs host (max units) | ticks | worst tick (instr.) "
             "| stop |", "|---|---|---|---:|---:|---:|---|"]
    for x in r["agreement"]:
        if "skipped" in x:
            lines.append(f"| {x['config']} | {x.get('motion', '–')} | {x.get('controller', '–')} | – | – | – | "
                         f"not run: {x['skipped']} |")
            continue
        worst = "–" if x["worst_tick_instructions"] is None else f"{x['worst_tick_instructions']:,}"
        lines.append(f"| {x['config']} | {x['motion']} | {x['controller']} | {x['max_units']} | {x['ticks']:,} | "
                     f"{worst} | {x['stop']} |")
    rt = r["realtime"]
    missed = [x["missed"] for x in rt["runs"]]
    lines += ["", f"native controller, real time at 1 kHz, the forehand {len(missed)} times: missed deadlines "
              f"{missed} (load average {rt['load_before'][0]:.1f} before, {rt['load_after'][0]:.1f} after; "
              f"{os.cpu_count()} cpus)",
              f"goal: 0 missed in every run: {'met' if all(m == 0 for m in missed) else 'NOT met'}",
              "stops: " + "; ".join(x["stop"] for x in rt["runs"] if x["stop"] != "completed")]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.controllers",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    print("servodyn controllers: agreement and worst tick of the general application, lock-step; real time",
          flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        results = {"agreement": agreement_table(Path(tmp)), "realtime": realtime_runs(Path(tmp))}
    publish(Path(args.out), "controllers", table(results), results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
