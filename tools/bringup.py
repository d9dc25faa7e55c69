"""Bring-up commands: from a box of servos to an arm that moves. `scan`, `setup`, `doctor`,
`monitor`, `calibrate`, `reboot`, `clear-errors` and `torque off`, on every bus a configuration
names; each bus kind's protocol work is its bench module (hal.dynamixel.bringup, hal.can.bringup), the
host's (ports, permissions, latency timer) hal.ports.

Every command that writes to a servo says what it will write first and asks (`--yes` skips the
question); a command that moves nothing but switches torque off says so before it does.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable


from ..hal import port_access, ports as hal_ports
from ..hal.realtime import LOOP_PRIORITY
from ..errors import ExitCode, ServodynError
from ..hal.bringup import ERROR, Finding
from ..hal.can import bringup as can_bench
from ..hal.can.dialects import CTRL_MODES, DAMIAO_DISABLED, DAMIAO_ENABLED, DAMIAO_STATUS
from ..hal.can.link import open_bus
from ..hal.can.spec import SOCKETCAN_NAME, Can, interface_for
from ..hal.config import RobotConfig, load_config
from ..hal.dynamixel import bringup as dxl
from ..hal.dynamixel.control_table import BAUD_RATES, ITEMS, TABLE_SIZE
from ..hal.dynamixel.units import ServoMap
from ..hal.errors import ConfigError, ServoError
from ..hal.config_patch import ConfigPatch
from .cli.prompt import ask
from ..hal.ports import bus_ports


class BringUpError(ServodynError):
    """One line for the user; `code` the exit status (2 bad input, 1 findings)."""

    def __init__(self, message: str, code: int = ExitCode.BAD_INPUT):
        super().__init__(message)
        self.exit_code = code


# ---------------------------------------------------------------------------- shared

def config_and_ports(config_name: str, port) -> tuple[RobotConfig, dict[str, str]]:
    """The configuration and the real port of each of its buses; one line when a bus has none."""
    try:
        config = load_config(config_name)
        ports = bus_ports(config, port)
    except (ConfigError, ValueError) as err:
        raise BringUpError(str(err)) from None
    if not ports:
        raise BringUpError(f"'{config.name}' names no real port (port = \"auto\" is the simulated bus): give "
                           "--port PATH (`servodyn ports` lists the adapters)")
    return config, ports


def wait_enter(prompt: str, say: Callable = print) -> None:
    """A step a person does by hand, then Enter; end of input stops the command."""
    say(f"{prompt} [Enter] ", end="", flush=True)
    if not sys.stdin.readline():
        say("")
        raise BringUpError("no more input: stopped before the end (nothing was written)")


def _link(path: str, baud: int) -> dxl.Link:
    link = dxl.Link(path, baud)
    try:
        link.open()
    except ServoError as err:
        raise BringUpError(str(err)) from None
    return link


def _kind(config: RobotConfig, bus: str) -> str:
    kind = config.buses[bus].kind
    if kind not in ("dynamixel", "can"):
        raise BringUpError(f"bus '{bus}' is a {kind} bus: bring-up speaks Dynamixel and CAN")
    return kind


class _CanPort:
    """A CAN bus of the configuration opened with python-can: the interface its channel names
    (can0: SocketCAN, a /dev path: an SLCAN adapter), at the configured bit rate."""

    def __init__(self, config: RobotConfig | None, bus: str | None, channel: str):
        """Without a configuration (a scan of a bare channel): the channel's interface, the CAN
        backend's default bit rate."""
        spec = config.buses[bus] if config is not None else None
        self.channel = channel
        self.interface = interface_for(channel, spec.options.get("interface") if spec else None)
        self.bitrate = spec.baud if spec else Can.default_baud
        self.bus = None

    def __enter__(self):
        try:
            self.bus = open_bus(self.channel, self.interface, self.bitrate)
        except ServoError as err:
            raise BringUpError(str(err)) from None
        return self.bus

    def __exit__(self, *exc):
        if self.bus is not None:
            self.bus.shutdown()


def _can_state(reply) -> str:
    if reply is None:
        return "did not answer"
    return f"{DAMIAO_STATUS.get(reply.status, f'status 0x{reply.status:X}')}, at {math.degrees(reply.p):.1f}°"


def _print_findings(findings: list[Finding], say=print) -> None:
    for f in findings:
        say(("  ! " if f.severity == ERROR else "  ~ ") + f.line())


# ---------------------------------------------------------------------------- scan

def parse_bauds(text: str | None) -> tuple[int, ...]:
    """--baud: "all" (every rate, the factory's first) or a comma list of rates."""
    if text in (None, "all"):
        return dxl.SCAN_RATES
    rates = []
    for part in text.split(","):
        try:
            rate = int(part.strip())
        except ValueError:
            raise BringUpError(f"--baud: {part!r} is not a rate (all, or some of {', '.join(map(str, BAUD_RATES))})") from None
        if rate not in BAUD_RATES:
            raise BringUpError(f"--baud: {rate} is not a Dynamixel X rate ({', '.join(map(str, BAUD_RATES))})")
        rates.append(rate)
    return tuple(dict.fromkeys(rates))


def scan(port: str | None, bauds: str | None, config_name: str | None, as_json: bool, say=print) -> int:
    config = None
    if config_name is not None:
        config, ports = config_and_ports(config_name, port)
        buses = {name: ports[name] for name in ports if _kind(config, name)}
    elif port is None:
        raise BringUpError("scan: give --port PATH (`servodyn ports` lists the adapters) or --config FILE")
    else:
        buses = {None: port[0] if isinstance(port, list) else port}
    rates = parse_bauds(bauds)
    everything, findings = [], []
    for bus, path in buses.items():
        if (config is not None and config.buses[bus].kind == "can") or (config is None and SOCKETCAN_NAME.match(path)):
            found, more = _scan_can(config, bus, path, as_json, say)
            everything += found
            findings += more
            continue
        if not as_json:
            say(f"scanning {path} at {', '.join(map(str, rates))} baud, IDs 0-{dxl.MAX_ID} (broadcast ping) ...")
        with _link(path, rates[0]) as link:
            result = dxl.scan(link, rates)
        everything += result.found
        if config is not None:
            findings += dxl.compare(config, bus, result)
        if not as_json:
            if result.found:
                say(f"  {'ID':>3}  {'model':<12} {'number':>6} {'firmware':>8} {'baud':>8}")
                for f in sorted(result.found, key=lambda f: (f.baud, f.id)):
                    say(f"  {f.id:>3}  {f.model or '?':<12} {f.model_number:>6} {f.firmware:>8} {f.baud:>8}")
            for baud, ids in sorted(result.collisions.items()):
                say(f"  several servos answer at ID {', '.join(map(str, sorted(ids)))} at {baud} baud "
                    "(their replies collide): connect one at a time")
            say(f"{len(result.found)} servo{'s' * (len(result.found) != 1)} in {result.seconds:.2f} s")
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


def _scan_can(config, bus, path, as_json, say):
    """A CAN bus: register reads to every id (no torque), replies heard on every id."""
    port = _CanPort(config, bus, path)
    heard: list[str] = []
    if not as_json:
        say(f"scanning {path} ({port.interface}, {port.bitrate} bit/s), CAN IDs 1-{can_bench.MAX_ID} "
            "(register reads: no torque) ...")
    started = time.monotonic()
    with port as can_bus:
        found = can_bench.scan(can_bus, bitrate=port.bitrate, heard=heard)
    findings = can_bench.compare(config, bus, found) if config is not None else []
    if not as_json:
        if found:
            say(f"  {'CAN ID':>6}  {'model':<10} {'master':>6} {'mode':<18} status")
            for f in found:
                x = f.extra
                say(f"  {f.id:>6}  {f.model or '?':<10} {'0x%X' % x['master_id'] if x.get('master_id') is not None else '?':>6} "
                    f"{CTRL_MODES.get(x.get('ctrl_mode'), str(x.get('ctrl_mode'))):<18} {x.get('status', '?')}")
        for line in heard:
            say(f"  {line}")
        say(f"{len(found)} motor{'s' * (len(found) != 1)} in {time.monotonic() - started:.2f} s")
    return found, findings


# ---------------------------------------------------------------------------- setup

def setup(config_name: str, joint_name: str, port, yes: bool, say=print) -> int:
    config, ports = config_and_ports(config_name, port)
    joint = next((j for j in config.joints if j.dof == joint_name), None)
    if joint is None:
        raise BringUpError(f"'{config.name}' has no joint '{joint_name}' (joints: "
                           f"{', '.join(j.dof for j in config.joints)})")
    bus = config.buses[joint.bus]
    path = ports[joint.bus]
    if _kind(config, joint.bus) == "can":
        say(f"looking for the one motor on {path} (every CAN ID) ...")
        with _CanPort(config, joint.bus, path) as can_bus:
            try:
                lines = can_bench.setup(can_bus, joint, confirm=lambda what: ask(what, yes, say))
            except ServoError as err:
                raise BringUpError(str(err)) from None
        for line in lines:
            say(f"  {line}")
        return 0
    say(f"looking for the one servo on {path} (every rate, every ID) ...")
    with _link(path, dxl.FACTORY_BAUD) as link:
        try:
            found = dxl.find_alone(link)
            say(f"found {found.model or found.model_number} at ID {found.id}, {found.baud} baud, firmware {found.firmware}")
            steps = dxl.setup_plan(link, found, joint, bus)
        except ServoError as err:
            raise BringUpError(str(err)) from None
        if not steps:
            say(f"it is already set up as joint '{joint.dof}' (ID {joint.id}, {bus.baud} baud): nothing to write")
            return 0
        say(f"setup writes to this servo's EEPROM, torque off, to make it joint '{joint.dof}':")
        for step in steps:
            say(f"  {step.line()}")
        if not ask("write these?", yes, say):
            say("nothing written")
            return 1
        try:
            after = dxl.apply_setup(link, found, steps, bus.baud)
        except ServoError as err:
            raise BringUpError(str(err)) from None
    say(f"done: joint '{joint.dof}' answers at ID {after.id}, {after.baud} baud ({after.model})")
    return 0


# ---------------------------------------------------------------------------- doctor

def host_findings(path: str) -> list[Finding]:
    """The host's side of a port: exists, permission, held by another process, latency timer. A
    pseudo-terminal is the simulator's, which holds its other end: none of these apply."""
    if hal_ports.is_pseudo_terminal(path):
        return []
    return list(port_access.port_findings(path))


def doctor(config_name: str, port, as_json: bool, say=print) -> int:
    config, ports = config_and_ports(config_name, port)
    findings: list[Finding] = list(port_access.realtime_findings(priority=LOOP_PRIORITY))
    started = time.monotonic()
    for bus, path in ports.items():
        if _kind(config, bus) == "can":
            with _CanPort(config, bus, path) as can_bus:
                findings += can_bench.doctor(config, bus, can_bus)
            continue
        here = host_findings(path)
        findings += here
        if any(f.severity == ERROR and f.check in ("exists", "permission") for f in here):
            continue
        with _link(path, config.buses[bus].baud) as link:
            findings += dxl.doctor(config, bus, link)
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

def _each_bus(config_name, port, what: str, say, act, can_act=None) -> int:
    """`act(link, joints, bus)` on each Dynamixel bus, `can_act(can_bus, joints, bus)` on each CAN
    bus (default: each motor's state after clearing its errors); the count of joints that failed."""
    config, ports = config_and_ports(config_name, port)
    failed = 0
    for bus, path in ports.items():
        joints = config.joints_on(bus)
        if _kind(config, bus) == "can":
            with _CanPort(config, bus, path) as can_bus:
                failed += (can_act or _can_clear)(can_bus, joints, bus, say)
            continue
        with _link(path, config.buses[bus].baud) as link:
            failed += act(link, joints, bus)
    return 1 if failed else 0


def _report_can(states, joints, say, good) -> int:
    bad = 0
    for joint in joints:
        reply = states.get(joint.dof)
        ok = reply is not None and good(reply)
        bad += not ok
        say(f"  {joint.dof:<24} id {joint.id:>3}: {_can_state(reply)}")
    return bad


def _can_clear(can_bus, joints, bus, say) -> int:
    say(f"bus '{bus}': each motor's latched error cleared (a CAN motor has no reboot; an over-temperature "
        "stays until it has cooled)")
    return _report_can(can_bench.clear_errors(can_bus, joints), joints, say,
                       lambda r: r.status in (DAMIAO_DISABLED, DAMIAO_ENABLED))


def _can_torque_off(can_bus, joints, bus, say) -> int:
    say(f"bus '{bus}': torque off, each motor out of motor mode")
    return _report_can(can_bench.torque_off(can_bus, joints), joints, say, lambda r: r.status != DAMIAO_ENABLED)


def torque_off(config_name: str, port, say=print) -> int:
    def act(link, joints, bus):
        say(f"bus '{bus}' ({link.path}): torque off, every servo at {link.baud} baud (broadcast)")
        state = dxl.torque_off(link, [j.id for j in joints])
        bad = 0
        for joint in joints:
            value = state[joint.id]
            bad += value != 0
            say(f"  {joint.dof:<24} id {joint.id:>3}: " + ("torque off" if value == 0 else
                "did not answer: switch its power off" if value is None else "still on: switch its power off"))
        return bad
    return _each_bus(config_name, port, "torque off", say, act, _can_torque_off)


def reboot(config_name: str, port, yes: bool, say=print) -> int:
    config, _ = config_and_ports(config_name, port)
    say("reboot: each servo restarts with torque off; a joint under load falls (support the arm)")
    if not ask("reboot every servo?", yes, say):
        say("nothing sent")
        return 1

    def act(link, joints, bus):
        state = dxl.reboot(link, [j.id for j in joints])
        bad = 0
        for joint in joints:
            value = state[joint.id]
            bad += value != 0
            say(f"  {joint.dof:<24} id {joint.id:>3}: " + (
                "did not come back" if value is None else "up, no hardware error" if value == 0 else
                f"up, hardware error 0x{value:02X} still set ({', '.join(dxl.hardware_faults(value))}): its cause "
                "is still there"))
        return bad
    return _each_bus(config_name, port, "reboot", say, act)


def clear_errors(config_name: str, port, say=print) -> int:
    def act(link, joints, bus):
        say(f"bus '{bus}' ({link.path}): a tripped Bus Watchdog written 0, hardware errors read")
        bad = 0
        state = dxl.clear_watchdog(link, [j.id for j in joints])
        for joint in joints:
            try:
                status = link.read(joint.id, "hardware_error_status")
            except ServoError:
                status = None
            if state[joint.id] is None or status is None:
                line, bad = "did not answer", bad + 1
            elif status:
                line = (f"bus watchdog clear; hardware error 0x{status:02X} ({', '.join(dxl.hardware_faults(status))}) "
                        "latched: only `servodyn reboot` (or a power cycle) clears it")
                bad += 1
            else:
                line = "no error"
            say(f"  {joint.dof:<24} id {joint.id:>3}: {line}")
        return bad
    return _each_bus(config_name, port, "clear errors", say, act)


# ---------------------------------------------------------------------------- monitor

MONITOR_START = ITEMS["torque_enable"].address          # Torque Enable .. Present Temperature in one read


def _open_limp(config, ports: dict, links: dict, then: str, say) -> None:
    """Open every bus into `links` (a Dynamixel Link or a _CanPort, by bus), torque off on each, said
    first with what comes `then`."""
    for bus, path in ports.items():
        what = "motor" if _kind(config, bus) == "can" else "servo"
        if what == "motor":
            links[bus] = port_ = _CanPort(config, bus, path)
            port_.__enter__()
        else:
            links[bus] = _link(path, config.buses[bus].baud)
        say(f"bus '{bus}' ({path}): torque off on every {what} {then}".replace(" :", ":"))
        if what == "motor":
            can_bench.torque_off(links[bus].bus, config.joints_on(bus))
        else:
            dxl.torque_off(links[bus], [j.id for j in config.joints_on(bus)])


def monitor(config_name: str, port, count: int | None, rate: float, say=print) -> int:
    """Torque off, then every joint's state, SI and raw, refreshed in place until Ctrl-C."""
    config, ports = config_and_ports(config_name, port)
    links = {}
    try:
        _open_limp(config, ports, links, "(support the arm), then read only", say)
        live = _live_table() if sys.stdout.isatty() and count is None else None
        shown = 0
        with live or _Plain(say) as out:
            while count is None or shown < count:
                out.update(_monitor_table(config, links))
                shown += 1
                if count is None or shown < count:
                    time.sleep(1.0 / rate)
    except KeyboardInterrupt:
        say("")
    finally:
        for link in links.values():
            link.__exit__(None, None, None) if isinstance(link, _CanPort) else link.close()
    return 0


class _Plain:
    """Monitor's output when not on a terminal: each refresh printed as a block."""

    def __init__(self, say):
        self.say = say

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, table) -> None:
        from rich.console import Console
        console = Console(width=140, force_terminal=False, color_system=None)
        with console.capture() as capture:
            console.print(table)
        self.say(capture.get().rstrip())


def _live_table():
    from rich.live import Live
    return Live(refresh_per_second=10, transient=False)


def _monitor_table(config, links):
    from rich.table import Table
    table = Table(title=f"{config.name}: torque off (Ctrl-C ends)", title_justify="left")
    for head in ("joint", "id", "q deg", "ticks", "qd rad/s", "vel raw", "I A", "cur raw", "°C", "V", "error"):
        table.add_column(head, justify="left" if head == "joint" else "right")
    for bus, link in links.items():
        joints = config.joints_on(bus)
        if isinstance(link, _CanPort):
            states = can_bench.states(link.bus, joints)
            for joint in joints:
                r = states.get(joint.dof)
                if r is None:
                    table.add_row(joint.dof, str(joint.id), *["-"] * 8, "no answer")
                    continue
                q = (r.p - joint.zero_offset) / (joint.direction * joint.gear_ratio)
                qd = r.v / (joint.direction * joint.gear_ratio)
                table.add_row(joint.dof, str(joint.id), f"{math.degrees(q):8.2f}", f"{r.p:.4f} rad", f"{qd:7.3f}",
                              f"{r.v:.3f}", f"{r.t:6.3f} N·m", "-", f"{r.temperature}/{r.temperature2}", "-",
                              DAMIAO_STATUS.get(r.status, f"0x{r.status:X}"))
            continue
        for joint in joints:
            units = ServoMap.from_joints([joint])
            try:
                raw = dxl.decode_table(link.read_table(joint.id, MONITOR_START, TABLE_SIZE - MONITOR_START), MONITOR_START)
            except ServoError:
                table.add_row(joint.dof, str(joint.id), *["-"] * 8, "no answer")
                continue
            ticks, vel, cur = raw["present_position"], raw["present_velocity"], raw["present_current"]
            q, qd, amps = (float(units.from_ticks(ticks)[0]), float(units.from_velocity_units(vel)[0]),
                           float(units.current_from_units(cur)[0]))
            status = raw["hardware_error_status"]
            table.add_row(joint.dof, str(joint.id), f"{math.degrees(q):8.2f}", str(ticks), f"{qd:7.3f}", str(vel),
                          f"{amps:6.3f}", str(cur), str(raw["present_temperature"]),
                          f"{raw['present_input_voltage'] / 10:.1f}",
                          ", ".join(dxl.hardware_faults(status)) if status else "-")
    return table


# ---------------------------------------------------------------------------- calibrate

MIN_TRAVEL = math.radians(3.0)      # a "move it" step that turns the horn less is asked again


def calibrate(config_name: str, port, joints: list[str] | None, margin_deg: float, yes: bool,
              write_to: str | None, say=print) -> int:
    """Torque off; per joint: its + direction, its zero (the mean of two approaches), both stops;
    then the configuration patched (comments kept) after the change is shown and confirmed."""
    config, ports = config_and_ports(config_name, port)
    chosen = [j for j in config.joints if joints is None or j.dof in joints]
    unknown = sorted(set(joints or ()) - {j.dof for j in config.joints})
    if unknown:
        raise BringUpError(f"'{config.name}' has no joint '{unknown[0]}'")
    if not math.isfinite(margin_deg) or margin_deg < 0:
        raise BringUpError(f"--margin must be a finite number of degrees >= 0, got {margin_deg:g}")
    margin = math.radians(margin_deg)
    try:
        patch = ConfigPatch.of(config, write_to)
    except (ConfigError, OSError) as err:
        raise BringUpError(str(err)) from None
    links = {}
    results = {}
    try:
        _open_limp(config, ports, links, ": move the joints by hand", say)
        for joint in chosen:
            results[joint.dof] = _calibrate_joint(joint, _horn_reader(joint, links[joint.bus]), config, margin, say)
    finally:
        for link in links.values():
            link.__exit__(None, None, None) if isinstance(link, _CanPort) else link.close()
    for dof, values in results.items():
        patch.set_joint(dof, **values)
    try:
        return patch.offer(lambda question: ask(question, yes, say), say)
    except ConfigError as err:
        raise BringUpError(str(err)) from None


def _horn_reader(joint, link) -> Callable[[], float]:
    """The joint's horn (motor output) angle now, rad: a servo's Present Position, a CAN motor's
    reported position (its own zero kept: the configuration's zero_offset takes the pose)."""
    def horn() -> float:
        try:
            if isinstance(link, _CanPort):
                reply = can_bench.states(link.bus, [joint]).get(joint.dof)
                if reply is None:
                    raise BringUpError(f"joint '{joint.dof}' (motor {joint.id}) did not answer")
                return reply.p
            return dxl.horn_angles(link, [joint.id])[joint.id]
        except ServoError as err:
            raise BringUpError(f"joint '{joint.dof}': {err}") from None
    return horn


def _calibrate_joint(joint, horn: Callable[[], float], config, margin: float, say) -> dict:
    name = f"joint '{joint.dof}' (id {joint.id})"
    for _ in range(3):
        before = horn()
        wait_enter(f"{name}: move it a little (10-30°) in its + direction ({joint.dof} increasing)", say)
        travel = horn() - before
        if abs(travel) >= MIN_TRAVEL:
            break
        say(f"  it turned {math.degrees(travel):.1f}°, less than {math.degrees(MIN_TRAVEL):g}°: again")
    else:
        raise BringUpError(f"{name} did not move: is it the servo at id {joint.id}? (`servodyn monitor` shows them live)")
    direction = 1 if travel > 0 else -1
    wait_enter(f"{name}: put it in its zero pose, coming from the - side", say)
    low_side = horn()
    wait_enter(f"{name}: move it away, then back to its zero pose from the + side", say)
    high_side = horn()
    zero = (low_side + high_side) / 2
    backlash = abs(high_side - low_side)
    wait_enter(f"{name}: move it to its - stop", say)
    stop_a = horn()
    wait_enter(f"{name}: move it to its + stop", say)
    stop_b = horn()
    scale = direction * joint.gear_ratio
    q_stops = sorted(((stop_a - zero) / scale, (stop_b - zero) / scale))
    lower, upper = q_stops[0] + margin, q_stops[1] - margin
    model_lower, model_upper = (config.model.lower[config.model.dof_names.index(joint.dof)],
                                config.model.upper[config.model.dof_names.index(joint.dof)])
    clipped = lower < model_lower or upper > model_upper
    lower, upper = max(lower, model_lower), min(upper, model_upper)
    if not lower < upper:
        raise BringUpError(f"{name}: its stops ({math.degrees(q_stops[0]):.1f}° .. {math.degrees(q_stops[1]):.1f}°) "
                           f"leave no range inside a {math.degrees(margin):g}° margin and the model's limits")
    say(f"  direction {direction:+d}, zero at horn {math.degrees(zero):.2f}° (approaches {math.degrees(backlash):.2f}° "
        f"apart), stops {math.degrees(q_stops[0]):.1f}° .. {math.degrees(q_stops[1]):.1f}°"
        + (" (limited to the model's range)" if clipped else ""))
    zero = math.remainder(zero, 2 * math.pi) if abs(zero) > 2 * math.pi else zero
    return {"direction": direction, "zero_offset": zero, "position_limits": (lower, upper)}
