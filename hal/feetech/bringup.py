"""Feetech STS bring-up on a bench: find servos at any ID and rate, set one up for its joint through
the EEPROM lock, check every servo of a configuration, calibrate a joint's Homing_Offset and range
into the servo, switch torque off, restart. Each goes over a `Link` (hal.feetech.link); the commands
reach them through `FeetechBringUp` (hal.feetech.session).

The scan. A broadcast PING at each of the eight STS rates (1 Mbps, the factory's, first): every
servo listening at that rate answers it, so the whole ID range costs one 6-byte instruction a rate,
then one READ of the servo's first 7 bytes (firmware, model, ID, rate) for each servo found. The
listen after each PING is SCAN_WINDOW: a servo answers within its Return Delay Time (at most 254 x
2 us = 508 us, then its bytes), which a USB adapter's latency timer (16 ms on an FTDI) delays; the
window covers both. Replies that do not check are asked again by SYNC READ, which the servos
answer one after another in the order of the IDs (`sweep`: two instructions for IDs 0-252), and
the IDs readable in what still does not check are pinged alone: corrupt again, it is several
servos at that ID.

Set-up. Lock(55) is inverted: 0 unlocks (an EEPROM write is stored), 1 locks (an EEPROM write acts
until power-off, then the old value is back: a set-up that forgets the lock works until the next
power-up). So: torque off, Lock 0, the writes (the rate last: the servo answers it at the old rate,
then changes), Lock 1 at the new ID and rate, RESTART, and every item read back after the restart
— what the EEPROM really holds.

Calibration (as LeRobot's: ../shared/notes/servos/feetech.md §6). Present_Position = Actual −
Homing_Offset, wrapping within 0..4095 (single-turn feedback). The joint's zero pose measured by
hand is moved to step 2048, the middle of the turn, by the Homing_Offset (11-bit sign-magnitude,
±2047), so the joint's range never crosses the wrap; Min/Max_Position_Limit get its stops; the
configuration's `zero_offset` becomes the zero as the servo then reads it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from ..bringup import WARNING, Finding, Found
from ..errors import ServoInitializationError, ServoOperationError
from . import protocol
from .link import Link
from .protocol import BROADCAST_ID, SCAN_MAX_ID, status_faults
from .table import BAUD_RATES, DEFAULT_BAUD, DUTY_FULL, ITEMS, MODELS, STEP, TICKS_PER_REV, VOLTAGE_UNIT, item_value

FACTORY_ID, FACTORY_BAUD = 1, DEFAULT_BAUD
SCAN_RATES = BAUD_RATES                  # 1 Mbps (the factory's) first, then down to 38400
SCAN_WINDOW = 0.03      # s listened after a broadcast PING (the module's docstring)
IDENTITY = 7            # bytes 0..6: firmware major, minor, END, model number, ID, baud code
TABLE_READ = 71         # bytes 0..70: EEPROM, control and feedback (up to Present Current)
VOLTAGE_TOLERANCE = 0.10
TEMPERATURE_MARGIN = 10  # degC below Max_Temperature_Limit that doctor warns at
MULTI_TURN = 0x10        # Phase(18) bit 4: multi-turn angle feedback (positions leave 0..4095)
CENTRE = TICKS_PER_REV // 2
MAX_OFFSET = 2047        # Homing_Offset's magnitude (sign bit 11)
RESTART_WAIT = 3.0       # s a restarted servo may take to answer (Feetech: about 1.8 s)


# ---------------------------------------------------------------------------- scan

@dataclass
class ScanResult:
    """What a scan found, the collisions (rate -> IDs answering at once) and rates with unreadable
    replies, and what it cost: instructions sent, bytes on the wire both ways, seconds."""
    found: list[Found] = field(default_factory=list)
    collisions: dict[int, set[int]] = field(default_factory=dict)
    corrupt: list[int] = field(default_factory=list)
    rates: tuple[int, ...] = ()
    transactions: int = 0
    wire_bytes: int = 0
    seconds: float = 0.0


def firmware_text(found: Found) -> str:
    return found.extra.get("firmware_version", "?")


def identify(link: Link, servo_id: int, baud: int) -> Found:
    """The servo at `servo_id`, from its first 7 bytes: model, firmware (major x 100 + minor)."""
    data, _ = link.read(servo_id, 0, IDENTITY)
    number = data[3] | data[4] << 8
    model = MODELS.get(number)
    return Found(id=servo_id, model_number=number, model=model.name if model else None,
                 firmware=data[0] * 100 + data[1], baud=baud, kind="feetech",
                 extra={"firmware_version": f"{data[0]}.{data[1]}"})


def scan(link: Link, rates: Iterable[int] = SCAN_RATES, patience: float = 0.0,
         again: float | None = None) -> ScanResult:
    """A broadcast PING at each rate, then each servo that answered identified (the module's
    docstring). `patience`: s added to each listen. `again`: a simulated bus on a pseudo-terminal,
    whose bytes carry no rate, so a reply later than the listen would be heard at the next rate: a
    scan that heard nothing, or a reply whose servo then does not answer a READ at that rate, is
    made again with this patience (a loaded machine's simulator answers late)."""
    started, sent, before = time.monotonic(), link.transactions, link.sent + link.received
    result, late = _scan_pass(link, tuple(rates), patience)
    if again is not None and (late or not (result.found or result.collisions or result.corrupt)):
        result, _ = _scan_pass(link, tuple(rates), again)
    result.transactions = link.transactions - sent
    result.wire_bytes = link.sent + link.received - before
    result.seconds = time.monotonic() - started
    return result


def _scan_pass(link: Link, rates: tuple[int, ...], patience: float) -> tuple[ScanResult, bool]:
    """One scan at `rates`, and whether a servo that answered the PING then did not answer a READ."""
    result, late = ScanResult(rates=rates), False
    for baud in rates:
        link.set_baud(baud)
        packets, bad = link.exchange(protocol.ping(BROADCAST_ID), window=SCAN_WINDOW, patience=patience)
        ids = {p.id for p in packets if p.id <= SCAN_MAX_ID}
        garbled = bool(bad) or bool(link.heard) and not packets
        if garbled:                     # replies that did not check: ask again, each servo in its turn
            swept, bad = sweep(link, patience)
            ids |= swept
        for servo_id in sorted(bad - ids):
            alone, collided = link.ping(servo_id)
            if alone is not None:
                ids.add(servo_id)
            elif collided:
                result.collisions.setdefault(baud, set()).add(servo_id)
        if garbled and not ids and baud not in result.collisions:
            result.corrupt.append(baud)
        for servo_id in sorted(ids):
            try:
                result.found.append(identify(link, servo_id, baud))
            except ServoOperationError:        # a reply to an earlier PING, or a servo that answers pings only
                late = True
    return result, late


def sweep(link: Link, patience: float = 0.0) -> tuple[set[int], set[int]]:
    """The IDs 0-252 asked for their model number by SYNC READ (two instructions: a packet carries
    at most 248 IDs), which the servos answer in the order of the IDs, one after another (Feetech's
    protocol), where replies to a broadcast PING garbled each other: the IDs that answered, and
    the IDs readable in replies that did not check (servos sharing an ID still collide)."""
    found, bad = set(), set()
    ids = list(range(SCAN_MAX_ID + 1))
    for start in range(0, len(ids), protocol.MAX_PARAMS - 2):
        packets, suspects = link.exchange(protocol.sync_read(3, 2, ids[start:start + protocol.MAX_PARAMS - 2]),
                                          window=SCAN_WINDOW, patience=patience)
        found |= {p.id for p in packets if len(p.params) == 2}
        bad |= suspects
    return found, bad - found


def compare(config, bus_name: str, result: ScanResult) -> list[Finding]:
    """What a scan found against the configuration's bus: each joint's servo at its ID, model and
    the bus's rate; servos the configuration does not name; collisions."""
    bus, joints, cfg = config.buses[bus_name], config.joints_on(bus_name), config.argument
    findings: list[Finding] = []
    for baud, ids in sorted(result.collisions.items()):
        for servo_id in sorted(ids):
            findings.append(Finding(
                "collision", f"several servos answering at ID {servo_id} ({baud} baud), their replies collide",
                f"one servo per ID ({len(joints)} servos, IDs {', '.join(str(j.id) for j in joints)})",
                f"connect one servo at a time and run `servodyn setup --config {cfg} --joint NAME` for each",
                id=servo_id, bus=bus_name))
    for baud in result.corrupt:
        findings.append(Finding("corrupt replies", f"unreadable replies at {baud} baud", "clean status packets",
                                "several servos at one ID: connect one servo at a time", bus=bus_name))
    for joint in joints:
        mine = [f for f in result.found if f.id == joint.id]
        here = [f for f in mine if f.baud == bus.baud]
        setup = f"servodyn setup --config {cfg} --joint {joint.dof}"
        if here and here[0].model_number != joint.servo.model_number:
            findings.append(Finding("model", here[0].model or f"model number {here[0].model_number}", joint.servo.name,
                                    f"mount a {joint.servo.name} at this joint, or change its `servo` in the "
                                    "configuration", joint=joint.dof, id=joint.id, bus=bus_name))
        elif not here and mine:
            findings.append(Finding("baud rate", f"{mine[0].baud} baud", f"{bus.baud} baud",
                                    f"`{setup}` writes the bus's rate", joint=joint.dof, id=joint.id, bus=bus_name))
        elif not here and not result.collisions:
            findings.append(Finding("present", "no servo", f"a {joint.servo.name} at ID {joint.id}, {bus.baud} baud",
                                    f"check its power and cable; a new servo answers at ID {FACTORY_ID}, "
                                    f"{FACTORY_BAUD} baud: connect it alone and run `{setup}`",
                                    joint=joint.dof, id=joint.id, bus=bus_name))
    named = {j.id for j in joints}
    for f in result.found:
        if f.id not in named:
            fresh = " (a new servo's ID and rate)" if (f.id, f.baud) == (FACTORY_ID, FACTORY_BAUD) else ""
            findings.append(Finding("unexpected servo", f"{f.model or f.model_number} at ID {f.id}, {f.baud} baud"
                                    f"{fresh}", "only the configuration's IDs", f"connect it alone and run "
                                    f"`servodyn setup --config {cfg} --joint NAME` for the joint it drives",
                                    id=f.id, bus=bus_name, severity=WARNING))
    return findings


def find_alone(link: Link, rates: Sequence[int] = SCAN_RATES, patience: float = 0.0,
               again: float | None = None) -> Found:
    """The one servo on the line, at any ID and rate; one line naming what is wrong otherwise."""
    result = scan(link, rates, patience, again)
    if result.collisions or result.corrupt:
        raise ServoInitializationError(f"{link.path}: several servos answer at once (collisions at "
                                       f"{', '.join(map(str, sorted(result.collisions) or result.corrupt))} baud): "
                                       "connect only the one to set up")
    if not result.found:
        raise ServoInitializationError(f"{link.path}: no servo answered at any rate ({', '.join(map(str, rates))} "
                                       "baud): check its power (6-7.4 V or 12 V as its model) and the 3-pin cable")
    if len(result.found) > 1:
        seen = ", ".join(f"ID {f.id} at {f.baud}" for f in result.found)
        raise ServoInitializationError(f"{link.path}: {len(result.found)} servos answer ({seen}): connect only the "
                                       "one to set up")
    return result.found[0]


# ---------------------------------------------------------------------------- the table

def decode_table(data: bytes, start: int = 0) -> dict[str, int]:
    """Every item inside `data` (the table from `start`), by name, sign-magnitude decoded."""
    out = {}
    for item in ITEMS:
        lo = item.address - start
        if 0 <= lo and lo + item.size <= len(data):
            out[item.name] = item_value(item.name, int.from_bytes(data[lo:lo + item.size], "little"))
    return out


def servo_table(link: Link, servo_id: int) -> dict[str, int]:
    """A servo's table up to Present Current, in one READ."""
    data, _ = link.read(servo_id, 0, TABLE_READ)
    return decode_table(data)


def horn_ticks(direction: int, gear: float, q: float, zero_ticks: float) -> float:
    """Present Position (steps) at joint angle `q` for a zero read at `zero_ticks`."""
    return zero_ticks + direction * gear * q / STEP


def table_findings(joint, table: dict[str, int], supply_voltage: float | None = None,
                   bus: str | None = None) -> list[Finding]:
    """What in a servo's table a run cannot accept (errors) or a user should know (warnings), each
    with its fix: model, Status, voltage against [supply] and the servo's limits, temperature,
    load, Phase (multi-turn feedback), Max_Torque_Limit and Torque_Limit, Operating_Mode, the
    position limits against the configuration's, Response_Status_Level, Return_Delay_Time."""
    where = dict(joint=joint.dof, id=joint.id, bus=bus)
    out: list[Finding] = []
    if table["model_number"] != joint.servo.model_number:
        model = MODELS.get(table["model_number"])
        out.append(Finding("model", model.name if model else f"model number {table['model_number']}",
                           joint.servo.name, "mount the configured servo, or change the joint's `servo`", **where))
        return out
    if table["status"]:
        names = ", ".join(status_faults(table["status"])) or "unknown bits"
        out.append(Finding("status", f"0x{table['status']:02X} ({names})", "0",
                           "find the cause (load, supply, heat), then `servodyn reboot` (a restart clears it; "
                           "an overload also clears with torque off and on)", **where))
    volts = table["present_voltage"] * VOLTAGE_UNIT
    low, high = table["min_voltage_limit"] * VOLTAGE_UNIT, table["max_voltage_limit"] * VOLTAGE_UNIT
    if not low <= volts <= high:
        out.append(Finding("input voltage", f"{volts:.1f} V", f"{low:.1f}-{high:.1f} V (the servo's limits)",
                           f"power it from a supply inside its range ({joint.servo.name}: "
                           f"{joint.servo.supply_range[0]:g}-{joint.servo.supply_range[1]:g} V)", **where))
    elif supply_voltage and abs(volts - supply_voltage) > VOLTAGE_TOLERANCE * supply_voltage:
        out.append(Finding("input voltage", f"{volts:.1f} V", f"{supply_voltage:g} V ±{VOLTAGE_TOLERANCE:.0%} "
                           "([supply] voltage)", "check the power supply and its cable, or the configuration's "
                           "[supply] voltage (the duty for a torque is computed from the voltage read)",
                           severity=WARNING, **where))
    limit = table["max_temperature_limit"]
    if table["present_temperature"] >= limit - TEMPERATURE_MARGIN:
        out.append(Finding("temperature", f"{table['present_temperature']} degC", f"below {limit - TEMPERATURE_MARGIN} "
                           f"degC (the servo cuts out at {limit})", "let it cool with torque off; "
                           "`servodyn validate` shows the heat a motion costs", **where,
                           severity=WARNING if table["present_temperature"] < limit else "error"))
    load = abs(table["present_load"]) / DUTY_FULL * 100
    if load > table["overload_torque"]:
        out.append(Finding("load", f"{load:.0f} % duty", f"below {table['overload_torque']} % (Overload_Torque: "
                           f"held {table['protection_time'] * 10} ms it drops to {table['protective_torque']} %)",
                           "support the joint or lighten it; `servodyn validate` checks the duty a motion needs",
                           severity=WARNING, **where))
    if table["phase"] & MULTI_TURN:
        out.append(Finding("phase", f"0x{table['phase']:02X} (bit 4 set: multi-turn feedback)", "bit 4 clear",
                           "positions would leave 0..4095: `servodyn setup` clears it", **where))
    for name in ("max_torque_limit", "torque_limit"):
        if table[name] < DUTY_FULL:
            out.append(Finding(name.replace("_", " "), f"{table[name] / 10:g} %", "100 %",
                               "the servo would cap the duty it is driven by silently: `servodyn setup` writes "
                               "1000 (Max_Torque_Limit; Torque_Limit takes it at power-up)", **where))
    if table["operating_mode"] not in (0, 2):
        out.append(Finding("mode", f"Operating_Mode {table['operating_mode']}", "0 (position) or 2 (PWM)",
                           "every open writes 2 until power-off; `servodyn setup` stores 0", severity=WARNING, **where))
    out += _position_limits(joint, table, where)
    if table["response_status_level"] != 1:
        out.append(Finding("response status level", table["response_status_level"], "1 (every instruction "
                           "answered)", "`servodyn setup` writes 1", **where))
    if table["return_delay_time"]:
        out.append(Finding("return delay time", f"{table['return_delay_time'] * 2} us", "0",
                           "every open writes 0; `servodyn setup` stores it", severity=WARNING, **where))
    return out


def _position_limits(joint, table: dict[str, int], where: dict) -> list[Finding]:
    """Min/Max_Position_Limit (steps) against the configuration's range as the servo reads it now.
    Mode 2 ignores them (nothing stops the joint); position mode stops short of a range they cut."""
    lo, hi = table["min_position_limit"], table["max_position_limit"]
    if lo == 0 and hi == 0:                   # multi-turn: no limits
        return []
    ends = sorted(horn_ticks(joint.direction, joint.gear_ratio, q, joint.zero_offset / STEP)
                  for q in joint.position_limits)
    if ends[0] >= lo - 1 and ends[1] <= hi + 1:
        return []
    return [Finding("position limits", f"{lo}..{hi} steps", f"around {ends[0]:.0f}..{ends[1]:.0f} (the "
                    "configuration's range)", f"`servodyn calibrate --config ... --joint {joint.dof}` writes them",
                    severity=WARNING, **where)]


def doctor(config, bus_name: str, link: Link, patience: float = 0.0) -> list[Finding]:
    """Read-only: each joint's servo present at its ID and the bus's rate, and its table checked
    (table_findings), then firmware alike on the bus. A joint that does not answer is looked for
    at the other rates."""
    supply = config.supply.voltage if config.supply else None
    bus, cfg = config.buses[bus_name], config.argument
    findings: list[Finding] = []
    missing, firmware = [], {}
    link.set_baud(bus.baud)
    for joint in config.joints_on(bus_name):
        reply, bad = link.ping(joint.id)
        if reply is None:
            missing.append((joint, bad))
            continue
        table = servo_table(link, joint.id)
        firmware[joint.dof] = f"{table['firmware_major']}.{table['firmware_minor']}"
        findings += table_findings(joint, table, supply, bus_name)
    if len(set(firmware.values())) > 1:
        findings.append(Finding("firmware", ", ".join(f"{d} {v}" for d, v in firmware.items()), "one version",
                                "servos of different firmware behave differently (LeRobot refuses such a bus): "
                                "update them alike with Feetech's FD software", bus=bus_name, severity=WARNING))
    if missing:
        others = scan(link, [b for b in SCAN_RATES if b != bus.baud], patience)
        link.set_baud(bus.baud)
        for joint, bad in missing:
            setup = f"servodyn setup --config {cfg} --joint {joint.dof}"
            there = [f for f in others.found if f.id == joint.id]
            where = dict(joint=joint.dof, id=joint.id, bus=bus_name)
            if bad:
                findings.append(Finding("present", f"corrupt replies at ID {joint.id}", "one servo answering",
                                        f"two servos share this ID: connect one at a time and run `{setup}`", **where))
            elif there:
                findings.append(Finding("baud rate", f"{there[0].baud} baud", f"{bus.baud} baud",
                                        f"`{setup}` writes the bus's rate", **where))
            else:
                findings.append(Finding("present", "no answer", f"a {joint.servo.name} at ID {joint.id}, "
                                        f"{bus.baud} baud", f"check its power and cable; `servodyn scan --port "
                                        f"{link.path} --config {cfg}` looks at every ID and rate", **where))
    return findings


# ---------------------------------------------------------------------------- EEPROM writes

@dataclass(frozen=True)
class Step:
    """One EEPROM write: the item, its value now and the value it gets."""
    name: str
    old: int
    new: int

    @property
    def what(self) -> str:
        return self.name.replace("_", " ")

    def line(self) -> str:
        if self.name == "baud_rate":
            return f"{self.what}: {BAUD_RATES[self.old]} -> {BAUD_RATES[self.new]} baud"
        if self.name == "phase":
            return f"{self.what}: 0x{self.old:02X} -> 0x{self.new:02X} (single-turn feedback)"
        return f"{self.what}: {self.old} -> {self.new}"


def setup_plan(link: Link, found: Found, joint, bus) -> list[Step]:
    """The writes that make the servo `found` the joint's: Response_Status_Level 1 (first: the
    writes after it are answered), Return_Delay_Time 0, Phase bit 4 clear, Max_Torque_Limit 100 %,
    the ID, then the bus's rate last."""
    if found.model_number != joint.servo.model_number:
        raise ServoInitializationError(f"joint '{joint.dof}' wants a {joint.servo.name}; the servo found is "
                                       f"{found.model or f'model number {found.model_number}'}")
    link.set_baud(found.baud)
    table = servo_table(link, found.id)
    wanted = {"response_status_level": 1, "return_delay_time": 0, "phase": table["phase"] & ~MULTI_TURN,
              "max_torque_limit": DUTY_FULL, "id": joint.id, "baud_rate": BAUD_RATES.index(bus.baud)}
    return [Step(name, table[name], value) for name, value in wanted.items() if table[name] != value]


def write_locked(link: Link, servo_id: int, steps: Sequence[Step], written: list | None = None) -> tuple[int, int]:
    """Torque off, Lock 0, the steps in order, Lock 1 at the servo's new ID and rate: where it then
    answers (ID, baud). `written` gets each step once the servo has acknowledged it."""
    if any(s.name == "response_status_level" and s.old == 0 for s in steps):
        link.send(protocol.write(servo_id, 8, b"\x01"))         # unanswered at level 0: sent, not awaited
        time.sleep(0.01)
    link.write_item(servo_id, "torque_enable", 0)
    link.write_item(servo_id, "lock", 0)                        # inverted: 0 stores EEPROM writes
    for step in steps:
        if not (step.name == "response_status_level" and step.old == 0):
            link.write_item(servo_id, step.name, step.new)
        if written is not None:
            written.append(step)
        if step.name == "id":
            servo_id = step.new
        elif step.name == "baud_rate":
            time.sleep(0.01)                                    # it changes rate after its status packet
            link.set_baud(BAUD_RATES[step.new])
    link.write_item(servo_id, "lock", 1)
    return servo_id, link.baud


def verify_stored(link: Link, servo_id: int, steps: Sequence[Step], patience: float = 0.0) -> dict[str, int]:
    """RESTART the servo, wait for it at `servo_id` (link's rate), and read back every step's item:
    what the EEPROM holds. ServoOperationError naming what did not stay."""
    link.restart(servo_id)
    deadline = time.monotonic() + RESTART_WAIT + patience
    while True:
        reply, _ = link.ping(servo_id)
        if reply is not None:
            break
        if time.monotonic() > deadline:
            raise ServoOperationError(f"after a restart the servo does not answer at ID {servo_id}, {link.baud} "
                                      "baud: the EEPROM kept its old ID or rate (was Lock(55) 0 while writing?): "
                                      "run `servodyn scan` to find it")
        time.sleep(0.1)
    table = servo_table(link, servo_id)
    lost = [s for s in steps if table[s.name] != s.new]
    if lost:
        raise ServoOperationError("after a restart the EEPROM holds " + ", ".join(
            f"{s.what} {table[s.name]}, not {s.new}" for s in lost) + ": the writes did not stay (Lock(55) is "
            "inverted: 0 stores them)")
    return table


def apply_setup(link: Link, found: Found, steps: Sequence[Step], patience: float = 0.0,
                written: list | None = None) -> Found:
    """The plan written through the lock, then the servo restarted and every item read back."""
    link.set_baud(found.baud)
    servo_id, baud = write_locked(link, found.id, steps, written)
    verify_stored(link, servo_id, steps, patience)
    return identify(link, servo_id, baud)


def calibration_plan(link: Link, joint, values: dict) -> tuple[dict, list[Step]]:
    """A calibration (direction, zero_offset: the horn's reading at the zero pose, rad, under the
    servo's Homing_Offset now; position_limits) as the servo will hold it: the Homing_Offset that
    puts the zero at step 2048, the stops as Min/Max_Position_Limit, and the values with the
    zero_offset the servo will then read."""
    old = link.read_item(joint.id, "homing_offset")
    zero = values["zero_offset"] / STEP
    shift = old + round(zero) - CENTRE                       # the offset that reads the zero at CENTRE
    offset = max(-MAX_OFFSET, (shift + CENTRE) % TICKS_PER_REV - CENTRE)     # a turn wrapped into ±2047
    zero_after = (zero - (offset - old)) % TICKS_PER_REV
    ends = sorted(horn_ticks(values["direction"], joint.gear_ratio, q, zero_after) for q in values["position_limits"])
    now = {n: link.read_item(joint.id, n) for n in ("min_position_limit", "max_position_limit")}
    now["homing_offset"] = old
    wanted = {"homing_offset": offset, "min_position_limit": max(0, math.floor(ends[0])),
              "max_position_limit": min(TICKS_PER_REV - 1, math.ceil(ends[1]))}
    steps = [Step(n, now[n], v) for n, v in wanted.items() if now[n] != v]
    return {**values, "zero_offset": zero_after * STEP}, steps


def apply_calibration(link: Link, joint, steps: Sequence[Step], patience: float = 0.0) -> None:
    """The calibration's writes through the lock, then read back after a restart."""
    write_locked(link, joint.id, steps)
    verify_stored(link, joint.id, steps, patience)


# ---------------------------------------------------------------------------- recovery

def read_each(link: Link, ids: Iterable[int], name: str) -> dict[int, int | None]:
    out = {}
    for servo_id in ids:
        try:
            out[servo_id] = link.read_item(servo_id, name)
        except ServoOperationError:
            out[servo_id] = None
    return out


def torque_off(link: Link, ids: Iterable[int]) -> dict[int, int | None]:
    """Torque_Enable 0 by broadcast (every servo at this rate), then each ID read back."""
    link.broadcast_item("torque_enable", 0)
    time.sleep(0.005)
    return read_each(link, ids, "torque_enable")


def restart(link: Link, ids: Sequence[int], patience: float = 0.0) -> dict[int, int | None]:
    """RESTART each servo, then its Status read once it answers again (None: it did not)."""
    for servo_id in ids:
        link.restart(servo_id)
    deadline = time.monotonic() + RESTART_WAIT + patience
    state = read_each(link, ids, "status")
    while None in state.values() and time.monotonic() < deadline:
        time.sleep(0.1)
        state.update(read_each(link, [i for i, v in state.items() if v is None], "status"))
    return state


def clear_protection(link: Link, ids: Iterable[int]) -> dict[int, int | None]:
    """Torque off (what ends an overload's protection), then each Status read back."""
    for servo_id in ids:
        try:
            link.write_item(servo_id, "torque_enable", 0)
        except ServoOperationError:
            pass
    return read_each(link, ids, "status")
