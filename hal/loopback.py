"""LoopbackBus: a servo bus with no protocol behind it, for testing control loops.

The configuration's model stands in for the arm. Each write() applies the command's torque
law at the present state, saturated at each joint's current limit (kt · gear · current
limit), and integrates the model over one control period `dt` with model.step; read_state()
returns that state. Time is simulated, so a test runs as fast as the machine allows and
gives the same result every time. With torque disabled the joints are limp (zero torque).
"""

from __future__ import annotations

import numpy as np

from ..control.timing import SMALL_TIME_STEP
from .bus import JointCommand, JointState, ServoBus
from .errors import ServoInitializationError


class LoopbackBus(ServoBus):
    kind = "loopback"

    def __init__(self, config, bus=None, *, dt: float = SMALL_TIME_STEP, q0=None, substeps: int = 1,
                 integrator: str = "rk4", port: str | None = None, **options):
        """port: ignored (a loopback bus has none), so a loopback configuration runs wherever a
        bus with a port does."""
        super().__init__(config, bus, **options)
        model = config.model
        if sorted(self.dof_index) != list(range(model.nv)) or model.nq != model.nv:
            raise ServoInitializationError(f"loopback bus '{self.bus.name}' must drive every dof of "
                                           f"'{model.name}', which must have one coordinate per dof")
        if not dt > 0 or substeps < 1:
            raise ServoInitializationError("loopback: dt must be positive and substeps >= 1")
        self.model, self.dt, self.substeps, self.integrator = model, dt, substeps, integrator
        self.q0 = np.zeros(model.nq) if q0 is None else np.asarray(q0, dtype=float).copy()

    def _open(self) -> None:
        self.t = 0.0
        self._q = np.zeros(self.model.nq)
        self._q[self.dof_index] = self.q0[self.dof_index]
        self._qd = np.zeros(self.model.nv)
        self._tau = np.zeros(self.model.nv)
        self._torque_on = False

    def _close(self) -> None:
        pass

    def _enable_torque(self, on: bool) -> None:
        self._torque_on = on

    def _read(self) -> JointState:
        k = self.dof_index
        tau = self._tau[k].copy()
        return JointState(t=self.t, q=self._q[k].copy(), qd=self._qd[k].copy(),
                          current=tau / self.torque_per_amp, tau=tau)

    def _write(self, command: JointCommand) -> None:
        k = self.dof_index
        tau = np.zeros(self.n)
        if self._torque_on:
            wanted = command.torque_at(self._q[k], self._qd[k])
            tau = np.clip(wanted, -self.torque_limit, self.torque_limit)
            self.stats.limited += tau != wanted      # the current limit: limiting too
        self._tau[k] = tau
        self._q, self._qd = self.model.step(self._q, self._qd, self._tau, self.dt / self.substeps,
                                            self.integrator, nsteps=self.substeps)
        self.t += self.dt
