"""A process that must keep a period on a shared machine: real-time priority where the process may
have it, and no garbage collection in the middle of a tick.

    with realtime_priority(LOOP_PRIORITY):     # SCHED_FIFO, as the firmware's POSIX board takes it
        ...                                     # the previous policy is back afterwards
    with collector_paused():                    # no collection between two ticks
        ...
    with one_cpu(say=print) as cpu:             # this process, what it starts, and the kernel's
        ...                                     # serial-port work on one CPU (None: left as is)

Under SCHED_FIFO a thread runs until it blocks, ahead of every normally scheduled one, and its
sleeps end without timer slack; the kernel keeps 5 % of each second for the others
(/proc/sys/kernel/sched_rt_runtime_us), so a loop that never blocks cannot lock the machine up.
Where the policy is not allowed (no CAP_SYS_NICE, a container that drops it) the thread runs at
normal priority and one line says so, once per process.
"""

from __future__ import annotations

import gc
import os
import sys
from contextlib import contextmanager
from pathlib import Path

from .ports import REALTIME_FIX

LOOP_PRIORITY = 80       # SCHED_FIFO priority of a real-time control loop (firmware/posix: the same)
SIMULATOR_PRIORITY = 81  # the simulated servos answer ahead of the loop, as hardware does
# the CPUs the kernel's unbound work queues may run on: their workers carry a serial port's bytes
# (a USB adapter's and a pseudo-terminal's) from the writer's side to the reader's
WORKQUEUE_CPUMASK = Path("/sys/devices/virtual/workqueue/cpumask")

_refused: set[str] = set()       # what was said already, once per process


def _say_once(line: str) -> None:
    if line not in _refused:
        _refused.add(line)
        print(line, file=sys.stderr, flush=True)


@contextmanager
def realtime_priority(priority: int, who: str = "the loop"):
    """The calling thread under SCHED_FIFO at `priority` for the block (one line on standard error
    if the system refuses: it then runs at normal priority); its previous policy after."""
    if not hasattr(os, "sched_setscheduler"):
        yield False
        return
    try:
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as err:
        _say_once(f"servodyn: SCHED_FIFO not allowed ({err.strerror}): {who} runs at normal priority; "
                  f"to allow it, {REALTIME_FIX}")
        yield False
        return
    try:
        yield True
    finally:
        try:
            os.sched_setscheduler(0, before[0], before[1])
        except OSError:
            pass


@contextmanager
def collector_paused():
    """The cyclic garbage collector off for the block: a collection of the whole heap takes
    milliseconds, a tick's whole budget. A loop's ticks make no reference cycles; whatever the
    block leaves is collected after it, as usual."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _cpu_mask(text: str) -> int:
    """A sysfs CPU mask ("3", "ff,ffffffff": 32-bit groups in hex) as an int."""
    return int(text.strip().replace(",", ""), 16)


def _cpu_mask_text(mask: int) -> str:
    digits = f"{mask:x}"
    digits = digits.zfill(-(-len(digits) // 8) * 8)
    return ",".join(digits[k:k + 8] for k in range(0, len(digits), 8))


@contextmanager
def one_cpu(cpu: int | None = None, say=print, mask_file: Path = WORKQUEUE_CPUMASK):
    """The real-time path on one CPU for the block, and the CPU (or None: nothing changed):
    this process, and every process it starts in the block (they inherit it), pinned to `cpu`
    (default: the last it may use), and the kernel's unbound work queues steered there too.

    A byte written to a pseudo-terminal or a USB serial port reaches its reader through a kernel
    worker; on a virtual machine a wake-up that crosses to an idle CPU can wait a millisecond for
    it. With the loop, the simulated bus and the workers on one CPU no wake-up crosses: the native
    loop's 1 kHz swing missed 0-1 deadlines of 5,000 so, against 9-97 with nothing placed; pinned
    without the workers it was no better than unplaced, so without them nothing is pinned. The
    work queues are steered only from their default (every CPU) — an administrator's mask, or
    another run's, is left alone — and put back at the end if still as steered. One line says
    what was done or why not."""
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if len(allowed) < 2:
        yield None                                  # one CPU: nothing to place
        return
    cpu = allowed[-1] if cpu is None else cpu
    if cpu not in allowed:
        raise ValueError(f"CPU {cpu} is not one this process may use ({', '.join(map(str, allowed))})")
    try:
        before = mask_file.read_text()
        online = sum(1 << c for c in range(os.cpu_count() or 1))
        if _cpu_mask(before) & online != online:
            say(f"servodyn: the kernel's work queues are kept to CPUs {before.strip()} already: "
                "the real-time path is left unplaced")
            yield None
            return
        steered = _cpu_mask_text(1 << cpu)
        mask_file.write_text(steered)
    except OSError as err:
        say(f"servodyn: cannot steer the kernel's work queues ({err.strerror or err}): "
            "the real-time path is left unplaced")
        yield None
        return
    affinity = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {cpu})
        say(f"servodyn: real time on CPU {cpu}: the loop, the processes it starts and the kernel's "
            "serial-port work")
        yield cpu
    finally:
        os.sched_setaffinity(0, affinity)
        try:
            if _cpu_mask(mask_file.read_text()) == 1 << cpu:
                mask_file.write_text(before.strip())
        except OSError:
            pass
