"""Bring-up commands: from a box of servos to an arm that moves. `scan`, `setup`, `doctor`,
`reboot`, `clear-errors` and `torque off` here, `monitor` (monitor.py) and `calibrate`
(calibrate.py) beside, on every bus a configuration names. Each bus is driven through its
kind's bring-up (hal.bringup.BringUp, found by name from the backend: hal.dynamixel.session,
hal.can.session, hal.feetech.session), so nothing here knows a bus kind; the host's side (ports,
permissions, latency timer) is hal.ports and hal.port_access.

Every command that writes to a servo says what it will write first and asks `confirm(question)`
(the command line's question, which `--yes` answers); a command that moves nothing but switches
torque off says so before it does. Each
command's error is one line: a BringUpError (a ServodynError) with its exit status.
"""

from __future__ import annotations

import functools
import json
import time

from ...errors import ServodynError
from ...hal import port_access, ports as hal_ports
from ...hal import bringup as hal_bringup
from ...hal.bringup import ERROR, Finding, bringup_class, bringup_for_path, session
from ...hal.errors import HalError
from ...hal.realtime import LOOP_PRIORITY
from . import calibrate as _calibrate, monitor as _monitor


class BringUpError(ServodynError):
    """One line for the user; `code` (= exit_code) the exit status (2 bad input, 1 findings, or the
    HAL error's own: 10 a device silent, 12 a port lost or a write refused)."""

    def __init__(self, message: str, code: int = 2):
        super().__init__(message)
        self.code = self.exit_code = int(code)


def command(run):
    """A bring-up command whose HAL errors (a ServodynError of the HAL's tree) end it as one
    line, a BringUpError with the error's exit status."""
    @functools.wraps(run)
    def one_line(*args, **kwargs):
        try:
            return run(*args, **kwargs)
        except HalError as err:
            raise BringUpError(str(err), err.exit_code) from None
    return one_line


config_and_ports = command(hal_bringup.config_and_ports)
monitor = command(_monitor.monitor)
calibrate = command(_calibrate.calibrate)
wait_enter = command(_calibrate.wait_enter)


def _print_findings(findings: list[Finding], say=print) -> None:
    for f in findings:
        say(("  ! " if f.severity == ERROR else "  ~ ") + f.line())


# ---------------------------------------------------------------------------- scan

@command
def scan(port: str | None, bauds: str | None, config_name: str | None, as_json: bool, say=print) -> int:
    config = None
    if config_name is not None:
        config, ports = hal_bringup.config_and_ports(config_name, port)
        buses = [(bringup_class(config.buses[bus].kind), bus, path) for bus, path in ports.items()]
    elif port is None:
        raise BringUpError("scan: give --port PATH (`servodyn ports` lists the adapters) or --config FILE")
    else:
        path = port[0] if isinstance(port, list) else port
        buses = [(bringup_for_path(path), None, path)]
    rates = {bus: kind.scan_rates(bauds, config.buses[bus] if config else None) for kind, bus, _ in buses}
    everything, findings = [], []
    for kind, bus, path in buses:
        with kind(config, bus, path) as here:
            if not as_json:
                say(here.scanning(rates[bus]))
            result = here.scan(rates[bus])
            if config is not None:
                findings += here.compare(result)
        everything += result.found
        if not as_json:
            for line in result.lines:
                say(line)
    if as_json:
        say(json.dumps([f.as_json() for f in everything], indent=1))
    elif config is not None:
        if findings:
            say(f"against '{config.name}':")
            _print_findings(findings, say)
        else:
            say(f"every servo and motor of '{config.name}' is where the configuration says")
    if any(f.severity == ERROR for f in findings):
        return 1
    return 0 if everything or config is not None else 1


# ---------------------------------------------------------------------------- setup

@command
def setup(config_name: str, joint_name: str, port, confirm, say=print) -> int:
    config, ports = hal_bringup.config_and_ports(config_name, port)
    joint = next((j for j in config.joints if j.dof == joint_name), None)
    if joint is None:
        raise BringUpError(f"'{config.name}' has no joint '{joint_name}' (joints: "
                           f"{', '.join(j.dof for j in config.joints)})")
    with session(config, joint.bus, ports[joint.bus]) as here:
        say(here.looking())
        found, line = here.find_alone(joint)
        say(line)
        steps = here.setup_plan(found, joint)
        if not steps:
            say(here.already(joint))
            return 0
        say(here.setup_intro(joint))
        for step in steps:
            say(f"  {step.line()}")
        if not confirm("write these?"):
            say("nothing written")
            return 1
        written: list = []
        try:
            done = here.apply_setup(found, joint, steps, written)
        except HalError as err:
            raise BringUpError(f"{err}; {here.setup_lost(steps, written)}", err.exit_code) from None
    for line in done:
        say(line)
    return 0


# ---------------------------------------------------------------------------- doctor

def host_findings(path: str) -> list[Finding]:
    """The host's side of a port: exists, permission, held by another process, latency timer. A
    pseudo-terminal is the simulator's, which holds its other end, and a SocketCAN link no file:
    none of these apply."""
    if hal_ports.is_pseudo_terminal(path) or not path.startswith("/"):
        return []
    return list(port_access.port_findings(path))


@command
def doctor(config_name: str, port, as_json: bool, say=print) -> int:
    config, ports = hal_bringup.config_and_ports(config_name, port)
    findings: list[Finding] = list(port_access.realtime_findings(priority=LOOP_PRIORITY))
    started = time.monotonic()
    for bus, path in ports.items():
        here = host_findings(path)
        findings += here
        if any(f.severity == ERROR and f.check in ("port", "permission") for f in here):
            continue
        with session(config, bus, path) as open_bus:
            findings += open_bus.doctor()
    elapsed = time.monotonic() - started
    errors = [f for f in findings if f.severity == ERROR]
    if as_json:
        say(json.dumps({"findings": [f.as_json() for f in findings]}, indent=1))
    else:
        n = sum(len(config.joints_on(b)) for b in ports)
        if findings:
            _print_findings(findings, say)
        say(f"{n} servos on {len(ports)} bus{'es' * (len(ports) != 1)} checked in {elapsed:.2f} s: "
            + (f"{len(errors)} problem{'s' * (len(errors) != 1)}" if errors else "all well")
            + (f", {len(findings) - len(errors)} warning{'s' * (len(findings) - len(errors) != 1)}"
               if len(findings) > len(errors) else ""))
    return 1 if errors else 0


# ---------------------------------------------------------------------------- recovery

def _each_bus(config_name, port, act, say) -> int:
    """`act(session)` on each bus (a line saying what it did, each joint's outcome), said; 1 when
    a joint is not as asked."""
    config, ports = hal_bringup.config_and_ports(config_name, port)
    failed = 0
    for bus, path in ports.items():
        with session(config, bus, path) as here:
            header, outcomes = act(here)
        say(header)
        for o in outcomes:
            failed += not o.ok
            say(f"  {o.joint.dof:<24} id {o.joint.id:>3}: {o.text}")
    return 1 if failed else 0


@command
def torque_off(config_name: str, port, say=print) -> int:
    return _each_bus(config_name, port, lambda here: here.torque_off(), say)


@command
def reboot(config_name: str, port, confirm, say=print) -> int:
    hal_bringup.config_and_ports(config_name, port)
    say("reboot: each servo restarts with torque off; a joint under load falls (support the arm)")
    if not confirm("reboot every servo?"):
        say("nothing sent")
        return 1
    return _each_bus(config_name, port, lambda here: here.reboot(), say)


@command
def clear_errors(config_name: str, port, say=print) -> int:
    return _each_bus(config_name, port, lambda here: here.clear_errors(), say)
