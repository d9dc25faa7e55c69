"""A process that must keep a period on a shared machine: real-time priority where the process may
have it, and no garbage collection in the middle of a tick.

    with realtime_priority(LOOP_PRIORITY):     # SCHED_FIFO, as the firmware's POSIX board takes it
        ...                                     # the previous policy is back afterwards
    with collector_paused():                    # no collection between two ticks
        ...

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

LOOP_PRIORITY = 80       # SCHED_FIFO priority of a real-time control loop (firmware/posix: the same)
SIMULATOR_PRIORITY = 81  # the simulated servos answer ahead of the loop, as hardware does

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
        _say_once(f"servodyn: SCHED_FIFO not allowed ({err.strerror}): {who} runs at normal priority")
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
