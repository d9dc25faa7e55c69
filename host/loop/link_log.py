"""A run played by a controller over the host link, as the Python loop's RunLog: from its telemetry
(docs/host-link.md, TELEMETRY every tick), so the log, summary and figure are made by the same code
for every controller (issue 34's step 4 begins here).

Each tick of the motion, from the first tick the telemetry says `playing` to the tick it says
DONE: t on the motion's clock, the desired and measured positions, the measured speeds and the
commanded torque (telemetry's fixed point: 2^-12 rad, 2^-9 rad/s, 2^-9 N m), the current (the
servo's own units, exact, into amperes and the joint's sign as the controller reads them), and the
tick's work (µs) as its wall and CPU time. The controller reads no temperature.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..hal.dynamixel.units import ServoMap
from ..hal.link import messages as ms
from .log import RunLog


def telemetry_log(config, telemetry) -> RunLog:
    """The motion's ticks of `telemetry` (every tick's, in order) as a RunLog of `config`'s joints
    (none when the motion never began: a fault while homing). InputError when a tick of the motion
    is missing (telemetry decimated, or frames lost)."""
    playing = ms.STATES.index("playing")
    period = config.control_period
    start = next((t.tick for t in telemetry if t.state == playing), None)
    if start is None:
        return RunLog(tuple(config.model.dof_names))
    rows = [t for t in telemetry if t.tick >= start]
    end = next((k for k, t in enumerate(rows) if t.flags & ms.TM_DONE), len(rows) - 1)
    rows = rows[:end + 1]
    ticks = np.array([t.tick for t in rows])
    if len(ticks) and (np.diff(ticks) != 1).any():
        raise InputError(f"host link: the telemetry misses {int((np.diff(ticks) - 1).sum())} ticks of the "
                         "motion (telemetry every tick is needed for its log)")
    units = ServoMap.from_joints(config.joints)
    direction = np.array([j.direction for j in config.joints], dtype=float)
    log = RunLog(tuple(config.model.dof_names))
    field = lambda t, name: np.array([getattr(j, name) for j in t.joints], dtype=float)
    for t in rows:
        work = t.work_us * 1e-6
        log.t.append((t.tick - start) * period)
        log.q_d.append(field(t, "q_d"))
        log.q.append(field(t, "q"))
        log.qd.append(field(t, "qd"))
        log.tau.append(field(t, "tau"))
        log.current.append(direction * field(t, "effort") * np.asarray(units.current_unit, dtype=float))
        log.temperature.append(np.full(len(t.joints), np.nan))
        log.tick_start.append((t.tick - start) * period)
        log.tick_seconds.append(work)
        log.cpu_seconds.append(work)
        log.process_cpu_seconds.append(work)
    log.missed = rows[-1].missed if rows else 0
    return log
