"""Bring-up of a CAN bus of Damiao motors: what `servodyn scan`, `setup`, `doctor`, `calibrate`
(zero), `clear-errors` and `torque off` do on a CAN bus, over a python-can bus the caller opens
(link.open_bus(channel, spec.interface_for(channel, configured), bitrate)) and closes.

    scan(bus)                         every motor that answers a register read, wherever it answers
    compare(config, "arm", found)     what differs from the configuration, each with its fix
    find_alone(bus, joint)            the one motor on the bus, for a set-up
    setup_plan(bus, motor, joint)     its ids, MIT mode and ranges as register writes (reads only)
    apply_setup(bus, motor, joint, steps)   the writes, then a save to flash
    doctor(config, "arm", bus)        read-only: presence, mode, ranges, status, temperatures, errors
    zero(bus, joint, confirm)         the motor's zero where it stands
    clear_errors(bus, joints), torque_off(bus, joints)

Only scan, doctor and the state re-reads talk to a motor whose Master ID is not known; nothing here
gives torque: the frames sent are register reads and writes (id 0x7FF), status requests (0xCC),
flash saves (0xAA, only after a disable and a yes from `confirm`) and the special frames disable
(FD), clear error (FB) and set zero (FE). The facts relied on are in dialects.py with their sources
(factory CAN ID 1 and Master ID 0, flash saved only when disabled, ~10,000 flash cycles).

Unverified without hardware: whether the firmware answers a save (0xAA) at all (some tools wait
for an echo, the vendor's own examples do not: setup says which it saw), whether a write of the
CAN ID (ESC_ID) is echoed under the old id or the new one (both are accepted), and the mode a motor
is shipped in (setup writes MIT whatever it finds).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable

from ..bringup import ERROR, WARNING, Finding, Found
from ..errors import ServoInitializationError, ServoTimeoutError
from . import frames
from .dialects import (CTRL_MODES, DAMIAO_DISABLED, DAMIAO_ENABLED, DAMIAO_STATUS, DIALECTS, FACTORY_CAN_ID,
                       FACTORY_MASTER_ID, FLASH_CYCLES, MIT_MODE, RANGE_REGISTERS, REG_CTRL_MODE, REG_ESC_ID, REG_GR,
                       REG_MST_ID, REG_OT, range_matches, register_bits, register_value)
from .link import CanLink
from .motors import MOTORS
from .spec import MAX_ID, Can

REPLY_TIMEOUT = 0.05      # s for one answer (a motor answers within about a millisecond)
SCAN_LISTEN = 0.05        # s of quiet after the last probe before a scan ends
PROBE_BATCH = 16          # probes sent before the answers waiting are taken: a socketcan queue holds
                          # 10 frames by default, a pseudo-terminal a few kB of the adapter's replies
TEMPERATURE_MARGIN = 10.0   # K below the motor's OT limit from which a temperature is a warning

SETUP = "servodyn setup"
CLEAR = "servodyn clear-errors"
# what to do about each latched status (dialects.DAMIAO_STATUS names them)
STATUS_FIX = {
    0x8: "the supply is above the motor's overvoltage limit (or a braking motor pumped it up): lower it, "
         f"then run {CLEAR}",
    0x9: f"the supply sagged below the motor's undervoltage limit: check the supply and its wiring, then run {CLEAR}",
    0xA: f"run {CLEAR}; if it comes back, lower the gains or the torque asked of the joint",
    0xB: f"let the motor's driver cool, then run {CLEAR}",
    0xC: f"let the motor cool, then run {CLEAR}",
    0xD: f"the host stopped sending for longer than the motor's CAN timeout (as when a run stops): run {CLEAR}",
    0xE: f"run {CLEAR}; check that the joint moves freely",
}


# ---------------------------------------------------------------- scan
def scan(bus, ids: Iterable[int] = range(1, MAX_ID + 1), listen: float = SCAN_LISTEN, *,
         bitrate: int = Can.default_baud, timeout: float = REPLY_TIMEOUT, heard: list | None = None) -> list[Found]:
    """Every Damiao motor that answers a read of its Master ID (register 7, through id 0x7FF) sent
    to each of `ids`, whatever id it answers on; then each one's status and temperatures (0xCC),
    CTRL_MODE and gear ratio (which names the model). Found.extra: dialect, master_id (its
    register), reply_id (the id its answer came on: 0 on a factory-fresh motor), answers (more
    than 1: several motors share the CAN ID), status, status_code, ctrl_mode, mos_temperature,
    coil_temperature. `listen`: s of quiet after the last probe; `bitrate`: the rate the bus was
    opened at (python-can's bus does not say); `heard`: a list that gets one line per frame no
    motor's answer explains and per error frame (with what to check)."""
    link = CanLink(_name(bus), bus, timeout=timeout, errors=[])
    found, others = _scan(link, ids, listen, bitrate)
    if heard is not None:
        heard += [f"id 0x{i:X}: {d.hex() or '-'} (no motor's answer to a register read)" for i, d in others]
        heard += [f"error frame: {frames.error_frame(i, d)[1]}" for i, d in link.errors]
    return found


def _name(bus) -> str:
    return str(getattr(bus, "channel_info", None) or "can")


def _scan(link: CanLink, ids: Iterable[int], listen: float, bitrate: int):
    hits: dict[int, list] = {}     # CAN ID -> [(reply id, Master ID register)] in order of arrival
    others = []

    def take(msg) -> None:
        data = bytes(msg.data)
        if len(data) == 8 and data[2] == frames.REG_READ and data[3] == REG_MST_ID:
            g = frames.unpack_register(data)
            hits.setdefault(g.can_id, []).append((msg.arbitration_id, g.value))
        else:
            others.append((msg.arbitration_id, data))

    for k, can_id in enumerate(ids):
        link.send(frames.REGISTER_ID, frames.pack_register(frames.Register(can_id, frames.REG_READ, REG_MST_ID)))
        if k % PROBE_BATCH == PROBE_BATCH - 1:
            for msg in link.drain():
                take(msg)
    while (msg := link.recv(listen)) is not None:      # until `listen` s pass without a frame
        take(msg)
    # one Found per motor: two motors on one CAN ID are told apart by the ids they answer on
    found = [_motor(link, can_id, reply_id, master, len(answers), bitrate, others)
             for can_id, answers in sorted(hits.items()) for reply_id, master in sorted(set(answers))]
    return found, others


def _motor(link: CanLink, can_id: int, reply_id: int, master: int, answers: int, bitrate: int, others: list) -> Found:
    """A motor that answered a scan, with its status, temperatures, mode and model read."""
    extra = {"dialect": "damiao", "master_id": master, "reply_id": reply_id, "answers": answers}
    state = _refresh(link, can_id, reply_id, others)
    if state is not None:
        extra.update(status=DAMIAO_STATUS.get(state[0], f"unknown status 0x{state[0]:X}"), status_code=state[0],
                     mos_temperature=state[1], coil_temperature=state[2])
    mode = _read(link, can_id, REG_CTRL_MODE, {reply_id})
    extra["ctrl_mode"] = None if mode is None else int(mode)
    gear = _read(link, can_id, REG_GR, {reply_id})
    model = next((m.name for m in MOTORS.values() if m.dialect == "damiao" and gear is not None
                  and abs(m.gear_ratio - gear) < 0.01), None)
    return Found(id=can_id, model_number=None, model=model, firmware=None, baud=bitrate, kind="can", extra=extra)


def _read(link: CanLink, can_id: int, rid: int, reply_ids=None):
    answer = link.register(can_id, frames.REG_READ, rid, reply_ids=reply_ids)
    return None if answer is None else register_value(rid, answer[0])


def _is_feedback(data: bytes, can_id: int) -> bool:
    """A Damiao feedback frame of this motor, not a register echo (which names the CAN ID in bytes 0-1)."""
    if len(data) != 8 or (data[0] & 0xF) != (can_id & 0xF):
        return False
    return not (data[0] | (data[1] << 8) == can_id and data[2] in (frames.REG_READ, frames.REG_WRITE, frames.REG_STORE))


def _refresh(link: CanLink, can_id: int, reply_id: int, others: list | None = None):
    """(status, MOS °C, coil °C) from the feedback frame a status request (0xCC) asks for, or None."""
    link.send(frames.REGISTER_ID, frames.pack_register(frames.Register(can_id, frames.REG_REFRESH, 0)))
    deadline = time.monotonic() + link.timeout
    while (left := deadline - time.monotonic()) > 0 and (msg := link.recv(left)) is not None:
        data = bytes(msg.data)
        if msg.arbitration_id == reply_id and _is_feedback(data, can_id):
            y = frames.unpack_damiao_feedback(frames.Ranges(1.0, 1.0, 1.0), data)   # ranges: p, v, t unused here
            return y.status, y.temperature, y.temperature2
        if others is not None:
            others.append((msg.arbitration_id, data))
    return None


# ---------------------------------------------------------------- compare
def compare(config, bus_name: str, found: list[Found]) -> list[Finding]:
    """What a scan found that differs from the configuration's bus `bus_name`, each with its fix:
    a joint's motor that did not answer, one that answers on another Master ID (0: fresh from the
    factory), in another mode than MIT, several motors on one CAN ID, a motor the configuration
    does not know."""
    joints = config.joints_on(bus_name)
    fresh = [f for f in found if f.extra.get("master_id") == FACTORY_MASTER_ID]
    findings = []
    for joint in joints:
        where = dict(joint=joint.dof, id=joint.id, bus=bus_name)
        expected_master = joint.options["feedback_id"]
        if not DIALECTS[joint.options["dialect"]].registers:
            findings.append(Finding("scan", found="not scanned", expected="an answer to a register read",
                                    fix=f"a {joint.options['dialect']} motor has no registers: check it with "
                                        "servodyn doctor", severity=WARNING, **where))
            continue
        here = [f for f in found if f.id == joint.id]
        if not here:
            if fresh:
                fix = (f"a factory-fresh motor answers at CAN ID {fresh[0].id}: if it is this joint's, connect it "
                       f"alone and run {SETUP} for joint '{joint.dof}'")
            else:
                fix = ("check the motor's power (24 V), its CAN_H/CAN_L wiring to this bus, the 120 ohm terminators "
                       "and the bitrate")
            findings.append(Finding("reply", found="no reply", expected=f"an answer on Master ID 0x{expected_master:X}",
                                    fix=fix, **where))
            continue
        answers = max(f.extra.get("answers", 1) for f in here)
        if answers > 1:
            findings.append(Finding("CAN ID", found=f"{answers} motors answer", expected="one motor",
                                    fix=f"connect the motors one at a time and run {SETUP} for each joint", **where))
        f = next((f for f in here if f.extra.get("master_id") == expected_master), here[0])
        master = f.extra.get("master_id")
        if master != expected_master:
            what = f"0x{master:X}" + (" (as from the factory)" if master == FACTORY_MASTER_ID else "")
            findings.append(Finding("Master ID", found=what, expected=f"0x{expected_master:X}",
                                    fix=f"run {SETUP} for joint '{joint.dof}' with only its motor connected "
                                        "(writes its ids, MIT mode and ranges, and saves them)", **where))
        mode = f.extra.get("ctrl_mode")
        if mode is not None and mode != MIT_MODE:
            findings.append(Finding("CTRL_MODE", found=f"{mode} ({CTRL_MODES.get(mode, 'unknown')})",
                                    expected=f"{MIT_MODE} (MIT)",
                                    fix=f"in any other mode the motor ignores MIT frames without a word: run {SETUP} "
                                        f"for joint '{joint.dof}'", **where))
    known = {j.id for j in joints}
    feedback = {j.options["feedback_id"]: j.dof for j in joints}
    for f in found:
        if f.id in known:
            continue                                     # a second motor on a joint's id: named above
        master = f.extra.get("master_id")
        if master == FACTORY_MASTER_ID:
            fix = (f"a factory-fresh motor: connect it alone and run {SETUP} for the joint it drives"
                   if f.id == FACTORY_CAN_ID else f"connect it alone and run {SETUP} for the joint it drives")
        else:
            fix = f"remove it from bus '{bus_name}', or run {SETUP} for the joint it drives"
        clash = feedback.get(master)
        if clash:
            fix += f" (its frames come on joint '{clash}''s Master ID)"
        findings.append(Finding("unexpected motor", found=f"a motor with Master ID 0x{master:X}",
                                expected="no motor at this CAN ID", fix=fix, id=f.id, bus=bus_name,
                                severity=ERROR if clash or master == FACTORY_MASTER_ID else WARNING))
    return findings


# ---------------------------------------------------------------- doctor
def doctor(config, bus_name: str, bus, *, ids: Iterable[int] = range(1, MAX_ID + 1), listen: float = SCAN_LISTEN,
           timeout: float = REPLY_TIMEOUT) -> list[Finding]:
    """Read-only: compare()'s findings, then for each joint's motor that answers where it should
    its PMAX/VMAX/TMAX against the joint's ranges, its status (a latched fault named, with what to
    do) and its MOS and coil temperatures against its OT limit; and the error frames seen meanwhile
    (no ACK: power, bitrate, terminators). Nothing is written."""
    link = CanLink(bus_name, bus, timeout=timeout, errors=[])
    found, _ = _scan(link, ids, listen, config.buses[bus_name].baud)
    findings = compare(config, bus_name, found)
    for joint in config.joints_on(bus_name):
        f = next((f for f in found if f.id == joint.id and f.extra.get("master_id") == joint.options["feedback_id"]),
                 None)
        if f is None or not DIALECTS[joint.options["dialect"]].registers:
            continue                                     # compare() named it
        where = dict(joint=joint.dof, id=joint.id, bus=bus_name)
        reply = {f.extra["reply_id"]}
        ranges = joint.options["ranges"]
        for rid, name in RANGE_REGISTERS.items():
            value = _read(link, joint.id, rid, reply)
            if value is not None and not range_matches(value, getattr(ranges, name)):
                findings.append(Finding(name.upper().replace("_", ""), found=f"{value:g}",
                                        expected=f"{getattr(ranges, name):g}",
                                        fix=f"every frame would be scaled wrong: run {SETUP} for joint '{joint.dof}' "
                                            "(writes the configuration's ranges)", **where))
        code = f.extra.get("status_code")
        limit = _read(link, joint.id, REG_OT, reply)
        hot = [(k, f.extra.get(key)) for k, key in (("MOS", "mos_temperature"), ("coil", "coil_temperature"))]
        heat = ", ".join(f"{k} {t} °C" for k, t in hot if t is not None)
        if code is None:
            findings.append(Finding("status", found="no answer to a status request", expected="a feedback frame",
                                    fix="check the motor's firmware (it answers register reads but not 0xCC)", **where))
        elif code not in (DAMIAO_DISABLED, DAMIAO_ENABLED):
            what = f"{f.extra['status']} (0x{code:X})" + (f" at {heat}" if code in (0xB, 0xC) and heat else "")
            limit_text = f", limit {limit:g} °C" if code in (0xB, 0xC) and limit is not None else ""
            findings.append(Finding("status", found=what + limit_text, expected="no fault",
                                    fix=STATUS_FIX.get(code, f"run {CLEAR}"), **where))
            continue                                     # an over-temperature is named once, here
        if limit is None:
            continue
        for k, t in hot:
            if t is not None and t >= limit - TEMPERATURE_MARGIN:
                findings.append(Finding(f"{k} temperature", found=f"{t} °C", expected=f"below {limit:g} °C (OT)",
                                        fix="let the motor cool before a run; lighter loads or a slower motion",
                                        severity=ERROR if t >= limit else WARNING, **where))
    findings += _error_findings(link.errors, bus_name)
    return findings


def _error_findings(errors: list, bus_name: str) -> list[Finding]:
    """One finding per error class seen (each once), with what to check (frames.ERROR_CLASSES)."""
    seen, findings = set(), []
    for arbitration_id, data in errors:
        stops, _ = frames.error_frame(arbitration_id, data)
        for name, hint in frames.error_classes(arbitration_id) or [("error frame", "an unknown error class")]:
            if name not in seen:
                seen.add(name)
                findings.append(Finding("error frame", found=name, expected="none", fix=hint, bus=bus_name,
                                        severity=ERROR if stops else WARNING))
    return findings


# ---------------------------------------------------------------- setup
NAMES = {REG_ESC_ID: "CAN ID (ESC_ID)", REG_MST_ID: "Master ID", REG_CTRL_MODE: "CTRL_MODE",
         **{rid: name.upper().replace("_", "") for rid, name in RANGE_REGISTERS.items()}}


def _show(rid: int, value) -> str:
    if value is None:
        return "?"
    return (f"0x{int(value):X}" if rid == REG_MST_ID else
            f"{int(value)} ({CTRL_MODES.get(int(value), '?')})" if rid == REG_CTRL_MODE else f"{value:g}")


def _same(rid: int, a, b) -> bool:
    return a is not None and (range_matches(a, b) if rid in RANGE_REGISTERS else a == b)


@dataclass(frozen=True)
class Step:
    """One register write of a set-up: the register, its value now (None: it did not answer) and
    the value it gets."""
    rid: int
    old: float | None
    new: float

    @property
    def what(self) -> str:
        return NAMES[self.rid]

    def line(self) -> str:
        return f"{self.what}: {_show(self.rid, self.old)} -> {_show(self.rid, self.new)}"


def find_alone(bus, joint, from_id: int | None = None, *, listen: float = SCAN_LISTEN,
               timeout: float = REPLY_TIMEOUT) -> Found:
    """The one motor on the bus (at `from_id`, or at any CAN ID) for the joint's set-up; one line's
    error for a joint whose motor has no registers, no motor, several, or another model."""
    if not DIALECTS[joint.options["dialect"]].registers:
        raise ServoInitializationError(f"joint '{joint.dof}': a {joint.options['dialect']} motor has no registers "
                                       "to set up over CAN: use its vendor's tool")
    link = CanLink(_name(bus), bus, timeout=timeout)
    found, _ = _scan(link, range(1, MAX_ID + 1) if from_id is None else [from_id], listen, Can.default_baud)
    where = f"CAN ID {from_id}" if from_id is not None else "any CAN ID"
    if not found:
        raise ServoInitializationError(
            f"joint '{joint.dof}': no motor answered at {where}: check its power (24 V), the CAN wiring, the "
            "120 ohm terminators and the bitrate")
    per_id = {f.id: f.extra["answers"] for f in found}
    if sum(per_id.values()) > 1:
        ids = ", ".join(str(i) for i, n in per_id.items() for _ in range(n))
        raise ServoInitializationError(
            f"joint '{joint.dof}': {sum(per_id.values())} motors answer (CAN IDs {ids}): "
            "connect only this joint's motor and run setup again")
    motor = found[0]
    if motor.model is not None and motor.model != joint.servo.name:
        raise ServoInitializationError(
            f"joint '{joint.dof}' is configured for a {joint.servo.name}, the motor found is a {motor.model} "
            f"(its gear ratio register): connect the joint's own motor, or correct 'motor' in the configuration")
    return motor


def describe(motor: Found) -> str:
    return f"found {motor.model or 'a Damiao motor'} at CAN ID {motor.id}, Master ID 0x{motor.extra['master_id']:X}"


def setup_plan(bus, motor: Found, joint, *, timeout: float = REPLY_TIMEOUT) -> list[Step]:
    """The register writes that make `motor` the joint's: its CAN ID (ESC_ID), Master ID, CTRL_MODE
    MIT and PMAX/VMAX/TMAX from the joint's ranges, each read first (nothing is written)."""
    link = CanLink(_name(bus), bus, timeout=timeout)
    ranges = joint.options["ranges"]
    wanted = [(REG_ESC_ID, joint.id), (REG_MST_ID, joint.options["feedback_id"]), (REG_CTRL_MODE, MIT_MODE),
              *[(rid, getattr(ranges, name)) for rid, name in RANGE_REGISTERS.items()]]
    steps = []
    for rid, value in wanted:
        before = _read(link, motor.id, rid, {motor.extra["reply_id"]})
        if not _same(rid, before, value):
            steps.append(Step(rid, before, value))
    return steps


def apply_setup(bus, motor: Found, joint, steps: list[Step], written: list | None = None, *,
                timeout: float = REPLY_TIMEOUT) -> list[str]:
    """The steps written to a disabled motor (RAM), each checked by reading it back and appended to
    `written` once taken, then saved to flash (a save is taken only from a disabled motor). The
    lines of what was done."""
    link = CanLink(_name(bus), bus, timeout=timeout)
    can_id, reply_id = motor.id, motor.extra["reply_id"]
    _special(link, can_id, frames.EXIT)
    lines = [f"disabled it ({frames.SPECIALS[frames.EXIT]})"]
    for step in steps:
        answer = link.register(can_id, frames.REG_WRITE, step.rid, register_bits(step.rid, step.new),
                               answer_ids={can_id, joint.id})
        if step.rid == REG_ESC_ID:
            can_id = int(step.new)
        elif step.rid == REG_MST_ID:
            reply_id = int(step.new)
        after = _read(link, can_id, step.rid, {reply_id})
        if not _same(step.rid, after, step.new):
            raise ServoInitializationError(
                f"joint '{joint.dof}': the motor did not take {step.what} = {_show(step.rid, step.new)} "
                f"({'no echo' if answer is None else 'echoed'}, reads back {_show(step.rid, after)}): "
                "power-cycle it and run setup again")
        if written is not None:
            written.append(step)
        lines.append(step.line())
    _special(link, can_id, frames.EXIT)          # a save is taken only from a disabled motor
    answer = link.register(can_id, frames.REG_STORE, 1, reply_ids={reply_id})
    lines.append("saved to flash" + (" (the motor confirmed)" if answer is not None else
                                     ": sent, the motor sent no confirmation (not every firmware does): "
                                     "power-cycle it and run servodyn scan to check"))
    return lines


def setup(bus, joint_config, from_id: int | None = None, confirm: Callable[[str], bool] = lambda what: False, *,
          listen: float = SCAN_LISTEN, timeout: float = REPLY_TIMEOUT) -> list[str]:
    """With only this joint's motor on the bus: find it (find_alone), plan its writes (setup_plan),
    then, only if `confirm(what)` says yes to the whole plan (`what` names every change and the
    flash's wear: about 10,000 saves), write and save them (apply_setup). The lines of what was
    found and done; a "no" writes nothing."""
    joint = joint_config
    motor = find_alone(bus, joint, from_id, listen=listen, timeout=timeout)
    steps = setup_plan(bus, motor, joint, timeout=timeout)
    lines = [describe(motor)]
    if not steps:
        return lines + ["nothing to write"]
    what = (f"write {'; '.join(s.line() for s in steps)} to joint '{joint.dof}''s motor and save them to its "
            f"flash (it lasts about {FLASH_CYCLES:,} saves)")
    if not confirm(what):
        return lines + ["nothing written"]
    return lines + apply_setup(bus, motor, joint, steps, timeout=timeout)


def _special(link: CanLink, can_id: int, code: int) -> None:
    """A special frame (frames.SPECIALS); its answer, if any, is taken with the next reads."""
    link.send(can_id, frames.pack_special(code))


# ---------------------------------------------------------------- zero, clear, torque off
def zero(bus, joint, confirm: Callable[[str], bool], *, timeout: float = REPLY_TIMEOUT) -> frames.Reply:
    """The motor's present position becomes its zero, if `confirm(what)` says yes: disable, set
    zero (FE), disable (as openarm_can's zero command). The motor's state read after (its p is
    the motor's, 0 here when done); the joint's zero_offset is then 0 at this pose."""
    link = CanLink(_name(bus), bus, timeout=timeout)
    if confirm(f"set the zero of joint '{joint.dof}' (motor {joint.id}) where it stands now; the motor keeps it"):
        for code in (frames.EXIT, frames.SET_ZERO, frames.EXIT):
            _special(link, joint.id, code)
            _collect(link, [joint])
    return _states(link, [joint])[joint.dof]


def clear_errors(bus, joints, *, timeout: float = REPLY_TIMEOUT) -> dict[str, frames.Reply]:
    """Clear each Damiao motor's latched fault (FB; an over-temperature stays until the motor has
    cooled); each joint's state read after, by dof."""
    link = CanLink(_name(bus), bus, timeout=timeout)
    damiao = [j for j in joints if DIALECTS[j.options["dialect"]].registers]
    for joint in damiao:
        _special(link, joint.id, frames.CLEAR_ERROR)
    _collect(link, damiao)
    return _states(link, joints)


def torque_off(bus, joints, *, timeout: float = REPLY_TIMEOUT) -> dict[str, frames.Reply]:
    """Exit motor mode (FD) on every joint's motor, each sent its frame; each state read after."""
    link = CanLink(_name(bus), bus, timeout=timeout)
    for joint in joints:
        _special(link, joint.id, frames.EXIT)
    _collect(link, joints)
    return _states(link, joints)


def states(bus, joints, *, timeout: float = REPLY_TIMEOUT, partial: bool = False) -> dict[str, frames.Reply]:
    """Each joint's state as its motor reports it now, changing nothing (monitor, calibrate);
    `partial`: a motor that does not answer is left out rather than an error."""
    return _states(CanLink(_name(bus), bus, timeout=timeout), joints, partial)


def _states(link: CanLink, joints, partial: bool = False) -> dict[str, frames.Reply]:
    """Each joint's state as its motor reports it now: a Damiao motor's answer to a status request
    (0xCC, which changes nothing), another dialect's to exit motor mode (its only question)."""
    for joint in joints:
        if DIALECTS[joint.options["dialect"]].registers:
            link.send(frames.REGISTER_ID, frames.pack_register(frames.Register(joint.id, frames.REG_REFRESH, 0)))
        else:
            _special(link, joint.id, frames.EXIT)
    return _collect(link, joints, partial)


def _collect(link: CanLink, joints, partial: bool = False) -> dict[str, frames.Reply]:
    """One answer from each joint's motor, on its Master ID, within the link's timeout (`partial`:
    those that answered; else a silent one is a ServoTimeoutError)."""
    pending = {(j.options["feedback_id"], j.id): j for j in joints}
    states = {}
    deadline = time.monotonic() + link.timeout
    while pending and (left := deadline - time.monotonic()) > 0 and (msg := link.recv(left)) is not None:
        data = bytes(msg.data)
        for (reply_id, can_id), joint in list(pending.items()):
            dialect = DIALECTS[joint.options["dialect"]]
            if msg.arbitration_id != reply_id or len(data) not in dialect.reply_length:
                continue
            if dialect.registers and not _is_feedback(data, can_id):
                continue
            if not dialect.registers and dialect.reply_key(data) != can_id:
                continue
            states[joint.dof] = dialect.unpack(joint.options["ranges"], data)
            del pending[(reply_id, can_id)]
            break
    if pending and not partial:
        (reply_id, can_id), joint = next(iter(pending.items()))
        raise ServoTimeoutError(joint.dof, can_id, f"no answer on Master ID 0x{reply_id:X}: run servodyn doctor")
    return states
