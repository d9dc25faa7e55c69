"""The Feetech STS bus's bring-up (hal.bringup.BringUp): what `servodyn scan`, `setup`, `doctor`,
`monitor`, `calibrate`, `reboot`, `clear-errors` and `torque off` do on a Feetech bus, over the
operations of hal.feetech.bringup on a `Link`. Found by name: `Feetech.bringup`.

    with FeetechBringUp(config, "arm", "/dev/ttyACM0") as session:
        findings = session.doctor()
"""

from __future__ import annotations

from ..bringup import BringUp, MonitorRow, Outcome, Scan, serial_rates
from ..errors import ServoError
from ..ports import PTY_REPLY_TIMEOUT, is_pseudo_terminal
from . import bringup as sts
from .link import Link
from .protocol import SCAN_MAX_ID, status_faults
from .table import BAUD_RATES, CURRENT_UNIT, DUTY_FULL, STEP, TICKS_PER_REV, VOLTAGE_UNIT

MONITOR_START = 40                  # Torque_Enable .. Present Current in one read
SCAN_PATIENCE = 0.05                # s a scan's listen waits longer on a simulated bus (of its 1 s patience)


class FeetechBringUp(BringUp):
    device = "servo"

    def __init__(self, config, bus, path):
        super().__init__(config, bus, path)
        self.baud = config.buses[bus].baud if config is not None else sts.FACTORY_BAUD
        self.link: Link | None = None
        self.patience = 0.0
        self._first: dict[str, int] = {}       # each joint's first horn reading (_horn)

    @classmethod
    def scan_rates(cls, text, spec=None) -> tuple[int, ...]:
        """"all" (every STS rate, 1 Mbps first) or a comma list of rates."""
        return serial_rates(text, sts.SCAN_RATES, BAUD_RATES, "Feetech STS")

    def _open(self) -> None:
        # a simulated bus (`servodyn sim`) under load answers far later than a servo (hal.ports)
        self.patience = PTY_REPLY_TIMEOUT["feetech"] if is_pseudo_terminal(self.path) else 0.0
        self.link = Link(self.path, self.baud, patience=self.patience)
        self.link.open()

    def _close(self) -> None:
        if self.link is not None:
            self.link.close()

    @property
    def _scan_patience(self) -> float:
        return min(self.patience, SCAN_PATIENCE)

    @property
    def _again(self) -> float | None:
        """A scan's second pass, on a simulated bus only (hal.feetech.bringup.scan)."""
        return self.patience if self.patience > SCAN_PATIENCE else None

    # --- scan
    def scanning(self, rates) -> str:
        return (f"scanning {self.path} at {', '.join(map(str, rates))} baud, IDs 0-{SCAN_MAX_ID} "
                "(STS broadcast ping) ...")

    def _scan(self, rates) -> Scan:
        result = sts.scan(self.link, rates, self._scan_patience, self._again)
        lines = []
        if result.found:
            lines.append(f"  {'ID':>3}  {'model':<14} {'number':>6} {'firmware':>8} {'baud':>8}")
            for f in sorted(result.found, key=lambda f: (f.baud, f.id)):
                number = f.model_number if f.model_number is not None else "?"
                lines.append(f"  {f.id:>3}  {f.model or '?':<14} {number:>6} {sts.firmware_text(f):>8} {f.baud:>8}")
        for baud, ids in sorted(result.collisions.items()):
            lines.append(f"  several servos answer at ID {', '.join(map(str, sorted(ids)))} at {baud} baud "
                         "(their replies collide): connect one at a time")
        lines.append(f"{len(result.found)} servo{'s' * (len(result.found) != 1)} in {result.seconds:.2f} s "
                     f"({result.transactions} instructions, {result.wire_bytes} bytes on the wire)")
        return Scan(result.found, lines, result)

    def _compare(self, scan: Scan):
        return sts.compare(self.config, self.bus, scan.result)

    # --- setup
    def looking(self) -> str:
        return f"looking for the one servo on {self.path} (every STS rate, every ID) ..."

    def _find_alone(self, joint):
        found = sts.find_alone(self.link, patience=self._scan_patience, again=self._again)
        return found, (f"found {found.model or found.model_number} at ID {found.id}, {found.baud} baud, "
                       f"firmware {sts.firmware_text(found)}")

    def _setup_plan(self, found, joint):
        return sts.setup_plan(self.link, found, joint, self.config.buses[joint.bus])

    def setup_intro(self, joint) -> str:
        return (f"setup writes to this servo's EEPROM, torque off and Lock(55) 0 (inverted: 0 stores), then "
                f"Lock 1 and a restart to read it back, to make it joint '{joint.dof}':")

    def already(self, joint) -> str:
        return (f"it is already set up as joint '{joint.dof}' (ID {joint.id}, "
                f"{self.config.buses[joint.bus].baud} baud): nothing to write")

    def _apply_setup(self, found, joint, steps, written):
        after = sts.apply_setup(self.link, found, steps, self.patience, written)
        return [f"done: joint '{joint.dof}' answers at ID {after.id}, {after.baud} baud ({after.model}), "
                "its EEPROM read back after a restart"]

    # --- doctor and recovery
    def _doctor(self):
        return sts.doctor(self.config, self.bus, self.link, self._scan_patience)

    def _ids(self) -> list[int]:
        return [j.id for j in self.joints]

    def _torque_off(self):
        state = sts.torque_off(self.link, self._ids())
        return (f"bus '{self.bus}' ({self.path}): torque off, every servo at {self.link.baud} baud (broadcast)",
                [Outcome(j, state[j.id] == 0, "torque off" if state[j.id] == 0 else
                         "did not answer: switch its power off" if state[j.id] is None else
                         "still on: switch its power off") for j in self.joints])

    def _status_outcomes(self, state: dict, none: str, clear: str, still: str) -> list[Outcome]:
        return [Outcome(j, state[j.id] == 0, none if state[j.id] is None else clear if state[j.id] == 0 else
                        f"status 0x{state[j.id]:02X} ({', '.join(status_faults(state[j.id])) or 'unknown bits'}) "
                        f"still set: {still}") for j in self.joints]

    def _reboot(self):
        state = sts.restart(self.link, self._ids(), self.patience)
        return (f"bus '{self.bus}' ({self.path}): each servo restarted (RESTART 0x08)",
                self._status_outcomes(state, "did not come back", "up, no error", "its cause is still there"))

    def _clear_errors(self):
        state = sts.clear_protection(self.link, self._ids())
        return (f"bus '{self.bus}' ({self.path}): torque off on each servo (an overload's protection ends when "
                "torque next goes on), status read", self._status_outcomes(
                    state, "did not answer", "no error", "`servodyn reboot` restarts the servo, which clears it"))

    # --- calibrate and monitor
    def _horn(self, joint) -> float:
        """Present Position (rad), unwrapped to within half a turn of the joint's first reading in
        this session: an uncalibrated servo's 0..4095 may wrap inside a joint's range, so a
        calibration starts each joint near the middle of its range (as LeRobot's does)."""
        ticks = self.link.read_item(joint.id, "present_position")
        first = self._first.setdefault(joint.dof, ticks)
        return (ticks + round((first - ticks) / TICKS_PER_REV) * TICKS_PER_REV) * STEP

    def _calibration(self, joint, values):
        return sts.calibration_plan(self.link, joint, values)

    def _apply_calibration(self, joint, steps) -> str:
        sts.apply_calibration(self.link, joint, steps, self.patience)
        return f"joint '{joint.dof}' (id {joint.id}): its EEPROM holds the calibration (read back after a restart)"

    def _monitor(self):
        rows = []
        for joint in self.joints:
            try:
                data, _ = self.link.read(joint.id, MONITOR_START, sts.TABLE_READ - MONITOR_START)
            except ServoError:
                rows.append(MonitorRow(joint.dof, joint.id))
                continue
            raw = sts.decode_table(data, MONITOR_START)
            ticks, speed, load = raw["present_position"], raw["present_velocity"], raw["present_load"]
            sense = joint.direction * joint.gear_ratio
            status = raw["status"]
            rows.append(MonitorRow(
                joint.dof, joint.id, q=(ticks * STEP - joint.zero_offset) / sense, qd=speed * STEP / sense,
                raw=(str(ticks), str(speed), str(load)),
                effort=f"{load / DUTY_FULL:6.1%} {raw['present_current'] * CURRENT_UNIT:5.2f} A",
                temperature=str(raw["present_temperature"]), voltage=f"{raw['present_voltage'] * VOLTAGE_UNIT:.1f}",
                error=", ".join(status_faults(status)) if status else "-"))
        return rows

