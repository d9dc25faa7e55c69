"""Closed-form control (paper §3.2, Fig. 4): inverse dynamics every `time_step` produce the
torques that drive the direct dynamics every `small_time_step`. The step itself is the C core's
(`sd_control_step`, the same one the firmware runs); this module configures it and runs closed
loops against a simulated plant."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import _core, _core32
from ..errors import ExitCode, ServodynError
from ..model import INTEGRATORS
from .timing import BANDWIDTH, SMALL_TIME_STEP, TIME_STEP
from .trajectory import Trajectory

MODES = {
    "feedforward": _core.MODE_FEEDFORWARD,          # tau = RNEA(desired), held for time_step
    "feedforward_pd": _core.MODE_FEEDFORWARD_PD,    # the held feed-forward plus a joint PD
    "computed_torque": _core.MODE_COMPUTED_TORQUE,  # RNEA(measured, qdd_d + kp e + kd e'), held
    "pd": _core.MODE_PD,                            # the joint PD alone
}
DEFAULT_MODE = "feedforward_pd"
# rad/s: the speed over which the compensated Coulomb friction rises to its full value,
# F_c·tanh(q̇_d/FRICTION_SPEED) (firmware/core/control.c says why it is smoothed). Four velocity
# quanta of a Dynamixel (0.229 rpm = 0.024 rad/s each; a CAN motor's 12-bit speed field is as
# coarse): below it a measured speed is mostly quantisation, so friction identified there is not
# known either; a plan's reversal crosses it in a few ticks (0.1 rad/s at 5 rad/s² is 20 ms), so
# the command ramps by 2·F_c instead of stepping in one tick, and 97 % of F_c is on at 0.2 rad/s.
FRICTION_SPEED = 0.1


class ControlFault(ServodynError, ValueError):
    """The controller refused a step: a desired or measured state that is not finite (the
    core's fault, SD_STATUS_NONFINITE). A loop stops on it, torque off."""
    exit_code = ExitCode.NONFINITE


@dataclass
class ControlConfig:
    """What a user sets. Gains default from a bandwidth: for the PD modes kp = M_ii w², kd =
    2 zeta M_ii w with M_ii the joint's own inertia at the start pose; for computed torque
    kp = w², kd = 2 zeta w (the model supplies the inertia)."""
    mode: str = DEFAULT_MODE
    small_time_step: float = SMALL_TIME_STEP   # s: the control and plant period
    time_step: float = TIME_STEP      # s: inverse dynamics period, a multiple of small_time_step
    bandwidth: float = BANDWIDTH      # rad/s
    damping: float = 1.0
    kp: np.ndarray | None = None
    kd: np.ndarray | None = None
    tau_max: np.ndarray | float | None = None   # N m; None or 0: no limit
    friction_coulomb: np.ndarray | None = None  # N m per dof, compensated on q̇_d; None: none
    friction_viscous: np.ndarray | None = None  # N m s/rad per dof
    friction_speed: float = FRICTION_SPEED      # rad/s: the Coulomb term's smoothing

    @property
    def update_ticks(self) -> int:
        ratio = self.time_step / self.small_time_step
        ticks = int(round(ratio))
        if ticks < 1 or abs(ratio - ticks) > 1e-9 * ratio:
            raise ValueError(f"time_step ({self.time_step} s) must be a whole multiple of "
                             f"small_time_step ({self.small_time_step} s)")
        return ticks


@dataclass
class RunResult:
    """A closed-loop run: row k is tick k (time t[k]): the state the controller measured, the
    desired state, and the torque it commanded for that tick."""
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    q_d: np.ndarray
    qd_d: np.ndarray
    dof_names: tuple[str, ...]
    completed: bool                   # False when the plant diverged before the end
    nlimited: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def error(self) -> np.ndarray:
        return self.q_d - self.q

    def tracking_rms(self) -> np.ndarray:
        return np.sqrt(np.mean(self.error**2, axis=0))

    def tracking_max(self) -> np.ndarray:
        return np.abs(self.error).max(axis=0)


class Controller:
    """The C core's controller step with a configuration, for one model."""

    def __init__(self, model, config: ControlConfig | None = None, q_start=None,
                 precision: str = "double"):
        if config is None:
            config = ControlConfig()
        if config.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got '{config.mode}'")
        self.model = model
        self.config = config
        n = model.nv
        q_start = model.neutral_q() if q_start is None else np.asarray(q_start, dtype=float)
        w, zeta = config.bandwidth, config.damping
        if config.mode == "computed_torque":
            kp, kd = np.full(n, w * w), np.full(n, 2 * zeta * w)
        else:
            inertia = np.diag(model.mass_matrix(q_start))
            kp, kd = inertia * w * w, 2 * zeta * inertia * w
        self.kp = kp if config.kp is None else np.broadcast_to(np.asarray(config.kp, float), (n,)).copy()
        self.kd = kd if config.kd is None else np.broadcast_to(np.asarray(config.kd, float), (n,)).copy()
        limit = 0.0 if config.tau_max is None else config.tau_max
        self.tau_max = np.broadcast_to(np.asarray(limit, dtype=float), (n,)).copy()
        core = model._pick(precision)
        controller_type = _core32.Controller if precision == "float" else _core.Controller
        friction = {name: np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()
                    for name, value in (("friction_coulomb", config.friction_coulomb),
                                        ("friction_viscous", config.friction_viscous)) if value is not None}
        try:
            self._c = controller_type(core, MODES[config.mode], config.update_ticks, self.kp,
                                      self.kd, self.tau_max, friction_speed=config.friction_speed, **friction)
        except ValueError as err:
            raise ValueError(f"{err} (ball joints are for simulation only)" if any(
                b.ball for b in model.bodies) else str(err)) from None

    def reset(self) -> None:
        self._c.reset()

    def set_gains(self, kp, kd, error_lowpass=None) -> None:
        """New PD gains from the next step on (gain scheduling), and the one-pole low-pass of the
        errors they act on (per dof, 1 - exp(-w_c dt); 0: none; None: unchanged; see
        schedule.error_lowpass)."""
        n = self.model.nv
        self.kp = np.broadcast_to(np.asarray(kp, dtype=float), (n,)).copy()
        self.kd = np.broadcast_to(np.asarray(kd, dtype=float), (n,)).copy()
        if error_lowpass is None:
            self._c.set_gains(self.kp, self.kd)
        else:
            self._c.set_gains(self.kp, self.kd, np.broadcast_to(np.asarray(error_lowpass, dtype=float), (n,)).copy())

    def step(self, q_d, qd_d, qdd_d, q, qd) -> np.ndarray:
        """One small_time_step: the torques for the measured (q, qd) and the desired state."""
        try:
            return self._c.step(q_d, qd_d, qdd_d, q, qd)
        except ValueError as err:
            # the binding refuses a non-finite input as the core would (zero torque, a fault)
            if all(np.all(np.isfinite(np.asarray(v, dtype=float))) for v in (q_d, qd_d, qdd_d, q, qd)):
                raise
            raise ControlFault(f"the controller refused the step: {err}") from None

    @property
    def status(self) -> int:
        return self._c.status

    def run(self, plant, traj: Trajectory, q0=None, qd0=None, integrator: str = "rk4") -> RunResult:
        """Drive the plant (a Model) along the trajectory, one controller step and one plant
        step of small_time_step per sample, in C. The plant starts at the trajectory's first
        point unless q0, qd0 are given."""
        dt = self.config.small_time_step
        if len(traj.t) > 1 and not np.allclose(np.diff(traj.t), dt, rtol=1e-6, atol=1e-12):
            raise ValueError(f"the trajectory must be sampled every small_time_step ({dt} s)")
        q0 = traj.q[0] if q0 is None else np.asarray(q0, dtype=float)
        qd0 = traj.qd[0] if qd0 is None else np.asarray(qd0, dtype=float)
        self._c.reset()
        q, qd, tau, ticks = self._c.simulate(plant.core, traj.q, traj.qd, traj.qdd, q0, qd0, dt,
                                             INTEGRATORS[integrator])
        n = ticks
        return RunResult(t=traj.t[:n], q=q[:n], qd=qd[:n], tau=tau[:n], q_d=traj.q[:n],
                         qd_d=traj.qd[:n], dof_names=self.model.dof_names,
                         completed=n == len(traj.t), nlimited=self._c.nlimited)
