"""A run played by a controller over the host link, as the Python loop's RunLog: from its telemetry
(docs/host-link.md, TELEMETRY every tick), so the log, summary and figure are made by the same code
for every controller (issue 34's step 4 begins here).

Each tick of the motion, from the first tick the telemetry says `playing` to the tick it says
DONE: t on the motion's clock, the desired and measured positions, the measured speeds and the
commanded torque (telemetry's fixed point: 2^-12 rad, 2^-9 rad/s, 2^-9 N m), the current (the
servo's own units, exact, into amperes and the joint's sign as the controller reads them: a
Dynamixel's Present Current, a CAN motor's torque field over its MIT range), and the tick's work
(µs) as its wall and CPU time. The controller reads no temperature.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..hal.can.frames import to_float
from ..hal.dynamixel.units import current_unit
from ..hal.link import messages as ms
from .log import RunLog


TORQUE_BITS = 12       # a CAN motor's torque field (hal/can/frames.py): telemetry's effort and command codes


def effort_currents(config):
    """f(effort codes of one tick, joint order) -> each joint's current as its bus reads it (A, the
    joint's sign): a Dynamixel's Present Current units, a CAN motor's torque code (the host's CanBus)."""
    convert = []
    for j in config.joints:
        if config.buses[j.bus].kind == "can":
            r, scale, per_amp = j.options["ranges"], j.direction * j.gear_ratio, j.gear_ratio * j.torque_constant
            convert.append(lambda code, r=r, scale=scale, per_amp=per_amp:
                           to_float(int(code), -r.t_max, r.t_max, TORQUE_BITS) * scale / per_amp)
        else:
            convert.append(lambda code, sign=float(j.direction), unit=float(current_unit(j)): sign * code * unit)
    return lambda codes: np.array([f(code) for f, code in zip(convert, codes)], dtype=float)


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
    currents = effort_currents(config)
    log = RunLog(tuple(config.model.dof_names))
    field = lambda t, name: np.array([getattr(j, name) for j in t.joints], dtype=float)
    for t in rows:
        work = t.work_us * 1e-6
        log.t.append((t.tick - start) * period)
        log.q_d.append(field(t, "q_d"))
        log.q.append(field(t, "q"))
        log.qd.append(field(t, "qd"))
        log.tau.append(field(t, "tau"))
        log.current.append(currents(field(t, "effort")))
        log.temperature.append(np.full(len(t.joints), np.nan))
        log.tick_start.append((t.tick - start) * period)
        log.tick_seconds.append(work)
        log.cpu_seconds.append(work)
        log.process_cpu_seconds.append(work)
    log.missed = rows[-1].missed if rows else 0
    return log
