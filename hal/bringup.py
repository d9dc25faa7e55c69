"""What bring-up finds, on every kind of bus: the devices a scan found (`Found`) and what a check
found wrong, each with its fix (`Finding`). The host's side (ports, permissions, the latency timer,
locks) is hal.ports; each backend's side is its `bench` module (hal.dynamixel.bringup, hal.can.bringup);
the commands that print them are servodyn.tools.bringup.

    Finding("firmware", found=44, expected=">= 45", joint="r_elbow_flexion", id=4,
            fix="update the firmware with Dynamixel Wizard 2.0 (Tools > Firmware Update)")
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

ERROR, WARNING = "error", "warning"


@dataclass(frozen=True)
class Finding:
    """One thing a check found wrong, in one line with its fix. `severity` "error": a run refuses to
    start on it (doctor exits 1); "warning": it runs, but the user should know."""
    check: str                    # short name: "permission", "latency timer", "firmware", "drive mode", ...
    found: Any
    expected: Any
    fix: str                      # what to do, as exact as a command line where there is one
    joint: str | None = None      # the configuration's dof, when the finding is a joint's
    id: int | None = None         # the servo's or motor's id on its bus
    bus: str | None = None        # the configuration's bus name, or the port
    severity: str = ERROR

    def line(self) -> str:
        """One line: where, what was found against what is expected, and the fix."""
        where = []
        if self.bus:
            where.append(f"bus '{self.bus}'")
        if self.joint:
            where.append(f"joint '{self.joint}'")
        if self.id is not None:
            where.append(f"id {self.id}")
        head = (" ".join(where) + ": ") if where else ""
        return f"{head}{self.check}: found {self.found}, expected {self.expected}; {self.fix}"

    def as_json(self) -> dict:
        """doctor --json's object: joint, id, check, found, expected, fix (and bus, severity)."""
        return {k: (v if isinstance(v, (int, float, str, bool, type(None))) else str(v))
                for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Found:
    """One device a scan found: its id on the bus, model, firmware and the rate it answered at.
    `extra`: what the kind adds (a Damiao motor's Master ID, a CAN motor's status)."""
    id: int
    model_number: int | None
    model: str | None             # the catalogue's name, or None when the number is not in it
    firmware: int | None
    baud: int                     # the rate it answered at (serial baud or CAN bit rate)
    kind: str = "dynamixel"
    extra: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        """scan --json's object: id, model_number, model, firmware, baud (and kind, extra)."""
        return {"id": self.id, "model_number": self.model_number, "model": self.model,
                "firmware": self.firmware, "baud": self.baud, "kind": self.kind, **self.extra}
