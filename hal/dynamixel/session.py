"""The Dynamixel bus's bring-up (hal.bringup.BringUp): what `servodyn scan`, `setup`, `doctor`,
`monitor`, `calibrate`, `reboot`, `clear-errors` and `torque off` do on a Dynamixel bus, over the
operations of hal.dynamixel.bringup on a `Link`. Found by name: `Dynamixel.bringup`.

    with DynamixelBringUp(config, "arm", "/dev/ttyUSB0") as session:
        findings = session.doctor()
"""

from __future__ import annotations

from ..bringup import BadRequest, BringUp, MonitorRow, Outcome, Scan, serial_rates
from ..errors import ServoError
from ..ports import PTY_REPLY_TIMEOUT, is_pseudo_terminal
from . import bringup as dxl
from .control_table import BAUD_RATES, ITEMS, TABLE_SIZE
from .link import FACTORY_BAUD, Link
from .units import ServoMap

MONITOR_START = ITEMS["torque_enable"].address          # Torque Enable .. Present Temperature in one read


class DynamixelBringUp(BringUp):
    device = "servo"

    def __init__(self, config, bus, path):
        if config is not None and bus in config.buses and config.buses[bus].protocol == 1.0:
            raise BadRequest(f"bus '{bus}' has protocol = 1.0: servodyn's bring-up (scan, setup, doctor, calibrate, "
                             "monitor) speaks Protocol 2.0 only; set 1.0 servos up with ROBOTIS's own tools "
                             "(ID, baud rate), then `servodyn swing`")
        super().__init__(config, bus, path)
        self.baud = config.buses[bus].baud if config is not None else FACTORY_BAUD
        self.link: Link | None = None

    @classmethod
    def claims(cls, path: str) -> bool:
        """A device path (/dev/ttyUSB0, /dev/pts/3): a serial port, the Dynamixel bus's."""
        return path.startswith("/")

    @classmethod
    def scan_rates(cls, text, spec=None) -> tuple[int, ...]:
        """"all" (every rate, the factory's first, then the fastest) or a comma list of rates."""
        return serial_rates(text, dxl.SCAN_RATES, BAUD_RATES, "Dynamixel X")

    def _open(self) -> None:
        # a simulated bus (`servodyn sim`) under load answers far later than a servo (hal.ports)
        self.link = Link(self.path, self.baud,
                         patience=PTY_REPLY_TIMEOUT["dynamixel"] if is_pseudo_terminal(self.path) else 0.0)
        self.link.open()

    def _close(self) -> None:
        if self.link is not None:
            self.link.close()

    # --- scan
    def scanning(self, rates) -> str:
        return f"scanning {self.path} at {', '.join(map(str, rates))} baud, IDs 0-{dxl.MAX_ID} (broadcast ping) ..."

    def _scan(self, rates) -> Scan:
        result = dxl.scan(self.link, rates)
        lines = []
        if result.found:
            lines.append(f"  {'ID':>3}  {'model':<12} {'number':>6} {'firmware':>8} {'baud':>8}")
            for f in sorted(result.found, key=lambda f: (f.baud, f.id)):
                lines.append(f"  {f.id:>3}  {f.model or '?':<12} {f.model_number:>6} {f.firmware:>8} {f.baud:>8}")
        for baud, ids in sorted(result.collisions.items()):
            lines.append(f"  several servos answer at ID {', '.join(map(str, sorted(ids)))} at {baud} baud "
                         "(their replies collide): connect one at a time")
        lines.append(f"{len(result.found)} servo{'s' * (len(result.found) != 1)} in {result.seconds:.2f} s")
        return Scan(result.found, lines, result)

    def _compare(self, scan: Scan):
        return dxl.compare(self.config, self.bus, scan.result)

    # --- setup
    def looking(self) -> str:
        return f"looking for the one servo on {self.path} (every rate, every ID) ..."

    def _find_alone(self, joint):
        found = dxl.find_alone(self.link)
        return found, (f"found {found.model or found.model_number} at ID {found.id}, {found.baud} baud, "
                       f"firmware {found.firmware}")

    def _setup_plan(self, found, joint):
        return dxl.setup_plan(self.link, found, joint, self.config.buses[joint.bus])

    def setup_intro(self, joint) -> str:
        return f"setup writes to this servo's EEPROM, torque off, to make it joint '{joint.dof}':"

    def already(self, joint) -> str:
        return (f"it is already set up as joint '{joint.dof}' (ID {joint.id}, "
                f"{self.config.buses[joint.bus].baud} baud): nothing to write")

    def _apply_setup(self, found, joint, steps, written):
        after = dxl.apply_setup(self.link, found, steps, self.config.buses[joint.bus].baud, written)
        return [f"done: joint '{joint.dof}' answers at ID {after.id}, {after.baud} baud ({after.model})"]

    # --- doctor and recovery
    def _doctor(self):
        return dxl.doctor(self.config, self.bus, self.link)

    def _ids(self) -> list[int]:
        return [j.id for j in self.joints]

    def _torque_off(self):
        state = dxl.torque_off(self.link, self._ids())
        return (f"bus '{self.bus}' ({self.path}): torque off, every servo at {self.link.baud} baud (broadcast)",
                [Outcome(j, state[j.id] == 0, "torque off" if state[j.id] == 0 else
                         "did not answer: switch its power off" if state[j.id] is None else
                         "still on: switch its power off") for j in self.joints])

    def _reboot(self):
        state = dxl.reboot(self.link, self._ids())
        outcomes = []
        for joint in self.joints:
            value = state[joint.id]
            outcomes.append(Outcome(joint, value == 0, "did not come back" if value is None else
                                    "up, no hardware error" if value == 0 else
                                    f"up, hardware error 0x{value:02X} still set "
                                    f"({', '.join(dxl.hardware_faults(value))}): its cause is still there"))
        return f"bus '{self.bus}' ({self.path}): each servo rebooted", outcomes

    def _clear_errors(self):
        state = dxl.clear_watchdog(self.link, self._ids())
        outcomes = []
        for joint in self.joints:
            try:
                status = self.link.read(joint.id, "hardware_error_status")
            except ServoError:
                status = None
            if state[joint.id] is None or status is None:
                outcomes.append(Outcome(joint, False, "did not answer"))
            elif status:
                outcomes.append(Outcome(joint, False, f"bus watchdog clear; hardware error 0x{status:02X} "
                                        f"({', '.join(dxl.hardware_faults(status))}) latched: only "
                                        "`servodyn reboot` (or a power cycle) clears it"))
            else:
                outcomes.append(Outcome(joint, True, "no error"))
        return f"bus '{self.bus}' ({self.path}): a tripped Bus Watchdog written 0, hardware errors read", outcomes

    # --- calibrate and monitor
    def _horn(self, joint) -> float:
        return dxl.horn_angles(self.link, [joint.id])[joint.id]

    def _monitor(self):
        rows = []
        for joint in self.joints:
            units = ServoMap.from_joints([joint])
            try:
                raw = dxl.decode_table(self.link.read_table(joint.id, MONITOR_START, TABLE_SIZE - MONITOR_START),
                                       MONITOR_START)
            except ServoError:
                rows.append(MonitorRow(joint.dof, joint.id))
                continue
            ticks, vel, cur = raw["present_position"], raw["present_velocity"], raw["present_current"]
            status = raw["hardware_error_status"]
            rows.append(MonitorRow(
                joint.dof, joint.id, q=float(units.from_ticks(ticks)[0]), qd=float(units.from_velocity_units(vel)[0]),
                raw=(str(ticks), str(vel), str(cur)), effort=f"{float(units.current_from_units(cur)[0]):6.3f} A",
                temperature=str(raw["present_temperature"]), voltage=f"{raw['present_input_voltage'] / 10:.1f}",
                error=", ".join(dxl.hardware_faults(status)) if status else "-"))
        return rows
