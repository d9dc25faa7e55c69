"""The servo bus: one interface for every kind of servo chain, like python-can's BusABC.

    with make_bus(load_config("replica")) as bus:       # backend chosen by the bus's kind
        bus.enable_torque(True)
        state = bus.read_state()                         # one batched read: q, qd, current, tau
        bus.write(JointCommand.position(q_goal, kp=20.0, kd=0.5, tau_ff=tau))   # one batched write
        bus.stop()                                       # torque off on every servo, never raises

A control tick is one read_state() and one write(). Everything at this interface is SI, in the
joints' sense and in the model's dof order; servo units, registers, data sheets and error bits
live inside the backends. The base class checks what every backend would otherwise repeat: the
bus is open, commands are well formed and clamped to the joint limits (counted per joint in
`stats.limited`: *limiting*, not a fault), and measured positions are inside the limits.

A backend implements `_open`, `_close`, `_enable_torque`, `_read` and `_write` (and `_stop` where
it can switch torque off faster than `_enable_torque(False)`); what it is (its catalogue of data
sheets, rates, ids, configuration keys, wire time) is described apart, in hal.backend, where
`make_bus` finds it by kind and imports it only then.
"""

from __future__ import annotations

import errno
import os
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING

import numpy as np

from .backend import backend
from .errors import ServoInitializationError, ServoLimitError, ServoOperationError

if TYPE_CHECKING:
    from .config import RobotConfig

# ---------------------------------------------------------------------------- data

@dataclass(frozen=True)
class JointState:
    """What one read returns, per joint of the bus (SI, joint sense)."""
    t: float                  # s: when it was read (backend clock)
    q: np.ndarray             # rad
    qd: np.ndarray            # rad/s
    current: np.ndarray       # A: motor current, positive = positive joint torque
    tau: np.ndarray           # N m: joint torque of that current
    # °C: each winding's temperature as its servo last reported it (read at a low rate, held between
    # reads; nan for a joint not read yet); None: the bus does not read temperatures
    temperature: np.ndarray | None = None


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
        """Checked once, cheaply: the five fields become rows of one new array (a copy), one
        finiteness test and one sign test of the gains."""
        names = _COMMAND_FIELDS
        values = [getattr(self, name) for name in names]
        sizes = {len(shape) and shape[0] if len(shape) < 2 else -1 for shape in map(np.shape, values)}
        joints = sizes - {0}
        if -1 in sizes or len(joints) != 1:
            raise ValueError("JointCommand: fields must be scalars or 1-d arrays of one length, one value per joint")
        rows = np.empty((len(names), joints.pop()))
        for row, value in zip(rows, values):
            row[...] = value
        if not np.isfinite(rows).all():
            bad = names[int(np.argmin(np.isfinite(rows).all(axis=1)))]
            raise ValueError(f"JointCommand: '{bad}' is not finite")
        if (rows[3:] < 0).any():
            raise ValueError("JointCommand: gains kp and kd must be >= 0")
        for name, row in zip(names, rows):
            object.__setattr__(self, name, row)

    @classmethod
    def _checked(cls, q, qd, tau_ff, kp, kd) -> "JointCommand":
        """A command from arrays that come from a checked one (the bus's clamped copy): not
        checked again."""
        command = object.__new__(cls)
        command.__dict__.update(q=q, qd=qd, tau_ff=tau_ff, kp=kp, kd=kd)    # frozen: past __setattr__
        return command

    @classmethod
    def position(cls, q, kp, kd, qd=0.0, tau_ff=0.0) -> "JointCommand":
        return cls(q=q, qd=qd, tau_ff=tau_ff, kp=kp, kd=kd)

    @classmethod
    def torque(cls, tau) -> "JointCommand":
        if type(tau) is not np.ndarray or tau.ndim != 1 or not tau.size:
            return cls(q=0.0, qd=0.0, tau_ff=tau, kp=0.0, kd=0.0)
        # the control loop's command every tick, checked as __post_init__ would, for less: the
        # zero rows need no check, so only the torques' finiteness is tested
        rows = np.zeros((len(_COMMAND_FIELDS), tau.shape[0]))
        rows[2] = tau
        if not np.isfinite(rows[2]).all():
            raise ValueError("JointCommand: 'tau_ff' is not finite")
        return cls._checked(*rows)

    def torque_at(self, q, qd) -> np.ndarray:
        """The joint torque the command asks for at the measured q, qd."""
        return self.tau_ff + self.kp * (self.q - q) + self.kd * (self.qd - qd)


_COMMAND_FIELDS = tuple(f.name for f in fields(JointCommand))


@dataclass
class BusStats:
    """What a bus counted since it was made; every loop reports it."""
    reads: int = 0                  # read_state() calls that returned a state
    writes: int = 0                 # write() calls that went out
    reads_retried: int = 0          # reads whose first try failed (no whole reply) and were retried
    limited: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # per joint:
                                    # commands clamped to a joint, velocity, torque or current limit

    def as_dict(self, dof_names) -> dict:
        return {"reads": self.reads, "writes": self.writes, "reads_retried": self.reads_retried,
                "limited": dict(zip(dof_names, map(int, self.limited)))}


# ---------------------------------------------------------------------------- the bus

BITS_PER_BYTE = 10        # a serial line's byte on the wire, 8N1: start, 8 data, stop

# what the OS says of a port that is gone (unplugged, or the simulator serving it ended)
_GONE = frozenset({errno.EIO, errno.ENXIO, errno.ENODEV, errno.EBADF})
try:
    import termios
    PORT_ERRORS = (OSError, termios.error)     # a serial port's calls raise either (termios: tcflush)
except ImportError:
    PORT_ERRORS = (OSError,)


def port_gone(err: BaseException) -> str | None:
    """Why the port itself is gone, if `err` (or the error it was raised from) says so: the OS's
    EIO, ENXIO, ENODEV or EBADF, or pyserial's "device disconnected"; None for what a port comes
    back from (a timeout, a controller's bus-off)."""
    for cause in (err, err.__cause__, err.__context__):
        if cause is None or type(cause).__name__ == "SerialTimeoutException":
            continue
        code = cause.errno if isinstance(cause, OSError) else cause.args[0] if \
            isinstance(cause, PORT_ERRORS) and cause.args else None
        if code in _GONE:
            return os.strerror(code)
        if type(cause).__name__ == "SerialException":       # pyserial's, its errno in its words
            return str(cause)
    return None


class ServoBus(ABC):
    """The joints of one bus of a robot configuration, in the model's dof order."""

    kind: str = ""                        # the kind of bus (hal.backend: its description)

    def __init__(self, config: "RobotConfig", bus: str | None = None, *, position_margin: float = 0.05):
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
        self.lower = np.array([j.position_limits[0] for j in self.joints])
        self.upper = np.array([j.position_limits[1] for j in self.joints])
        self.velocity_limit = np.array([j.velocity_limit for j in self.joints])
        self.torque_limit = np.array([j.torque_limit for j in self.joints])
        self.current_limit = np.array([j.current_limit for j in self.joints])
        # joint torque per motor current (N m / A): the gear and the torque constant
        self.torque_per_amp = np.array([j.gear_ratio * j.torque_constant for j in self.joints])
        self.position_margin = position_margin    # rad beyond a limit before read_state raises
        self.stats = BusStats(limited=np.zeros(len(self.joints), dtype=np.int64))
        self.is_open = False
        self.lost: str | None = None          # why the port is known to be gone: stop() is then brief

    @property
    def n(self) -> int:
        return len(self.joints)

    def open(self) -> None:
        if not self.is_open:
            self._open()
            self.is_open = True

    def close(self) -> None:
        """Close the port; the servos keep their torque setting (stop() switches it off first)."""
        if self.is_open:
            self.is_open = False
            self._close()

    def stop(self) -> bool:
        """The safe stop: torque off on every servo, best effort, then close. Never raises, whatever
        state the bus is in (python-can's shutdown()). True if every servo confirmed."""
        ok = False
        try:
            if self.is_open:
                ok = bool(self._stop())
        except Exception:
            ok = False
        try:
            self.close()
        except Exception:
            pass
        return ok

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
        self.stats.reads += 1
        outside = (state.q < self.lower - self.position_margin) | (state.q > self.upper + self.position_margin)
        if outside.any():
            k = int(np.argmax(outside))
            raise ServoLimitError(self.dof_names[k], float(state.q[k]), (self.lower[k], self.upper[k]), state)
        return state

    def write(self, command: JointCommand) -> None:
        """One batched write; targets and feed-forward torques are clamped to the joint limits."""
        self._check_open()
        if command.q.shape != (self.n,):
            raise ValueError(f"JointCommand for {command.q.shape[0]} joints, bus '{self.bus.name}' has {self.n}")
        # np.clip, without its wrappers (a command's values are finite)
        q = np.minimum(np.maximum(command.q, self.lower), self.upper)
        qd = np.minimum(np.maximum(command.qd, -self.velocity_limit), self.velocity_limit)
        tau_ff = np.minimum(np.maximum(command.tau_ff, -self.torque_limit), self.torque_limit)
        self.stats.limited += (q != command.q) | (qd != command.qd) | (tau_ff != command.tau_ff)
        self._write(JointCommand._checked(q, qd, tau_ff, command.kp, command.kd))
        self.stats.writes += 1

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

    def _stop(self) -> bool:
        """Torque off on every servo, as fast as the backend can; True if all confirmed."""
        self._enable_torque(False)
        return True


def make_bus(config: "RobotConfig", bus: str | None = None, kind: str | None = None, **options) -> ServoBus:
    """The backend for a bus of the configuration (not yet open). `kind` overrides the bus's own
    kind, e.g. "loopback" to run a controller without servos; `options` go to the backend."""
    if bus is None and len(config.buses) == 1:
        bus = next(iter(config.buses))
    if bus not in config.buses:
        raise ServoInitializationError(f"'{config.name}' has no bus {bus!r} (buses: {', '.join(config.buses)})")
    return backend(kind or config.buses[bus].kind).bus_class()(config, bus, **options)
