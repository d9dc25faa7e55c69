"""Dynamixel bring-up on a bench: find servos at any ID and baud rate, set one up for its joint,
check every servo of a configuration, reboot, clear a tripped watchdog, switch torque off. Each
goes over a `Link` (hal.dynamixel.link: the serial port and servodyn's Protocol 2.0 codec); the
commands reach them through `DynamixelBringUp` (hal.dynamixel.session), the bus kind's bring-up.

    with Link("/dev/ttyUSB0", 57600) as link:
        result = scan(link, BAUD_RATES)            # every servo at every rate
        findings = compare(config, "arm", result)  # what differs from the configuration

The checks a run depends on (`table_findings`) are one function, used by `doctor` and at every
open of the bus (hal.dynamixel.backend), so what doctor passes a run accepts.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

from ..bringup import WARNING, Finding, Found
from ..errors import ServoInitializationError, ServoOperationError
from .control_table import BAUD_RATES, ITEMS, MODELS, PWM_FULL, TABLE_SIZE, TICKS_PER_REV, hardware_faults
from .link import FACTORY_BAUD, FACTORY_ID, Link
from . import instructions
from .protocol import BROADCAST_ID, MAX_ID, StatusPacket, unpack_field
from .pwm import pwm_driven
from .units import current_unit

MIN_FIRMWARE = 45          # fast sync read (0x8A), which every tick uses, needs X430/540 firmware 45
VOLTAGE_TOLERANCE = 0.10   # Present Input Voltage within ±10 % of the supply's
SCAN_RATES = tuple(sorted(BAUD_RATES, key=lambda b: (b != FACTORY_BAUD, -b)))   # factory's first, then fastest


# ---------------------------------------------------------------------------- scan

@dataclass
class ScanResult:
    """What a scan found: the servos, and the rates at which replies collided (several servos at
    one ID), with the IDs readable in the corrupt bytes."""
    found: list[Found] = field(default_factory=list)
    collisions: dict[int, set[int]] = field(default_factory=dict)     # baud -> IDs answering at once
    corrupt: list[int] = field(default_factory=list)                  # bauds with unreadable replies
    rates: tuple[int, ...] = ()
    seconds: float = 0.0


def _found(packet: StatusPacket, baud: int) -> Found:
    number = unpack_field(packet.params[:2]) if len(packet.params) >= 2 else None
    model = MODELS.get(number)
    firmware = packet.params[2] if len(packet.params) >= 3 else None
    return Found(id=packet.id, model_number=number, model=model.name if model else None, firmware=firmware,
                 baud=baud)


def scan(link: Link, rates: Iterable[int] = SCAN_RATES, progress: Callable[[int, int], None] | None = None) -> ScanResult:
    """A broadcast ping at each rate (the whole ID range answers it), the replies collected until
    the line is quiet. A corrupt reply whose ID is readable is pinged alone: corrupt again, it is
    several servos at that ID."""
    started = time.monotonic()
    result = ScanResult(rates=tuple(rates))
    for baud in result.rates:
        link.set_baud(baud)
        packets, bad = link.exchange(instructions.ping(BROADCAST_ID), expect=None)
        seen = {p.id for p in packets}
        for packet in packets:
            if len(packet.params) == 3 and not packet.error_number:
                result.found.append(_found(packet, baud))
        suspects = {b.id for b in bad if b.id is not None and b.id <= MAX_ID} - seen
        for servo_id in sorted(suspects):
            alone, again = link.ping(servo_id)
            if alone is not None:
                result.found.append(_found(alone, baud))
            elif again:
                result.collisions.setdefault(baud, set()).add(servo_id)
        if bad and not suspects and not packets:
            result.corrupt.append(baud)
        if progress is not None:
            progress(baud, len(result.found))
    result.seconds = time.monotonic() - started
    return result


def compare(config, bus_name: str, result: ScanResult) -> list[Finding]:
    """What a scan found against the configuration's bus: each joint's servo at its ID, model and
    the bus's rate; servos the configuration does not name; collisions."""
    bus = config.buses[bus_name]
    joints = config.joints_on(bus_name)
    findings: list[Finding] = []
    by_id: dict[int, list[Found]] = {}
    for f in result.found:
        by_id.setdefault(f.id, []).append(f)
    cfg = config.argument
    for baud, ids in sorted(result.collisions.items()):
        for servo_id in sorted(ids):
            findings.append(Finding(
                "collision", f"several servos answering at ID {servo_id} ({baud} baud), their replies collide",
                f"one servo per ID ({len(joints)} servos, IDs {', '.join(str(j.id) for j in joints)})",
                f"connect one servo at a time and run `servodyn setup --config {cfg} --joint NAME` for each",
                id=servo_id, bus=bus_name))
    for baud in result.corrupt:
        findings.append(Finding("corrupt replies", f"unreadable replies at {baud} baud", "clean status packets",
                                "several servos at one ID, or a TTL/RS-485 mix-up: connect one servo at a time",
                                bus=bus_name))
    for joint in joints:
        here = [f for f in by_id.get(joint.id, []) if f.baud == bus.baud]
        elsewhere = [f for f in by_id.get(joint.id, []) if f.baud != bus.baud]
        setup = f"servodyn setup --config {cfg} --joint {joint.dof}"
        if here:
            f = here[0]
            if f.model_number != joint.servo.model_number:
                findings.append(Finding("model", f.model or f"model number {f.model_number}", joint.servo.name,
                                        f"mount a {joint.servo.name} at this joint, or change its `servo` in the "
                                        "configuration", joint=joint.dof, id=joint.id, bus=bus_name))
            continue
        if elsewhere:
            f = elsewhere[0]
            findings.append(Finding("baud rate", f"{f.baud} baud", f"{bus.baud} baud",
                                    f"`{setup}` writes the bus's rate", joint=joint.dof, id=joint.id, bus=bus_name))
            continue
        if result.collisions:           # the servos are there, sharing an ID: the collision says what to do
            continue
        findings.append(Finding("present", "no servo", f"a {joint.servo.name} at ID {joint.id}, {bus.baud} baud",
                                f"check its power and cable; a new servo answers at ID {FACTORY_ID}, {FACTORY_BAUD} "
                                f"baud: connect it alone and run `{setup}`", joint=joint.dof, id=joint.id,
                                bus=bus_name))
    named = {j.id for j in joints}
    for f in result.found:
        if f.id not in named:
            fresh = " (a new servo's ID and rate)" if (f.id, f.baud) == (FACTORY_ID, FACTORY_BAUD) else ""
            findings.append(Finding("unexpected servo", f"{f.model or f.model_number} at ID {f.id}, {f.baud} baud{fresh}",
                                    "only the configuration's IDs", f"connect it alone and run "
                                    f"`servodyn setup --config {cfg} --joint NAME` for the joint it drives",
                                    id=f.id, bus=bus_name, severity=WARNING))
    return findings


# ---------------------------------------------------------------------------- checks

def decode_table(data: bytes, start: int = 0) -> dict[str, int]:
    """Every item inside `data` (the table from `start`), by name."""
    out = {}
    for name, item in ITEMS.items():
        lo = item.address - start
        if 0 <= lo and lo + item.size <= len(data):
            out[name] = unpack_field(data[lo:lo + item.size], item.signed)
    return out


def table_findings(joint, table: dict[str, int], supply_voltage: float | None = None,
                   bus: str | None = None) -> list[Finding]:
    """What in a servo's control table a run cannot accept (errors) or a user should know
    (warnings), each with its fix: model, firmware, Drive Mode, Homing Offset, Status Return
    Level, Current Limit, input voltage, Hardware Error Status, a tripped Bus Watchdog."""
    where = dict(joint=joint.dof, id=joint.id, bus=bus)
    out: list[Finding] = []
    model = MODELS.get(table["model_number"])
    if table["model_number"] != joint.servo.model_number:
        out.append(Finding("model", model.name if model else f"model number {table['model_number']}",
                           joint.servo.name, "mount the configured servo, or change the joint's `servo`", **where))
        return out
    if table["firmware_version"] < MIN_FIRMWARE:
        out.append(Finding("firmware", table["firmware_version"], f">= {MIN_FIRMWARE} (fast sync read)",
                           "update it with Dynamixel Wizard 2.0 (Tools > Firmware Update)", **where))
    if table["drive_mode"] & 0x01:
        out.append(Finding("drive mode", f"0x{table['drive_mode']:02X} (reverse bit set)", "bit 0 clear",
                           "servodyn sets the direction itself (`direction` in the configuration): "
                           "`servodyn setup` clears the bit", **where))
    if table["homing_offset"] != 0:
        out.append(Finding("homing offset", f"{table['homing_offset']} ticks", "0",
                           "servodyn's zero is `zero_offset` in the configuration: `servodyn setup` writes 0 "
                           "(then `servodyn calibrate`)", **where))
    if table.get("status_return_level", 2) != 2:
        out.append(Finding("status return level", table["status_return_level"], "2 (every instruction answered)",
                           "power-cycle or `servodyn reboot` (it is RAM and comes back as 2)", **where))
    if pwm_driven(joint):       # PWM mode: no current limit acts, PWM Limit caps the duty
        if table["pwm_limit"] < PWM_FULL:
            out.append(Finding("PWM limit", f"{table['pwm_limit']} ({table['pwm_limit'] / PWM_FULL:.0%})",
                               f"{PWM_FULL} (100 %)", "the servo would cap the torque it is driven by silently: "
                               "`servodyn setup` writes 885", **where))
    elif "current_limit" in table:
        unit = current_unit(joint)
        amps = table["current_limit"] * unit
        if amps + unit / 2 < joint.current_limit:
            out.append(Finding("current limit", f"{amps:.3g} A ({table['current_limit']} units)",
                               f">= {joint.current_limit:g} A (the configuration's)",
                               "the servo would clamp the feed-forward silently: `servodyn setup` writes the "
                               "servo's maximum, or lower `current_limit` in the configuration", **where))
    if supply_voltage and table.get("present_input_voltage"):
        volts = table["present_input_voltage"] / 10
        if abs(volts - supply_voltage) > VOLTAGE_TOLERANCE * supply_voltage:
            out.append(Finding("input voltage", f"{volts:.1f} V", f"{supply_voltage:g} V ±{VOLTAGE_TOLERANCE:.0%} "
                               "([supply] voltage)", "check the power supply and its cable, or the configuration's "
                               "[supply] voltage (on a robot whose buses have supplies of their own, the servos' own)",
                               severity=WARNING, **where))
    if table.get("hardware_error_status"):
        names = ", ".join(hardware_faults(table["hardware_error_status"])) or "unknown bits"
        out.append(Finding("hardware error", f"0x{table['hardware_error_status']:02X} ({names})", "0",
                           "find the cause (load, supply, heat), then `servodyn reboot` (only a REBOOT or a power "
                           "cycle clears it)", **where))
    if table.get("bus_watchdog", 0) == -1:
        out.append(Finding("bus watchdog", "tripped (-1)", "0 or armed", "`servodyn clear-errors` (or the next "
                           "run's open) writes 0", severity=WARNING, **where))
    if table.get("return_delay_time", 0) != 0:
        out.append(Finding("return delay time", f"{table['return_delay_time'] * 2} us", "0",
                           "every open writes 0; `servodyn setup` stores it", severity=WARNING, **where))
    return out


def servo_table(link: Link, servo_id: int) -> dict[str, int]:
    """A servo's whole control table in one read, by item name."""
    return decode_table(link.read_table(servo_id, 0, TABLE_SIZE))


def doctor(config, bus_name: str, link: Link) -> list[Finding]:
    """Read-only: each joint's servo present at its ID and the bus's rate, and its table checked
    (table_findings). A joint that does not answer is looked for at its ID at the other rates."""
    supply = config.supply.voltage if config.supply else None
    bus = config.buses[bus_name]
    findings: list[Finding] = []
    missing = []
    link.set_baud(bus.baud)
    for joint in config.joints_on(bus_name):
        reply, bad = link.ping(joint.id)
        if reply is None:
            missing.append((joint, bad))
            continue
        try:
            table = servo_table(link, joint.id)
        except ServoOperationError:        # answers a ping, not a read: Status Return Level 0
            findings.append(Finding("status return level", "0 (answers pings only)", "2",
                                    "power-cycle or `servodyn reboot` (it is RAM and comes back as 2)",
                                    joint=joint.dof, id=joint.id, bus=bus_name))
            continue
        findings += table_findings(joint, table, supply, bus_name)
    if missing:
        others = scan(link, [b for b in SCAN_RATES if b != bus.baud]) if missing else ScanResult()
        link.set_baud(bus.baud)
        cfg = config.argument
        for joint, bad in missing:
            setup = f"servodyn setup --config {cfg} --joint {joint.dof}"
            there = [f for f in others.found if f.id == joint.id]
            if bad:
                findings.append(Finding("present", f"corrupt replies at ID {joint.id}", "one servo answering",
                                        "two servos share this ID: connect one at a time and run "
                                        f"`{setup}`", joint=joint.dof, id=joint.id, bus=bus_name))
            elif there:
                findings.append(Finding("baud rate", f"{there[0].baud} baud", f"{bus.baud} baud",
                                        f"`{setup}` writes the bus's rate", joint=joint.dof, id=joint.id, bus=bus_name))
            else:
                findings.append(Finding("present", "no answer", f"a {joint.servo.name} at ID {joint.id}, "
                                        f"{bus.baud} baud", f"check its power (the LED blinks once at power-up) "
                                        f"and cable; `servodyn scan --port {link.path} --config {cfg}` looks at "
                                        "every ID and rate", joint=joint.dof, id=joint.id, bus=bus_name))
    return findings


# ---------------------------------------------------------------------------- set-up

@dataclass(frozen=True)
class Step:
    """One write of a set-up: the item, its value now and the value it gets."""
    name: str
    old: int
    new: int

    @property
    def what(self) -> str:
        """The item's name in words: "homing offset"."""
        return ITEMS[self.name].name.replace("_", " ")

    def line(self) -> str:
        if self.name == "baud_rate":
            return f"{self.what}: {BAUD_RATES[self.old]} -> {BAUD_RATES[self.new]} baud"
        return f"{self.what}: {self.old} -> {self.new}"


def find_alone(link: Link, rates: Sequence[int] = SCAN_RATES) -> Found:
    """The one servo on the line, at any ID and rate; one line naming what is wrong otherwise."""
    result = scan(link, rates)
    if result.collisions or result.corrupt:
        raise ServoInitializationError(f"{link.path}: several servos answer at once (collisions at "
                                       f"{', '.join(map(str, sorted(result.collisions) or result.corrupt))} baud): "
                                       "connect only the one to set up")
    if not result.found:
        raise ServoInitializationError(f"{link.path}: no servo answered at any rate ({', '.join(map(str, rates))} "
                                       "baud): check its power and the cable (TTL 3-pin or RS-485 4-pin as the "
                                       "adapter's switch)")
    if len(result.found) > 1:
        seen = ", ".join(f"ID {f.id} at {f.baud}" for f in result.found)
        raise ServoInitializationError(f"{link.path}: {len(result.found)} servos answer ({seen}): connect only the "
                                       "one to set up")
    return result.found[0]


def setup_plan(link: Link, found: Found, joint, bus) -> list[Step]:
    """The writes that make the servo `found` the joint's: ID, Return Delay Time 0, Drive Mode
    reverse bit clear, Homing Offset 0, Current Limit at least the configuration's, then the
    bus's baud rate last (the servo answers that write at the old rate, then changes)."""
    if found.model_number != joint.servo.model_number:
        raise ServoInitializationError(f"joint '{joint.dof}' wants a {joint.servo.name}; the servo found is "
                                       f"{found.model or f'model number {found.model_number}'}")
    link.set_baud(found.baud)
    table = servo_table(link, found.id)
    steps = []
    unit = current_unit(joint)
    limit = "pwm_limit" if pwm_driven(joint) else "current_limit"     # PWM Limit at 100 % in PWM mode
    wanted = {"id": joint.id, "return_delay_time": 0, "drive_mode": table["drive_mode"] & ~0x01,
              "homing_offset": 0,
              limit: PWM_FULL if limit == "pwm_limit" else max(table["current_limit"], min(
                  joint.servo.current_limit_max, int(round(joint.current_limit / unit)))),
              "baud_rate": BAUD_RATES.index(bus.baud)}
    for name in ("return_delay_time", "drive_mode", "homing_offset", limit, "id", "baud_rate"):
        if table[name] != wanted[name]:
            steps.append(Step(name, table[name], wanted[name]))
    return steps


def apply_setup(link: Link, found: Found, steps: Sequence[Step], bus_baud: int,
                written: list | None = None) -> Found:
    """Torque off, the steps in order, then the servo pinged at its new ID and rate. `written`:
    a list that gets each step once the servo has acknowledged it (what the EEPROM holds if the
    port is lost on the way)."""
    servo_id = found.id
    link.set_baud(found.baud)
    link.write(servo_id, "torque_enable", 0)
    for step in steps:
        link.write(servo_id, step.name, step.new)
        if written is not None:
            written.append(step)
        if step.name == "id":
            servo_id = step.new
        elif step.name == "baud_rate":
            time.sleep(0.01)            # the servo changes rate after its status packet
            link.set_baud(BAUD_RATES[step.new])
    link.set_baud(bus_baud)
    reply, bad = link.ping(servo_id)
    if reply is None:
        raise ServoOperationError(f"after the set-up the servo does not answer at ID {servo_id}, {bus_baud} baud"
                                  + (" (corrupt replies)" if bad else "") + ": run `servodyn scan` to find it")
    return _found(reply, bus_baud)


# ---------------------------------------------------------------------------- recovery

def torque_off(link: Link, ids: Iterable[int]) -> dict[int, int | None]:
    """Torque Enable 0 by broadcast (every servo at this rate, whatever its ID), then each ID read
    back: ID -> Torque Enable (None: did not answer)."""
    link.write(BROADCAST_ID, "torque_enable", 0)
    return _read_each(link, ids, "torque_enable")


def reboot(link: Link, ids: Iterable[int]) -> dict[int, int | None]:
    """REBOOT each servo, then its Hardware Error Status read back once it is up (None: silent)."""
    ids = list(ids)
    for servo_id in ids:
        link.reboot(servo_id)
    time.sleep(0.1)                       # a servo takes a moment to boot
    return _read_each(link, ids, "hardware_error_status")


def clear_watchdog(link: Link, ids: Iterable[int]) -> dict[int, int | None]:
    """A tripped Bus Watchdog (-1) written 0 (goals are refused until then); the value read back."""
    out = {}
    for servo_id in ids:
        try:
            if link.read(servo_id, "bus_watchdog") == -1:
                link.write(servo_id, "bus_watchdog", 0)
            out[servo_id] = link.read(servo_id, "bus_watchdog")
        except ServoOperationError:
            out[servo_id] = None
    return out


def _read_each(link: Link, ids, name: str) -> dict[int, int | None]:
    out = {}
    for servo_id in ids:
        try:
            out[servo_id] = link.read(servo_id, name)
        except ServoOperationError:
            out[servo_id] = None
    return out


def horn_angles(link: Link, ids: Sequence[int]) -> dict[int, float]:
    """Each servo's Present Position as a horn angle (rad; 0 at tick 0), for a calibration."""
    return {i: link.read(i, "present_position") * 2 * math.pi / TICKS_PER_REV for i in ids}

