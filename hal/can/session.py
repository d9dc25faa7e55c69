"""The CAN bus's bring-up (hal.bringup.BringUp): what `servodyn scan`, `setup`, `doctor`, `monitor`,
`calibrate`, `reboot`, `clear-errors` and `torque off` do on a CAN bus of Damiao motors, over the
operations of hal.can.bringup on python-can's bus, opened on the channel's interface (can0:
SocketCAN, a /dev path: an SLCAN adapter) at the configured bit rate. Found by name: `Can.bringup`.

    with CanBringUp(config, "arm", "/dev/ttyACM0") as session:
        findings = session.doctor()
"""

from __future__ import annotations

import math
import time

from ..bringup import BadRequest, BringUp, MonitorRow, Outcome, Scan
from . import bringup as can_bench
from .dialects import CTRL_MODES, DAMIAO_DISABLED, DAMIAO_ENABLED, DAMIAO_STATUS, FLASH_CYCLES
from ..ports import PTY_REPLY_TIMEOUT, is_pseudo_terminal
from .link import open_bus
from .spec import BITRATES, MAX_ID, SOCKETCAN_NAME, Can, interface_for


SIMULATED_LISTEN = 0.5     # s of quiet that end a scan of a simulated bus (a real one's: bringup.SCAN_LISTEN)


def _state(reply) -> str:
    if reply is None:
        return "did not answer"
    return f"{DAMIAO_STATUS.get(reply.status, f'status 0x{reply.status:X}')}, at {math.degrees(reply.p):.1f}°"


class CanBringUp(BringUp):
    device = "motor"

    def __init__(self, config, bus, path):
        """Without a configuration (a scan of a bare channel): the channel's interface, the CAN
        backend's default bit rate."""
        super().__init__(config, bus, path)
        spec = config.buses[bus] if config is not None else None
        self.interface = interface_for(path, spec.options.get("interface") if spec else None)
        self.bitrate = spec.baud if spec else Can.default_baud
        self.can = None
        # a simulated bus (`servodyn sim`, a pseudo-terminal) under load answers far later than a
        # motor's millisecond (hal.ports says how late): its patience, and a scan's quiet, longer
        simulated = is_pseudo_terminal(path)
        self.wait = {"timeout": PTY_REPLY_TIMEOUT["can"]} if simulated else {}
        self.quiet = {**self.wait, "listen": SIMULATED_LISTEN} if simulated else {}

    @classmethod
    def claims(cls, path: str) -> bool:
        """A SocketCAN link's name (can0, vcan0); an SLCAN adapter's tty needs a configuration."""
        return bool(SOCKETCAN_NAME.match(path))

    @classmethod
    def scan_rates(cls, text, spec=None) -> tuple[int, ...]:
        """A CAN bus is scanned at its own bit rate: "all" means it; another rate is refused."""
        bitrate = spec.baud if spec is not None else Can.default_baud
        if text in (None, "all") or text.strip() == str(bitrate):
            return (bitrate,)
        raise BadRequest(f"--baud: a CAN bus is scanned at its bit rate ({bitrate} bit/s; the rates a CAN bus "
                         f"takes: {', '.join(map(str, BITRATES))}): set `bitrate` in the configuration")

    def _open(self) -> None:
        self.can = open_bus(self.path, self.interface, self.bitrate)

    def _close(self) -> None:
        if self.can is not None:
            self.can.shutdown()
            self.can = None

    # --- scan
    def scanning(self, rates) -> str:
        return (f"scanning {self.path} ({self.interface}, {self.bitrate} bit/s), CAN IDs 1-{MAX_ID} "
                "(register reads: no torque) ...")

    def _scan(self, rates) -> Scan:
        heard: list[str] = []
        started = time.monotonic()
        found = can_bench.scan(self.can, bitrate=self.bitrate, heard=heard, **self.quiet)
        lines = []
        if found:
            lines.append(f"  {'CAN ID':>6}  {'model':<10} {'master':>6} {'mode':<18} status")
            for f in found:
                x = f.extra
                master = '0x%X' % x['master_id'] if x.get('master_id') is not None else '?'
                lines.append(f"  {f.id:>6}  {f.model or '?':<10} {master:>6} "
                             f"{CTRL_MODES.get(x.get('ctrl_mode'), str(x.get('ctrl_mode'))):<18} {x.get('status', '?')}")
        lines += [f"  {line}" for line in heard]
        lines.append(f"{len(found)} motor{'s' * (len(found) != 1)} in {time.monotonic() - started:.2f} s")
        return Scan(found, lines)

    def _compare(self, scan: Scan):
        return can_bench.compare(self.config, self.bus, scan.found)

    # --- setup
    def looking(self) -> str:
        return f"looking for the one motor on {self.path} (every CAN ID) ..."

    def _find_alone(self, joint):
        motor = can_bench.find_alone(self.can, joint, **self.quiet)
        return motor, can_bench.describe(motor)

    def _setup_plan(self, found, joint):
        return can_bench.setup_plan(self.can, found, joint, **self.wait)

    def setup_intro(self, joint) -> str:
        return (f"setup writes to this motor, disabled, and saves it to its flash (which lasts about "
                f"{FLASH_CYCLES:,} saves) to make it joint '{joint.dof}':")

    def already(self, joint) -> str:
        return (f"it is already set up as joint '{joint.dof}' (CAN ID {joint.id}, Master ID "
                f"0x{joint.options['feedback_id']:X}): nothing to write (if an earlier setup was not saved, a power "
                "cycle will show it: run servodyn scan after one)")

    def _apply_setup(self, found, joint, steps, written):
        return can_bench.apply_setup(self.can, found, joint, steps, written, **self.wait)

    def setup_lost(self, steps, written) -> str:
        done = super().setup_lost(steps, written)
        return done + (" (in the motor's RAM, not saved: a power cycle undoes them)" if written else "")

    # --- doctor and recovery
    def _doctor(self):
        return can_bench.doctor(self.config, self.bus, self.can, **self.quiet)

    def _outcomes(self, states, good) -> list[Outcome]:
        return [Outcome(j, states.get(j.dof) is not None and good(states[j.dof]), _state(states.get(j.dof)))
                for j in self.joints]

    def _torque_off(self):
        states = can_bench.torque_off(self.can, self.joints, **self.wait)
        return (f"bus '{self.bus}': torque off, each motor out of motor mode",
                self._outcomes(states, lambda r: r.status != DAMIAO_ENABLED))

    def _reboot(self):
        return self._clear_errors()

    def _clear_errors(self):
        states = can_bench.clear_errors(self.can, self.joints, **self.wait)
        return (f"bus '{self.bus}': each motor's latched error cleared (a CAN motor has no reboot; an "
                "over-temperature stays until it has cooled)",
                self._outcomes(states, lambda r: r.status in (DAMIAO_DISABLED, DAMIAO_ENABLED)))

    # --- calibrate and monitor
    def _horn(self, joint) -> float:
        """The motor's reported position (its own zero kept: the configuration's zero_offset takes the pose)."""
        return can_bench.states(self.can, [joint], **self.wait)[joint.dof].p

    def _monitor(self):
        states = can_bench.states(self.can, self.joints, partial=True, **self.wait)
        rows = []
        for joint in self.joints:
            r = states.get(joint.dof)
            if r is None:
                rows.append(MonitorRow(joint.dof, joint.id))
                continue
            scale = joint.direction * joint.gear_ratio       # p = direction·gear·q + zero_offset (hal.can.backend)
            rows.append(MonitorRow(joint.dof, joint.id, q=(r.p - joint.zero_offset) / scale, qd=r.v / scale,
                                   raw=(f"{r.p:.4f} rad", f"{r.v:.3f}", f"{r.t:.3f}"), effort=f"{r.t * scale:6.3f} N·m",
                                   temperature=f"{r.temperature}/{r.temperature2}",
                                   error=DAMIAO_STATUS.get(r.status, f"0x{r.status:X}")))
        return rows
