"""The servo bus: one interface for every kind of servo chain, like python-can's BusABC.

    with make_bus(load_config("replica")) as bus:       # backend chosen by the bus's kind
        bus.enable_torque(True)
        state = bus.read_state()                         # one batched read: q, qd, current, tau
        bus.write(JointCommand.position(q_goal, kp=20.0, kd=0.5, tau_ff=tau))   # one batched write

A control tick is one read_state() and one write(). Everything at this interface is SI, in
the joints' sense and in the model's dof order; servo units live inside the backends (via
hal.units). The base class checks what every backend would otherwise repeat: the bus is
open, commands are well formed and clamped to the joint limits (counted per joint in
`limited`: *limiting*, not a fault), and measured positions are inside the limits. A backend
implements `_open`, `_close`, `_enable_torque`, `_read` and `_write`; `make_bus` finds it by
kind in BACKENDS and imports it only then.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields

import numpy as np

from .config import RobotConfig

BACKENDS = {   # kind -> "module:class", imported on first use
    "dynamixel": "servodyn.hal.dynamixel.backend:DynamixelBus",
    "can": "servodyn.hal.can.backend:CanBus",
    "loopback": "servodyn.hal.loopback:LoopbackBus",
}

# Dynamixel X Hardware Error Status (70) bits; after any of them only a REBOOT restores torque
DYNAMIXEL_HARDWARE_ERRORS = {0: "input voltage", 2: "overheating", 3: "motor encoder",
                             4: "electrical shock", 5: "overload"}


# ---------------------------------------------------------------------------- exceptions

class ServoError(Exception):
    """Base of every servo bus error."""


class ServoInitializationError(ServoError):
    """The bus or a servo could not be set up: no backend, port, servo or wrong model."""


class ServoOperationError(ServoError):
    """A bus operation failed: bus not open, corrupt reply, rejected instruction."""


class ServoTimeoutError(ServoError, TimeoutError):
    """A servo stopped answering."""

    def __init__(self, joint: str, servo_id: int, detail: str = ""):
        self.joint, self.servo_id = joint, servo_id
        super().__init__(f"joint '{joint}' (id {servo_id}) did not answer{': ' + detail if detail else ''}")


class ServoHardwareError(ServoError):
    """A servo reports hardware errors (its status bits, decoded into `faults`)."""

    def __init__(self, joint: str, servo_id: int, status: int, bit_names=DYNAMIXEL_HARDWARE_ERRORS):
        self.joint, self.servo_id, self.status = joint, servo_id, status
        self.faults = tuple(name for bit, name in sorted(bit_names.items()) if status >> bit & 1)
        super().__init__(f"joint '{joint}' (id {servo_id}) hardware error 0x{status:02x}: "
                         f"{', '.join(self.faults) or 'unknown bits'}")


class ServoLimitError(ServoError):
    """A measured joint position outside its limits: stop and go to a safe state."""

    def __init__(self, joint: str, value: float, limits: tuple[float, float], state=None):
        self.joint, self.value, self.limits, self.state = joint, value, limits, state
        super().__init__(f"joint '{joint}' at {value:.4g} rad, outside its limits "
                         f"[{limits[0]:.4g}, {limits[1]:.4g}]")


# ---------------------------------------------------------------------------- data

@dataclass(frozen=True)
class JointState:
    """What one read returns, per joint of the bus (SI, joint sense)."""
    t: float                  # s: when it was read (backend clock)
    q: np.ndarray             # rad
    qd: np.ndarray            # rad/s
    current: np.ndarray       # A: motor current, positive = positive joint torque
    tau: np.ndarray           # N m: joint torque of that current


@dataclass(frozen=True)
class JointCommand:
    """What one write sends, per joint: τ = tau_ff + kp (q - q_meas) + kd (qd - qd_meas).

    kp = kd = 0 is pure torque; a backend realises the law as its servos allow (a host PD in
    current mode, or the servo's own position loop)."""
    q: np.ndarray             # rad
    qd: np.ndarray            # rad/s
    tau_ff: np.ndarray        # N m
    kp: np.ndarray            # N m / rad, >= 0
    kd: np.ndarray            # N m s / rad, >= 0

    def __post_init__(self):
        arrays = np.broadcast_arrays(*(np.asarray(getattr(self, f.name), dtype=float) for f in fields(self)))
        if arrays[0].ndim != 1:
            raise ValueError("JointCommand: fields must be scalars or 1-d arrays, one value per joint")
        for f, a in zip(fields(self), arrays):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"JointCommand: '{f.name}' is not finite")
            object.__setattr__(self, f.name, a.copy())
        if np.any(self.kp < 0) or np.any(self.kd < 0):
            raise ValueError("JointCommand: gains kp and kd must be >= 0")

    @classmethod
    def position(cls, q, kp, kd, qd=0.0, tau_ff=0.0) -> "JointCommand":
        return cls(q=q, qd=qd, tau_ff=tau_ff, kp=kp, kd=kd)

    @classmethod
    def torque(cls, tau) -> "JointCommand":
        return cls(q=0.0 * np.asarray(tau, dtype=float), qd=0.0, tau_ff=tau, kp=0.0, kd=0.0)

    def torque_at(self, q, qd) -> np.ndarray:
        """The joint torque the command asks for at the measured q, qd."""
        return self.tau_ff + self.kp * (self.q - q) + self.kd * (self.qd - qd)


# ---------------------------------------------------------------------------- the bus

class ServoBus(ABC):
    """The joints of one bus of a robot configuration, in the model's dof order."""

    kind: str = ""

    def __init__(self, config: RobotConfig, bus: str | None = None, *, position_margin: float = 0.05):
        if bus is None:
            if len(config.buses) != 1:
                raise ServoInitializationError(f"'{config.name}' has buses {', '.join(config.buses)}: name one")
            bus = next(iter(config.buses))
        if bus not in config.buses:
            raise ServoInitializationError(f"'{config.name}' has no bus '{bus}'")
        self.config, self.bus = config, config.buses[bus]
        self.joints = config.joints_on(bus)
        self.dof_names = tuple(j.dof for j in self.joints)
        self.dof_index = np.array([config.model.dof_names.index(d) for d in self.dof_names])
        self.units = config.units(self.joints)
        self.lower = np.array([j.position_limits[0] for j in self.joints])
        self.upper = np.array([j.position_limits[1] for j in self.joints])
        self.velocity_limit = np.array([j.velocity_limit for j in self.joints])
        self.torque_limit = np.array([j.torque_limit for j in self.joints])
        self.position_margin = position_margin    # rad beyond a limit before read_state raises
        self.limited = np.zeros(len(self.joints), dtype=np.int64)   # clamped commands per joint
        self.is_open = False

    @property
    def n(self) -> int:
        return len(self.joints)

    def open(self) -> None:
        if not self.is_open:
            self._open()
            self.is_open = True

    def close(self) -> None:
        """Close the port; the servos keep their torque setting (disable it first if wanted)."""
        if self.is_open:
            self.is_open = False
            self._close()

    def __enter__(self) -> "ServoBus":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def enable_torque(self, on: bool) -> None:
        self._check_open()
        self._enable_torque(bool(on))

    def read_state(self) -> JointState:
        """One batched read of every joint; ServoLimitError if a joint is beyond its limits."""
        self._check_open()
        state = self._read()
        outside = (state.q < self.lower - self.position_margin) | (state.q > self.upper + self.position_margin)
        if np.any(outside):
            k = int(np.argmax(outside))
            raise ServoLimitError(self.dof_names[k], float(state.q[k]), (self.lower[k], self.upper[k]), state)
        return state

    def write(self, command: JointCommand) -> None:
        """One batched write; targets and feed-forward torques are clamped to the joint limits."""
        self._check_open()
        if command.q.shape != (self.n,):
            raise ValueError(f"JointCommand for {command.q.shape[0]} joints, bus '{self.bus.name}' has {self.n}")
        q = np.clip(command.q, self.lower, self.upper)
        qd = np.clip(command.qd, -self.velocity_limit, self.velocity_limit)
        tau_ff = np.clip(command.tau_ff, -self.torque_limit, self.torque_limit)
        self.limited += (q != command.q) | (qd != command.qd) | (tau_ff != command.tau_ff)
        self._write(JointCommand(q=q, qd=qd, tau_ff=tau_ff, kp=command.kp, kd=command.kd))

    def _check_open(self) -> None:
        if not self.is_open:
            raise ServoOperationError(f"bus '{self.bus.name}' is not open")

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"<{type(self).__name__} '{self.bus.name}' {self.bus.port} {self.n} joints, {state}>"

    # what a backend implements
    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    @abstractmethod
    def _enable_torque(self, on: bool) -> None: ...

    @abstractmethod
    def _read(self) -> JointState: ...

    @abstractmethod
    def _write(self, command: JointCommand) -> None: ...


def make_bus(config: RobotConfig, bus: str | None = None, kind: str | None = None, **options) -> ServoBus:
    """The backend for a bus of the configuration (not yet open). `kind` overrides the bus's own
    kind, e.g. "loopback" to run a controller without servos; `options` go to the backend."""
    if bus is None and len(config.buses) == 1:
        bus = next(iter(config.buses))
    if bus not in config.buses:
        raise ServoInitializationError(f"'{config.name}' has no bus {bus!r} (buses: {', '.join(config.buses)})")
    kind = kind or config.buses[bus].kind
    if kind not in BACKENDS:
        raise ServoInitializationError(f"no backend for bus kind {kind!r} (known: {', '.join(BACKENDS)})")
    module_name, class_name = BACKENDS[kind].split(":")
    try:
        backend = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as err:
        raise ServoInitializationError(f"bus kind {kind!r}: cannot load {BACKENDS[kind]} ({err})") from err
    return backend(config, bus, **options)
