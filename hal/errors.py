"""Every error the HAL raises, in one tree (as python-can's CanError), a branch of servodyn's
(servodyn.errors), each with the exit status a run stopped by it ends with:

    HalError
    ├── ConfigError              a robot configuration that cannot be used (also a ValueError)
    ├── ProtocolError            bytes that break a wire protocol (a codec's errors derive from it)
    └── ServoError               a bus or a servo failed at run time
        ├── ServoInitializationError   no backend, port, servo, or the wrong model      (2)
        ├── ServoOperationError        bus not open, corrupt reply, rejected instruction (12)
        ├── ServoTimeoutError          a servo stopped answering                        (10)
        ├── BusStallError              no servo answered: the bus (or the port) stalled (10)
        ├── ServoHardwareError         a servo reports a fault of its own               (11)
        └── ServoLimitError            a joint measured outside its limits              (15)
"""

from __future__ import annotations

from ..errors import ExitCode, ServodynError


class HalError(ServodynError):
    """Root of every HAL error."""


class ConfigError(HalError, ValueError):
    """A robot configuration that cannot be used; the message names the file, entry and key."""


class ProtocolError(HalError):
    """Bytes or values that a wire protocol's codec refuses."""


class ServoError(HalError):
    """Base of every servo bus error."""


class ServoInitializationError(ServoError):
    """The bus or a servo could not be set up: no backend, port, servo or wrong model."""


class ServoOperationError(ServoError):
    """A bus operation failed: bus not open, corrupt reply, rejected instruction."""
    exit_code = ExitCode.CORRUPT


class ServoTimeoutError(ServoError, TimeoutError):
    """A servo stopped answering."""
    exit_code = ExitCode.TIMEOUT

    def __init__(self, joint: str, servo_id: int, detail: str = ""):
        self.joint, self.servo_id = joint, servo_id
        super().__init__(f"joint '{joint}' (id {servo_id}) did not answer{': ' + detail if detail else ''}")


class BusStallError(ServoError, TimeoutError):
    """The whole bus went quiet: no servo answered for a while, so none of them is to blame."""
    exit_code = ExitCode.TIMEOUT

    def __init__(self, bus: str, detail: str = ""):
        self.bus = bus
        super().__init__(f"bus '{bus}' stalled: no servo answered{': ' + detail if detail else ''}")


class ServoHardwareError(ServoError):
    """A servo reports hardware errors: its status bits, and their names (the backend's table)."""
    exit_code = ExitCode.STATUS

    def __init__(self, joint: str, servo_id: int, status: int, faults: tuple[str, ...]):
        self.joint, self.servo_id, self.status, self.faults = joint, servo_id, status, tuple(faults)
        super().__init__(f"joint '{joint}' (id {servo_id}) hardware error 0x{status:02x}: "
                         f"{', '.join(self.faults) or 'unknown bits'}")


class ServoLimitError(ServoError):
    """A measured joint position outside its limits: stop and go to a safe state."""
    exit_code = ExitCode.RANGE

    def __init__(self, joint: str, value: float, limits: tuple[float, float], state=None):
        self.joint, self.value, self.limits, self.state = joint, value, limits, state
        super().__init__(f"joint '{joint}' at {value:.4g} rad, outside its limits "
                         f"[{limits[0]:.4g}, {limits[1]:.4g}]")
