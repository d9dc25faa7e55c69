"""The agreement oracle of every firmware build: the firmware's algorithm recomputed in the host's
double precision from the measured state the firmware saw (what crossed the simulated bus,
servodyn.loop.qemu.Record), each command compared with the firmware's in servo units."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..control import ControlConfig, Controller
from ..control.motion import DEFAULT_MOTION, load_motion
from ..control.schedule import Segment, homing, plan_run
from ..hal.backend import joint_sensors
from ..hal.config import load_config
from ..hal.dynamixel.units import ServoMap
from . import tick


def replay(config_name: str, record, segments=None) -> dict:
    """The firmware's algorithm in the host's double precision, fed the measured state the firmware
    saw: the desired positions and the Goal Current of every tick. segments(q_start): the run's
    segments (default: the generated firmware's plan, plan_run's homing and the built-in motion)."""
    config = load_config(config_name) if isinstance(config_name, (str, Path)) else config_name
    model, units = config.model, ServoMap.from_joints(config.joints)
    limit = [j.current_limit for j in config.joints]
    controller = Controller(model, ControlConfig(mode="feedforward_pd", small_time_step=config.control_period,
                                                 **config.friction))
    reads = record.reads
    q_meas = [units.from_ticks(r[:, 2]) for r in reads]
    qd_meas = [units.from_velocity_units(r[:, 1]) for r in reads]
    goals, q_d, phase = [], [], []
    n = 0
    if segments is None:
        swing = load_motion(DEFAULT_MOTION, model).sample(config.control_period,
                                                         time_scale=config.time_scale_for(DEFAULT_MOTION))
        segments = lambda q_start: plan_run(model, swing, q_start, sensors=joint_sensors(config))
    for segment in segments(q_meas[0]):
        controller.reset()
        for k in range(len(segment.traj.t)):
            if n + 1 >= len(reads):
                break
            tau = tick(controller, segment, k, q_meas[n + 1], qd_meas[n + 1])
            goals.append(units.goal_current_units(tau, limit)[0])
            q_d.append(segment.traj.q[k])
            phase.append("swing" if segment.name == "motion" else segment.name)
            n += 1
    return {"goals": np.array(goals), "q_d": np.array(q_d), "phase": np.array(phase),
            "q": np.array(q_meas[1:1 + len(goals)])}


def agreement(config_name: str, p, record) -> dict:
    """How far each command of a run over the host link (plan `p`, its bus exchanges `record`) is
    from the host's double-precision controller fed the same measured state (replay over the
    plan's homing and motion): max_units, ticks compared, motion_ticks among them."""
    segments = lambda q0: (Segment("home", homing(q0, p.swing.q[0], p.home_ms * 1e-3, p.period), p.hold_gains),
                           Segment("motion", p.swing, p.swing_gains))
    twin = replay(config_name, record, segments)
    n = min(len(twin["goals"]), len(record.goals))      # a run that stopped early: its commands
    diff = np.abs(np.array(record.goals[:n]) - twin["goals"][:n]) if n else np.zeros((0, 1))
    return {"max_units": int(diff.max()) if diff.size else None, "ticks": n,
            "motion_ticks": int((twin["phase"][:n] == "swing").sum())}
