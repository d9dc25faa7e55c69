"""The firmware's budget (`make bench`): instructions per control tick, flash, RAM and stack.

Runs the whole swing on each board under QEMU with `-icount shift=7,sleep=off`: every instruction
is 128 ns of emulated time and SysTick counts the 25 MHz processor clock, so instructions =
counts / 3.2, the same on every run. These are instruction counts, not cycles (QEMU models no
pipeline, caches or wait states): a budget and a regression figure. At 7.8 emulated MIPS a tick
does not fit 1 ms, so the run uses a PERIOD_US period (2 ms until the momentum observer joined
every tick: its worst tick, about 19,000 instructions, takes 2.4 ms there); the lock-stepped plant
still advances 1 ms per tick and the instruction counts do not depend on the period.

Goals for the 7-dof replica on the M4F: <= 15,000 instructions per tick, flash <= 64 KB,
RAM <= 16 KB, stack <= 2 KB.

Wall time. The counts are exact whatever the load, but the run's wall time is not. Each tick
waits for the simulated servos in this Python process. Until the images slept through that wait
(board_io.c's sync line: WFI until the bus has answered), the firmware polled its UART meanwhile
(board_uart_wait, the clock held), so QEMU emulated that loop at full speed and competed with the
servos for the cores: measured then at load 4 on 2 cores, 18.6 ms of wall clock a tick, of which
11.3 ms of QEMU's CPU and 1.55 ms in the simulated servos. On an idle machine the 9,202 ticks take
about a minute; on a machine shared several times over they took more than the 300 s the run was
given, and the budget ended in a time-out with nothing measured. So each board is first timed on a few
hundred ticks; when the whole swing would not fit the wall-clock budget (--budget, default 300 s a
board) the firmware is told to stop after the ticks that fit (its `ticks=N` argument) and the
report says so: the worst tick then is the worst of those ticks, a lower bound on the whole
swing's (the footprint and the stack path are the image's, complete either way). A board whose run
fails is one line in the report, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from servodyn.hil import BOARDS, FirmwareError, default_elf, run_qemu, summarize

ROOT = Path(__file__).resolve().parents[2]
BUDGET = 300.0                # s of wall clock per board
CALIBRATION = (20, 400)       # ticks of the two timing runs: their difference is the per-tick cost
MARGIN = 1.3                  # the whole run must fit the budget with this much to spare
SHIFT = 7
PERIOD_US = 3000              # the emulated period of a tick (module docstring)
GOALS = {"instructions": 15000, "flash": 64 * 1024, "ram": 16 * 1024, "stack": 2048}
F405_RAM = 32 * 1024          # the STM32F405 image's RAM goal (issue 34); flash and stack as above
# the interrupt handlers each image's worst stack path may add to main's
ISRS = {"an386": ("board_systick_isr", "board_uart0_rx_isr", "board_uart1_rx_isr"),
        "f405": ("board_systick_isr", "f405_usart1_isr", "f405_usart2_isr")}
ROWS = (("read", "fast sync read: send 21 B, parse the 106 B reply"),
        ("trajectory", "trajectory point (and the gain schedule)"),
        ("control_update", "inverse dynamics (RNEA) + PD, every 10th tick"),
        ("control", "PD alone, the other ticks"),
        ("observer", "momentum observer: one sample (sd_momentum, friction)"),
        ("output", "torque -> Goal Current, limits"),
        ("write", "sync write of Goal Current (35 B)"),
        ("tick", "whole tick"))


def footprint(elf: Path) -> dict:
    out = subprocess.run(["arm-none-eabi-size", "-A", str(elf)], capture_output=True, text=True,
                         check=True).stdout
    sections = {p[0]: int(p[1]) for p in (line.split() for line in out.splitlines()) if len(p) >= 2
                and p[1].isdigit()}
    flash = sum(sections.get(s, 0) for s in (".text", ".ARM.exidx", ".data"))
    ram = sum(sections.get(s, 0) for s in (".data", ".bss", ".stack"))
    return {"flash": flash, "ram": ram, "stack_reserved": sections.get(".stack", 0)}


def stack_path(board: str) -> str:
    isrs = [arg for name in ISRS.get(board, ISRS["an386"]) for arg in ("--isr", name)]
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "stackpath.py"), "--entry", "main", *isrs,
                          str(ROOT / "build" / "fw" / board)], capture_output=True, text=True)
    return run.stdout.strip() or run.stderr.strip()


def planned_ticks() -> int:
    """The firmware's ticks for the whole run (homing and swing), from its generated plan."""
    text = (ROOT / "build" / "fw" / "gen" / "servodyn_gen.c").read_text()
    return sum(int(re.search(rf"\.{k} = (\d+)", text).group(1)) for k in ("home_ticks", "swing_ticks"))


def timed_run(board: str, ticks: int | None, timeout: float):
    """run_qemu on the swing's first `ticks` (None: all); (report, record, wall seconds)."""
    args = f"period_us={PERIOD_US}" + (f" ticks={ticks}" if ticks else "")
    began = time.perf_counter()
    report, record, _ = run_qemu(board, default_elf(board), icount_shift=SHIFT, args=args, timeout=timeout)
    return report, record, time.perf_counter() - began


def plan_ticks(board: str, total: int, budget: float, say=print) -> int | None:
    """How many ticks fit the budget on this machine now (None: all of them)."""
    few, many = CALIBRATION
    short = timed_run(board, few, budget)[2]
    longer = timed_run(board, many, budget)[2]
    per_tick = max(1e-6, (longer - short) / (many - few))
    start = max(0.0, short - few * per_tick)
    projected = start + total * per_tick
    fits = (budget / MARGIN - start) / per_tick
    say(f"  {per_tick * 1e3:.2f} ms of wall clock a tick here (load {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores), {start:.1f} s to start: the whole run ({total:,} ticks) would take "
        f"{projected:.0f} s of the {budget:.0f} s budget" +
        ("" if projected * MARGIN <= budget else f": {max(many, int(fits)):,} ticks are measured"))
    return None if projected * MARGIN <= budget else max(many, int(fits))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="fw_budget", description=__doc__.split("\n\n")[0])
    parser.add_argument("--budget", type=float, default=BUDGET,
                        help=f"s of wall clock per board (default {BUDGET:g}); a run that would not fit "
                             "measures the ticks that do")
    args = parser.parse_args(argv)
    out = ROOT / "out" / "bench"
    out.mkdir(parents=True, exist_ok=True)
    results, lines, failed = {}, [], {}
    total = planned_ticks()
    for board in BOARDS:
        print(f"firmware budget: the swing on {BOARDS[board][0]} ({BOARDS[board][1]}), -icount "
              f"shift={SHIFT} ...", flush=True)
        try:
            ticks = plan_ticks(board, total, args.budget)
            report, record, wall = timed_run(board, ticks, 3 * args.budget)
            summary = summarize(report, record, "replica", SHIFT, board)
        except FirmwareError as err:
            failed[board] = str(err).splitlines()[0]
            print(f"  {board}: not measured: {failed[board]}", flush=True)
            continue
        summary.update(footprint(default_elf(board)))
        summary["stack_path"] = stack_path(board)
        summary.update(wall_s=wall, measured_ticks=report.get("ticks"), planned_ticks=total)
        results[board] = summary
    if failed and not results:
        print(f"firmware budget: no board measured ({'; '.join(f'{b}: {e}' for b, e in failed.items())})")
        return 1
    covered = {b: r["measured_ticks"] for b, r in results.items()}
    whole = all(n == total for n in covered.values())
    lines.append(f"Firmware, 7-dof replica, {'the whole swing' if whole else 'the run'} ({total:,} ticks"
                 + ("" if whole else "; measured: " + ", ".join(f"{b} the first {n:,}" for b, n in covered.items())
                    + ", the wall-clock budget's share: the worst is a lower bound on the whole swing's")
                 + f"), instructions per tick (-icount shift={SHIFT}; exact and repeatable; not cycles):\n")
    lines.append("| section | " + " | ".join(f"{b} worst | {b} mean" for b in results) + " |")
    lines.append("|---|" + "---:|---:|" * len(results))
    for key, what in ROWS:
        cells = []
        for board in results:
            v = results[board]["instructions_per_tick"].get(key, {"max": 0, "mean": 0})
            cells += [f"{v['max']:,}", f"{v['mean']:,}"]
        lines.append(f"| {what} | " + " | ".join(cells) + " |")
    lines.append("")
    m4 = results.get("an386")
    if m4 is not None:
        worst = m4["instructions_per_tick"]["tick"]["max"]
        lines.append(f"M4F goals: instructions/tick worst {worst:,} (goal <= {GOALS['instructions']:,}: "
                     f"{'met' if worst <= GOALS['instructions'] else 'NOT met'}"
                     f"{'' if m4['measured_ticks'] == total else ' on the ticks measured'}); flash {m4['flash']:,} B "
                     f"(<= {GOALS['flash']:,}: {'met' if m4['flash'] <= GOALS['flash'] else 'NOT met'}); RAM "
                     f"{m4['ram']:,} B incl. a {m4['stack_reserved']:,} B stack (<= {GOALS['ram']:,}: "
                     f"{'met' if m4['ram'] <= GOALS['ram'] else 'NOT met'}); stack used "
                     f"{m4['stack_used_bytes']:,} B measured (<= {GOALS['stack']:,}: "
                     f"{'met' if m4['stack_used_bytes'] <= GOALS['stack'] else 'NOT met'})")
    m7 = results.get("an500")
    if m7 is not None:
        lines.append(f"M7 (an500): flash {m7['flash']:,} B, RAM {m7['ram']:,} B, "
                     f"stack used {m7['stack_used_bytes']:,} B")
    f405 = results.get("f405")
    if f405 is not None:
        worst = f405["instructions_per_tick"]["tick"]["max"]
        lines.append(f"STM32F405 (netduinoplus2): instructions/tick worst {worst:,} (goal <= {GOALS['instructions']:,}: "
                     f"{'met' if worst <= GOALS['instructions'] else 'NOT met'}; "
                     f"{100 * worst / 168000:.1f} % of a 1 ms period at 168 MHz if one instruction were a cycle); "
                     f"flash {f405['flash']:,} B (<= {GOALS['flash']:,}: {'met' if f405['flash'] <= GOALS['flash'] else 'NOT met'}); "
                     f"RAM {f405['ram']:,} B (<= {F405_RAM:,}: {'met' if f405['ram'] <= F405_RAM else 'NOT met'}); "
                     f"stack used {f405['stack_used_bytes']:,} B")
    for board, why in failed.items():
        lines.append(f"{board}: NOT measured: {why}")
    if m4 is not None:
        tracking = m4["tracking_max_rad"]
        lines.append(f"Goals vs the host's double controller: largest difference "
                     f"{m4['goal_max_diff_units']} unit; swing tracking max "
                     + (f"{tracking * 57.29578:.3f} deg" if tracking is not None else "- (no swing tick measured)"))
        lines.append("Static worst stack path (M4F, scripts/stackpath.py):")
        lines.extend("  " + line for line in m4["stack_path"].splitlines())
    lines.append(f"Wall clock per board (this machine, load {os.getloadavg()[0]:.1f}): "
                 + ", ".join(f"{b} {r['wall_s']:.0f} s for {r['measured_ticks']:,} ticks" for b, r in results.items()))
    text = "\n".join(lines)
    print("\n" + text)
    (out / "firmware.md").write_text(text + "\n")
    (out / "firmware.json").write_text(json.dumps(results, indent=2, default=str) + "\n")
    print(f"\nwrote {out / 'firmware.md'}, {out / 'firmware.json'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
