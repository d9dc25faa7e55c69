"""The plant: the configured arm's physics, whatever wire its servos speak.

The arm moves by the C core's direct dynamics (Armstrong-Green + RK4 at small_time_step). Each
joint is driven by a `Drive` — a simulated servo or motor seen from its shaft: every step the
plant tells each drive where its horn is (`set_present`), asks it for the motor current to hold
over the step (`output_current`) and for the torque at the horn that current gives
(`output_torque`), then integrates the joint torques. A Dynamixel servo is one kind of drive; a
CAN motor model is another, and slots in without touching this file.

The horn of joint k turns by direction·gear·q + zero_offset (hal.config's JointConfig).

Each joint stops at the model's limits, its mechanical range: past one, a critically damped spring
of time constant STOP_TIME_CONSTANT on the joint's own inertia pushes it back (MuJoCo's soft
limits), so an arm left with torque off hangs on its stops as the real one does instead of folding
through them (the replicas' elbows sagged 0.05-0.1 rad past full extension in 5 s).

A joint may have friction of its own (`JointFriction`: a plant whose [sim] table gives it, see
hal/README.md): Coulomb, viscous and a static friction that falls to Coulomb's over a Stribeck
speed, a real step at zero speed. A step in an explicit integrator chatters or needs a tiny step;
so, as MuJoCo's frictionloss, it is a bounded force solved at the velocity level: each step, a
joint whose sliding friction would not reverse it within the step slides, F(q̇) against q̇; the
others are held with the force that brings them to rest by the step's end, each within ±F at its
speed (at rest the static friction): one linear solve on M⁻¹ for them all, and where a force
would exceed its bound the joint slips at it and the rest are solved again (an active set, at
most one solve per joint), held over the RK4 step
like the drives' currents. A joint at rest stays there exactly until the torque on it exceeds the
static friction, and no step can make friction push a joint forwards.

`external`, when set, is a torque from outside the arm at its joints, asked every step as
external(time, q, qd) -> (nv,): a hand turning limp joints on the bench (sim/console.py).
`wrenches`, when set, are forces from outside on the arm's bodies, asked every step as
wrenches(time, q, qd) -> f_ext (nbody × 6: torque about the body's origin, force; the body's user
frame; or None: none) and handed to model.step with the step's torques (sim/contact.py: pushes and
obstacles, which log what they apply). While a wrench acts, the step is cut into
`wrenches.substeps(dt)` pieces, each with the wrench asked again (a stiff contact held over a whole
step would gain energy); the drives' currents and friction stay held over the whole step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

from servodyn.control.timing import SMALL_TIME_STEP

STOP_TIME_CONSTANT = 0.01     # s: a joint's stop as a spring-damper (natural frequency 100 rad/s:
                              # 0.1 rad a step at 1 ms, well inside RK4's stable range)


@dataclass
class JointFriction:
    """Friction at the joints (arrays over the dofs; a joint without any: all 0)."""
    coulomb: np.ndarray           # N m, sliding
    viscous: np.ndarray           # N m s/rad
    static: np.ndarray            # N m to break away from rest (>= coulomb)
    stribeck: np.ndarray          # rad/s over which static falls to Coulomb's
    _units: np.ndarray | None = None   # unit torques, one row per dof, and a row of none

    def bound(self, qd: np.ndarray) -> np.ndarray:
        """|friction| at speed q̇: F_c + (F_s − F_c)·exp(−(q̇/v_s)²) + F_v·|q̇|."""
        return self.coulomb + (self.static - self.coulomb) * np.exp(-(qd / self.stribeck) ** 2) + \
            self.viscous * np.abs(qd)

    def torque(self, model, q, qd, tau, dt: float, f_ext=None) -> np.ndarray:
        """The friction torque held over the next step of `dt` under the joint torques `tau` and
        the external wrenches `f_ext` (see the module's docstring)."""
        if not (np.isfinite(q).all() and np.isfinite(qd).all() and np.isfinite(tau).all()):
            return np.zeros_like(qd)
        # one batched call: the free acceleration, and M⁻¹ column by column (a unit torque's)
        n = len(qd)
        if self._units is None or len(self._units) != n + 1:
            self._units = np.vstack([np.eye(n), np.zeros(n)])
        rows = model.forward_dynamics(np.tile(q, (n + 1, 1)), np.tile(qd, (n + 1, 1)), tau + self._units,
                                      None if f_ext is None else np.broadcast_to(f_ext, (n + 1, *np.shape(f_ext))))
        free, inverse = rows[n], (rows[:n] - rows[n]).T
        bound = self.bound(qd)
        friction = -np.sign(qd) * bound                  # sliding, against the motion
        diagonal = np.diag(inverse)
        after = qd + dt * (free + diagonal * friction)   # each alone: does sliding stop it this step?
        held = [k for k in range(n) if bound[k] > 0 and (qd[k] == 0 or after[k] * qd[k] <= 0)]
        if not held:
            return friction
        # the held joints at rest by the step's end, each within its friction: solve them all;
        # the one whose force would exceed its bound most slips at its bound, the rest again
        friction[held] = 0.0
        acceleration = free + inverse @ friction
        while held:
            wanted = -np.linalg.solve(inverse[np.ix_(held, held)], qd[held] / dt + acceleration[held])
            excess = np.abs(wanted) / bound[held]
            if excess.max() <= 1.0:
                friction[held] = wanted
                break
            worst = int(np.argmax(excess))
            k = held.pop(worst)
            friction[k] = math.copysign(bound[k], wanted[worst])
            acceleration += inverse[:, k] * friction[k]
        return friction


class Drive(Protocol):
    """What the plant needs of an actuator, in SI at its horn."""

    def set_present(self, position: float, velocity: float, current: float) -> None: ...

    def output_current(self, position: float, velocity: float, dt: float) -> float: ...

    def output_torque(self, current: float, velocity: float) -> float: ...


class Chain(Protocol):
    """Every drive of the plant at once, in its order, on float64 arrays (the drives one by one,
    `Drives`, unless a chain of drives does it faster together)."""

    def output(self, position, velocity, dt: float, current, torque) -> None:
        """Each drive's current for the next `dt` into `current`, its horn torque into `torque`."""

    def publish(self, position, velocity, current) -> None:
        """Each drive's set_present."""


class Drives:
    """The drives one by one: the plant's chain when none is given."""

    def __init__(self, drives: Sequence[Drive]):
        self.drives = drives

    def output(self, position, velocity, dt: float, current, torque) -> None:
        for k, (drive, p, v) in enumerate(zip(self.drives, position.tolist(), velocity.tolist())):
            current[k] = amps = float(drive.output_current(p, v, dt))
            torque[k] = drive.output_torque(amps, v)

    def publish(self, position, velocity, current) -> None:
        for drive, p, v, i in zip(self.drives, position.tolist(), velocity.tolist(), current.tolist()):
            drive.set_present(p, v, i)


class Plant:
    """A model driven through its joints' drives; q and qd in the model's dof order. `chain`: the
    drives as one (Chain), by default each in turn."""

    def __init__(self, model, joints: Sequence, drives: Sequence[Drive], *,
                 small_time_step: float = SMALL_TIME_STEP, q0=None, integrator: str = "rk4",
                 chain: Chain | None = None, friction: JointFriction | None = None):
        if [j.dof for j in joints] != list(model.dof_names) or len(drives) != len(joints):
            raise ValueError("Plant: one joint and one drive per dof of the model, in its dof order")
        self.model, self.drives = model, list(drives)
        self.chain = Drives(self.drives) if chain is None else chain
        self.small_time_step, self.integrator = small_time_step, integrator
        self.direction = np.array([j.direction for j in joints], dtype=float)
        self.gear_ratio = np.array([j.gear_ratio for j in joints], dtype=float)
        self.zero_offset = np.array([j.zero_offset for j in joints], dtype=float)
        self._scale = self.direction * self.gear_ratio
        self.q = model.neutral_q() if q0 is None else np.array(q0, dtype=float)
        self.qd = np.zeros(model.nv)
        self.current = np.zeros(model.nv)          # A at each drive, over the last step
        self.charge_squared = np.zeros(model.nv)   # A² s: ∫I² dt at each drive since take_heat()
        self.friction = friction                   # at the joints, besides the drives' own
        self.time = 0.0
        # the stops: the model's limits, each dof's inertia where the arm starts (the spring's time
        # constant is close to STOP_TIME_CONSTANT wherever the arm is); a stop can be broken (stops)
        self.lower, self.upper = np.array(model.lower, dtype=float), np.array(model.upper, dtype=float)
        self._stop_inertia = np.diag(model.mass_matrix(self.q)).copy()
        self.stops = np.ones(model.nv, dtype=bool)
        self.external = None                       # external(time, q, qd) -> joint torques, or None
        self.wrenches = None                       # wrenches(time, q, qd) -> f_ext or None (sim/contact.py)
        self.publish()

    def horn(self, q, qd) -> tuple[np.ndarray, np.ndarray]:
        """Each drive's horn angle and speed for the joint state."""
        scale = self._scale
        return scale * q + self.zero_offset, scale * qd

    def publish(self) -> None:
        """Tell every drive where its horn is."""
        position, velocity = self.horn(self.q, self.qd)
        self.chain.publish(position, velocity, self.current)

    def advance(self, duration: float) -> None:
        """Run for `duration` seconds in small_time_step steps; each drive is sampled once per
        step (its current held over it)."""
        steps = max(1, int(round(duration / self.small_time_step)))
        scale = self._scale
        horn_torque = np.empty(len(self.drives))
        for _ in range(steps):
            position, velocity = self.horn(self.q, self.qd)
            self.chain.output(position, velocity, self.small_time_step, self.current, horn_torque)
            self.charge_squared += self.current * self.current      # x small_time_step in take_heat
            tau = scale * horn_torque + self.stop_torque()
            if self.external is not None:
                tau = tau + self.external(self.time, self.q, self.qd)
            f_ext = self.wrenches(self.time, self.q, self.qd) if self.wrenches is not None else None
            if self.friction is not None:
                tau = tau + self.friction.torque(self.model, self.q, self.qd, tau, self.small_time_step, f_ext)
            if f_ext is None:
                self.q, self.qd = self.model.step(self.q, self.qd, tau, self.small_time_step, self.integrator)
            else:
                self._step_in_contact(tau, f_ext)
            self.time += self.small_time_step
            self.publish()

    def _step_in_contact(self, tau, f_ext) -> None:
        """One small step under external wrenches, in wrenches.substeps pieces (module docstring)."""
        pieces = self.wrenches.substeps(self.small_time_step) if hasattr(self.wrenches, "substeps") else 1
        dt = self.small_time_step / pieces
        for piece in range(pieces):
            if piece:
                f_ext = self.wrenches(self.time + piece * dt, self.q, self.qd)
            self.q, self.qd = self.model.step(self.q, self.qd, tau, dt, self.integrator, f_ext=f_ext)


    def take_heat(self) -> np.ndarray:
        """∫I² dt (A² s) at each drive since the last call: what heated its winding meanwhile."""
        taken, self.charge_squared = self.charge_squared, np.zeros_like(self.charge_squared)
        return taken * self.small_time_step

    def push(self, k: int, angle: float) -> None:
        """An external push puts joint k at `angle`, past its stop if need be: that stop gives from
        then on (a fault, sim/robot.py's "pushed")."""
        self.q[k] = angle
        self.stops[k] = False

    def stop_torque(self) -> np.ndarray:
        """The joints' stops at (q, qd): zero inside the limits; past one, the spring-damper's torque,
        which only ever pushes back (it never holds a joint that is leaving its stop)."""
        q, qd = self.q, self.qd
        lower, upper, angles = self.lower.tolist(), self.upper.tolist(), q.tolist()
        if all(low <= x <= high and -math.inf < x < math.inf for low, x, high in zip(lower, angles, upper)):
            return np.zeros_like(q)           # every finite joint inside its limits (past = 0, below)
        one_by_one = self._stops_one_by_one(lower, angles, upper)
        if one_by_one is not None:
            return one_by_one
        past = np.minimum(q - self.lower, 0.0) + np.maximum(q - self.upper, 0.0)
        if not past.any():
            return np.zeros_like(q)
        w = 1.0 / STOP_TIME_CONSTANT
        push = -self._stop_inertia * (w * w * past + 2.0 * w * qd)
        push = np.where(past > 0, np.minimum(push, 0.0), np.maximum(push, 0.0))    # back, never on
        return np.where((past != 0) & self.stops, push, 0.0)

    def _stops_one_by_one(self, lower: list, angles: list, upper: list) -> np.ndarray | None:
        """stop_torque's expressions joint by joint on floats, the same operations in the same
        order (a handful of joints: numpy's calls cost more than the arithmetic); None where they
        could differ from numpy's: a non-finite state, limits out of order, a push of exactly 0
        (whose sign numpy's minimum and maximum may set otherwise)."""
        w = 1.0 / STOP_TIME_CONSTANT
        out = []
        for x, v, low, high, inertia, stop in zip(angles, self.qd.tolist(), lower, upper,
                                                   self._stop_inertia.tolist(), self.stops.tolist()):
            if not (-math.inf < x < math.inf and -math.inf < v < math.inf and low <= high):
                return None
            if low <= x <= high or not stop:
                out.append(0.0)
                continue
            past = x - low if x < low else x - high       # min(x - low, 0) + max(x - high, 0)
            push = -inertia * (w * w * past + 2.0 * w * v)
            if push == 0.0 or push != push:
                return None
            out.append(min(push, 0.0) if past > 0 else max(push, 0.0))     # back, never on
        return np.array(out)


class PlantView:
    """The plant's clock and state, read through whatever holds a `plant` (a simulated arm or robot)."""

    plant: Plant

    @property
    def time(self) -> float:
        return self.plant.time

    @property
    def q(self):
        return self.plant.q

    @property
    def qd(self):
        return self.plant.qd
