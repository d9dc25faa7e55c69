"""What the host sends a controller over the host link (docs/host-link.md): a robot configuration as
its load messages (LOAD_ROBOT, one LOAD_BODY a body, one LOAD_JOINT a dof), and a motion as its
knots.

The numbers are the ones `servodyn codegen` compiles into the generated firmware, from the same
functions: the set-up sd_model (servodyn.model.layout), each joint's servo map and safety values
(`servo_table`, which codegen writes as fw_servo rows), the loop's timing and guards, and the contact
observer's constants (servodyn.loop.contact). The motion: its keyframes on the played clock (times x
scale, rates / scale, accelerations / scale^2) and, between them, a knot at every knot of the
motion's gain schedule, each with the gains there. A quintic through two points of a quintic, with
its rates and accelerations, is that quintic: the extra knots leave the played curve as it was, and
the gains, linear between knots on the controller, are the host's schedule exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control import ControlConfig
from ..control.controller import FRICTION_SPEED
from ..control.motion import DEFAULT_MOTION, motion_path
from ..control.schedule import GainSchedule, plan_gains
from ..control.timing import HOME_DURATION
from ..control.trajectory import MotionPath, Trajectory
from ..errors import InputError
from ..hal.backend import joint_sensors
from ..hal.dynamixel.pwm import pwm_driven
from ..hal.dynamixel.units import current_unit
from ..hal.link import messages as ms
from ..hal.safety import STALL_SPEED_RAD_S, STALL_TORQUE_SHARE
from ..model.layout import model_fields
from .contact import contact_observer

HOST_TIMEOUT_MS = 100      # host silent this long: the controller holds (docs/host-link.md's watchdog)
MODE_FEEDFORWARD_PD = 1    # sd_control_mode_
KNOT_SPACING = 0.01        # s: a densely sampled motion streams a knot about this often ...
KNOT_TOLERANCE = 1e-4      # rad: ... where the quintic through fewer knots is the motion within this
MIN_KNOT_GAP = 0.005       # s: no gain knot closer than this to a keyframe or a row


def servo_table(config) -> list[dict]:
    """Each joint's servo (model dof order) in the firmware's fw_servo fields: its bus, id, units,
    range, friction, following-error limit and the contact observer's constants. A CAN motor's units
    are its MIT ranges (`mit_range`; the unit scales 0), with its dialect and reply id."""
    observer = contact_observer(config)
    rows = []
    for k, j in enumerate(config.joints):
        can = config.buses[j.bus].kind == "can"
        if can:
            r = j.options["ranges"]
            units = {"model_number": 0, "rad_per_tick": 0.0, "radps_per_unit": 0.0, "amp_per_unit": 0.0,
                     "dialect": ms.DIALECTS.index(j.options["dialect"]), "reply_id": j.options["feedback_id"],
                     "mit_range": (r.p_max, r.v_max, r.t_max, r.kp_max, r.kd_max)}
        else:
            units = {"model_number": j.servo.model_number, "rad_per_tick": 2 * math.pi / j.servo.ticks_per_rev,
                     "radps_per_unit": 2 * math.pi / 60 * j.servo.velocity_unit, "amp_per_unit": float(current_unit(j)),
                     "dialect": 0, "reply_id": 0, "mit_range": (0.0,) * 5}
        rows.append({
            "bus": "can" if can else "dynamixel", "id": j.id, **units, "direction": float(j.direction),
            "zero_offset": float(j.zero_offset), "gear_ratio": float(j.gear_ratio),
            "nm_per_amp": j.torque_constant * j.gear_ratio,
            "current_limit": float(j.current_limit), "q_min": float(j.position_limits[0]),
            "q_max": float(j.position_limits[1]), "qd_max": float(j.velocity_limit),
            "friction_coulomb": float(j.friction_coulomb), "friction_viscous": float(j.friction_viscous),
            "following_error": float(config.guards.following_error[k]),
            "observer_gain": float(observer.gain[k]), "observer_lowpass": float(observer.lowpass[k]),
            "contact_threshold": float(observer.thresholds[k])})
    return rows


def buses_refused(config) -> str | None:
    """Why the controller's application cannot drive `config`'s buses, in words (None: it can)."""
    kinds = [bus.kind for bus in config.buses.values()]
    if any(kind not in ("dynamixel", "can") for kind in kinds) or kinds.count("dynamixel") > 1 or kinds.count("can") > 1:
        return f"a Dynamixel bus, a CAN bus or one of each; '{config.name}' has {', '.join(kinds)}"
    return None


def check_config(config) -> None:
    """InputError unless the general application can drive `config`: hinge joints on a Dynamixel
    Protocol 2.0 bus (every servo in Current Control Mode: fw_bus.c writes Goal Current), a CAN
    bus of MIT motors, or one of each."""
    model = config.model
    if model.free_root or any(b.ball for b in model.bodies):
        raise InputError(f"host link: the controller drives hinge joints only; '{config.model_ref}' has a free root "
                         "or ball joints")
    why = buses_refused(config)
    if why:
        raise InputError(f"host link: the controller's application drives {why}")
    old = sorted(name for name, bus in config.buses.items() if bus.kind == "dynamixel" and bus.protocol != 2.0)
    if old:
        raise InputError(f"host link: the controller speaks Dynamixel Protocol 2.0; '{config.name}' has bus "
                         f"'{old[0]}' on Protocol {config.buses[old[0]].protocol:.1f}")
    pwm = [j.dof for j in config.joints if config.buses[j.bus].kind == "dynamixel" and pwm_driven(j)]
    if pwm:
        raise InputError(f"host link: the controller drives servos by Goal Current; '{config.name}' drives {pwm[0]} "
                         "through PWM (its servo has no current control)")
    wide = [j.dof for j in config.joints if config.buses[j.bus].kind == "can" and j.id > 0xFF]
    if wide:
        raise InputError(f"host link: a CAN motor's command id is one byte on the link; joint '{wide[0]}' has "
                         "a wider one")


def robot_messages(config, kp, kd, error_lowpass, host_timeout_ms: int = HOST_TIMEOUT_MS) -> list:
    """LOAD_ROBOT, then LOAD_BODY for every body and LOAD_JOINT for every dof of `config`, with the
    joints' gains kp, kd (N m/rad, N m s/rad: what homing and holding use) and error low-pass."""
    check_config(config)
    f = model_fields(config.model)
    nb, nd = int(f["nbody"]), int(f["ndof"])
    period = config.control_period
    observer = contact_observer(config)
    safety = config.guards
    out = [ms.RobotHead(
        nbody=nb, ndof=nd, free_root=0, mode=MODE_FEEDFORWARD_PD, contact=int(safety.contact),
        contact_debounce=observer.debounce, reaction=ms.REACTIONS.index(safety.reaction),
        update_ticks=ControlConfig(small_time_step=period).update_ticks, host_timeout_ms=host_timeout_ms,
        period_us=round(period * 1e6), gravity=tuple(f["gravity"]), friction_speed=FRICTION_SPEED,
        stall_time=safety.stall_time, stall_speed=STALL_SPEED_RAD_S, stall_share=STALL_TORQUE_SHARE,
        contact_arm_time=observer.arm_time, reaction_time=safety.reaction_time)]
    for i in range(nb):
        out.append(ms.Body(index=i, parent=int(f["body_parent"][i]), dofnum=int(f["body_dofnum"][i]),
                           ball=int(f["body_ball"][i]), pos=tuple(f["body_pos"][i]), rot=tuple(f["body_rot"][i]),
                           mass=float(f["body_mass"][i]), com=tuple(f["body_com"][i]),
                           inertia=tuple(f["body_inertia"][i])))
    for k, s in enumerate(servo_table(config)):
        out.append(ms.Joint(
            index=k, bus=ms.BUSES[s["bus"]], id=s["id"], model_number=s["model_number"],
            dof_rot=tuple(f["dof_rot"][k]), armature=float(f["dof_armature"][k]), direction=s["direction"],
            zero_offset=s["zero_offset"], gear_ratio=s["gear_ratio"], rad_per_tick=s["rad_per_tick"],
            radps_per_unit=s["radps_per_unit"], effort_per_unit=s["amp_per_unit"], nm_per_effort=s["nm_per_amp"],
            effort_limit=s["current_limit"], q_min=s["q_min"], q_max=s["q_max"], qd_max=s["qd_max"], tau_max=0.0,
            friction_coulomb=s["friction_coulomb"], friction_viscous=s["friction_viscous"], kp=float(kp[k]),
            kd=float(kd[k]), error_lowpass=float(error_lowpass[k]), following_error=s["following_error"],
            observer_gain=s["observer_gain"], observer_lowpass=s["observer_lowpass"],
            contact_threshold=s["contact_threshold"], dialect=s["dialect"], reply_id=s["reply_id"],
            mit_range=s["mit_range"]))
    return out


@dataclass
class LinkPlan:
    """A configuration and a motion as the host link carries them, and the host's own plan of the
    same run (what the controller's commands are checked against)."""
    messages: list             # the load messages
    knots: list                # ms.Knot, the motion's, with gains
    home_ms: int               # COMMAND home's duration
    swing: object              # the motion sampled every control period (control.trajectory.Trajectory)
    swing_gains: GainSchedule  # the motion's gain schedule (the knots carry it)
    hold_gains: GainSchedule   # the joints' own gains (homing, holding), constant
    period: float              # s, the control period
    dof_names: tuple           # the joints, in the model's dof order

    def knot_messages(self, start: int, count: int) -> list:
        """KNOTS messages of knots start .. start + count - 1, as many in each as a frame holds."""
        ndof = len(self.knots[0].q)
        per = max(1, (ms.MAX_PAYLOAD - ms.SIZES[ms.KNOTS]) // ms.knot_bytes(ndof, True))
        out = []
        for first in range(start, start + count, per):
            items = self.knots[first:min(first + per, start + count)]
            out.append(ms.knots(first, items, last=first + len(items) == len(self.knots)))
        return out


def knot_times(path, scale: float, period: float) -> np.ndarray:
    """Where the motion's knots fall on the played clock (s): its breaks (keyframes, a CSV's rows),
    but no two closer than KNOT_SPACING where the quintic through the fewer breaks is the motion
    within KNOT_TOLERANCE (a CSV sampled densely streams a knot every few periods, not every one).
    InputError for a motion with no breaks (one sampled by another law)."""
    if path.breaks is None or len(path.breaks) < 2:
        raise InputError(f"host link: '{path.name}' is no keyframed or sampled motion: the controller plays "
                         "quintic pieces between knots")
    breaks = np.asarray(path.breaks, dtype=float)
    step = int(max(1, np.floor(KNOT_SPACING / max(np.min(np.diff(breaks)) * scale, period))))
    check = np.arange(0.0, path.duration, period / scale)
    q_file = path.evaluate(check)[0]
    while step > 1:
        kept = np.unique(np.r_[breaks[::step], breaks[-1]])
        q, qd, qdd = path.evaluate(kept)
        thinned = MotionPath.of_trajectory(path.name, Trajectory(t=kept, q=q, qd=qd, qdd=qdd, derived=False))
        if np.max(np.abs(thinned.evaluate(check)[0] - q_file), initial=0.0) <= KNOT_TOLERANCE:
            return kept * scale
        step //= 2
    return breaks * scale


def plan(config, motion_name: str = DEFAULT_MOTION, host_timeout_ms: int = HOST_TIMEOUT_MS,
         time_scale: float | None = None) -> LinkPlan:
    """The load messages of `config` and the knots of `motion_name` (a built-in motion, a keyframe
    file or a trajectory CSV) on its played clock, `time_scale` times slower than written (None:
    the configuration's). `swing` is what the controller plays: the quintic through the knots."""
    model, period = config.model, config.control_period
    scale = config.time_scale_for(motion_name) if time_scale is None else time_scale
    path = motion_path(motion_name, model)
    end = path.duration * scale
    _, swing_gains = plan_gains(model, path.at_scale(scale, period), joint_sensors(config))
    breaks = knot_times(path, scale, period)
    gain_knots = swing_gains.t[swing_gains.t < end]
    # a gain knot within MIN_KNOT_GAP of a break goes (the gains are linear between the knots that
    # stay): the quintic of a short segment in single precision amplifies the knots' rounding by
    # 1/h^2 (a 1 ms segment, 2 rad rounded to 2.4e-7: 3 rad/s^2 of acceleration, a servo unit or more)
    near = np.abs(gain_knots[:, None] - breaks[None, :]).min(axis=1) < MIN_KNOT_GAP if len(gain_knots) else []
    times = np.union1d(breaks, gain_knots[~np.asarray(near, dtype=bool)] if len(gain_knots) else gain_knots)
    t_us = np.unique(np.round(times * 1e6).astype(np.int64))
    t = t_us * 1e-6
    q, qd, qdd = path.evaluate(np.minimum(t / scale, path.duration))
    qd, qdd = qd / scale, qdd / scale**2
    swing = MotionPath.of_trajectory(path.name, Trajectory(t=t, q=q, qd=qd, qdd=qdd, derived=False)).at_scale(
        1.0, period)
    kp, kd = (np.array(g) for g in zip(*(swing_gains.at(tk) for tk in t)))
    knots = [ms.Knot(t_us=int(t_us[k]), q=tuple(q[k]), qd=tuple(qd[k]), qdd=tuple(qdd[k]), kp=tuple(kp[k]),
                     kd=tuple(kd[k])) for k in range(len(t))]
    lowpass = swing_gains.error_lowpass if swing_gains.error_lowpass is not None else np.zeros(model.nv)
    # the schedule the controller plays: the knots' gains, linear between them
    swing_gains = GainSchedule(t=t, kp=kp, kd=kd, error_lowpass=swing_gains.error_lowpass)
    kp0, kd0 = swing_gains.at(0.0)        # the joints' own: the gains at the motion's start, where it holds
    hold = GainSchedule(t=np.array([0.0, 1.0]), kp=np.array([kp0, kp0]), kd=np.array([kd0, kd0]),
                        error_lowpass=lowpass)
    return LinkPlan(messages=robot_messages(config, kp0, kd0, lowpass, host_timeout_ms), knots=knots,
                    home_ms=round(HOME_DURATION * 1e3), swing=swing, swing_gains=swing_gains, hold_gains=hold,
                    period=period, dof_names=tuple(model.dof_names))
