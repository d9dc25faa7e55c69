"""The firmware's budget (`make bench`): instructions per control tick, flash, RAM and stack.

Runs the whole swing on each board under QEMU with `-icount shift=7,sleep=off`: every instruction
is 128 ns of emulated time and SysTick counts the 25 MHz processor clock, so instructions =
counts / 3.2, the same on every run. These are instruction counts, not cycles (QEMU models no
pipeline, caches or wait states): a budget and a regression figure. At 7.8 emulated MIPS a tick
does not fit 1 ms, so the run uses a 2 ms period; the lock-stepped plant still advances 1 ms per
tick and the instruction counts do not depend on the period.

Goals for the 7-dof replica on the M4F: <= 15,000 instructions per tick, flash <= 64 KB,
RAM <= 16 KB, stack <= 2 KB.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from servodyn.tools.hil import BOARDS, default_elf, run_qemu, summarize

ROOT = Path(__file__).resolve().parent.parent
SHIFT = 7
GOALS = {"instructions": 15000, "flash": 64 * 1024, "ram": 16 * 1024, "stack": 2048}
ROWS = (("read", "fast sync read: send 21 B, parse the 106 B reply"),
        ("trajectory", "trajectory point (and the gain schedule)"),
        ("control_update", "inverse dynamics (RNEA) + PD, every 10th tick"),
        ("control", "PD alone, the other ticks"),
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
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "stackpath.py"),
                          "--entry", "main", "--isr", "board_systick_isr", "--isr", "board_uart0_rx_isr",
                          str(ROOT / "build" / "fw" / board)], capture_output=True, text=True)
    return run.stdout.strip() or run.stderr.strip()


def main() -> int:
    out = ROOT / "out" / "bench"
    out.mkdir(parents=True, exist_ok=True)
    results, lines = {}, []
    for board in BOARDS:
        print(f"firmware budget: the swing on {BOARDS[board][0]} ({BOARDS[board][1]}), -icount "
              f"shift={SHIFT} ...", flush=True)
        report, record, _ = run_qemu(board, default_elf(board), icount_shift=SHIFT, args="period_us=2000")
        summary = summarize(report, record, "replica", SHIFT, board)
        summary.update(footprint(default_elf(board)))
        summary["stack_path"] = stack_path(board)
        results[board] = summary
    lines.append("Firmware, 7-dof replica, the whole swing (9,202 ticks), instructions per tick "
                 f"(-icount shift={SHIFT}; exact and repeatable; not cycles):\n")
    lines.append("| section | " + " | ".join(f"{b} worst | {b} mean" for b in BOARDS) + " |")
    lines.append("|---|" + "---:|---:|" * len(BOARDS))
    for key, what in ROWS:
        cells = []
        for board in BOARDS:
            v = results[board]["instructions_per_tick"].get(key, {"max": 0, "mean": 0})
            cells += [f"{v['max']:,}", f"{v['mean']:,}"]
        lines.append(f"| {what} | " + " | ".join(cells) + " |")
    m4 = results["an386"]
    worst = m4["instructions_per_tick"]["tick"]["max"]
    lines.append("")
    lines.append(f"M4F goals: instructions/tick worst {worst:,} (goal <= {GOALS['instructions']:,}: "
                 f"{'met' if worst <= GOALS['instructions'] else 'NOT met'}); flash {m4['flash']:,} B "
                 f"(<= {GOALS['flash']:,}: {'met' if m4['flash'] <= GOALS['flash'] else 'NOT met'}); RAM "
                 f"{m4['ram']:,} B incl. a {m4['stack_reserved']:,} B stack (<= {GOALS['ram']:,}: "
                 f"{'met' if m4['ram'] <= GOALS['ram'] else 'NOT met'}); stack used "
                 f"{m4['stack_used_bytes']:,} B measured (<= {GOALS['stack']:,}: "
                 f"{'met' if m4['stack_used_bytes'] <= GOALS['stack'] else 'NOT met'})")
    lines.append(f"M7 (an500): flash {results['an500']['flash']:,} B, RAM {results['an500']['ram']:,} B, "
                 f"stack used {results['an500']['stack_used_bytes']:,} B")
    lines.append(f"Goals vs the host's double controller: largest difference "
                 f"{m4['goal_max_diff_units']} unit; swing tracking max "
                 f"{m4['tracking_max_rad'] * 57.29578:.3f} deg")
    lines.append("Static worst stack path (M4F, scripts/stackpath.py):")
    lines.extend("  " + line for line in m4["stack_path"].splitlines())
    text = "\n".join(lines)
    print("\n" + text)
    (out / "firmware.md").write_text(text + "\n")
    (out / "firmware.json").write_text(json.dumps(results, indent=2, default=str) + "\n")
    print(f"\nwrote {out / 'firmware.md'}, {out / 'firmware.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
