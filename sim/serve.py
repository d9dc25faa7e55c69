"""The simulated robot served to a host, one way for every configuration and every caller (the
swing, `servodyn sim`, the HIL replay, the soak and the benchmarks): `serve(config, mode)` puts each
bus of the configuration's SimulatedRobot behind its transport — a Dynamixel bus on a
pseudo-terminal (PtyServer), a CAN bus on python-can's virtual interface (VirtualCanServer) or an
SLCAN adapter on a pseudo-terminal (SlcanServer) — and gives the options that point each bus's
backend at it.

A configuration of one Dynamixel or Feetech bus read from a file is served by a child process of its own
(`SimProcess`, `python -m servodyn.sim.serve`), so the host loop's figures are its own: the
child dies with its parent (PR_SET_PDEATHSIG, and the end of its control socket), and the parent
injects faults and reads the plant's clock and the servos' torque through that socket, each request
answered before the next packet is sent (deterministic). Any other configuration is served by
threads of this process, one plant behind all of its buses (`Served`). Both are `SimulatedBuses`:
the one interface a run, `servodyn sim`, the soak and the benchmarks use.

Contact (sim/contact.py; the data are hal/contact_spec.py's): `serve(..., obstacles=[...])` puts
obstacles in the plant from its start; `schedule_push(push, origin)` starts a push at origin +
push.start on the plant's clock (a run calls it when the swing begins, with the plant's time then);
`status()["contact"]` is the ground truth so far (Contacts.status: onset_time, body, peak_force_n,
force_n, ...; None with neither), `contact_log()` the same row by row.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import signal
import socket
import subprocess
import sys
from abc import ABC, abstractmethod
from contextlib import nullcontext

from servodyn.control.timing import plant_step
from servodyn.errors import InputError, ServodynError
from servodyn.hal.contact_spec import Push, from_dict, to_dict
from servodyn.hal.config import RobotConfig, load_config
from servodyn.hal.ports import PTY_REPLY_TIMEOUT
from servodyn.hal.realtime import SIMULATOR_PRIORITY, realtime_priority

from .lab import Lab
from .robot import SimulatedRobot
from .transport.can import SlcanServer, VirtualCanServer
from .transport.pty import PtyServer

MODES = ("lockstep", "realtime")


class SimProcessError(ServodynError):
    """The simulator's child process could not start or stopped answering its control socket."""
    exit_code = 2


class SimulatedBuses(ABC):
    """A configuration's buses simulated and served, one plant behind them: `buses` (bus -> the
    options that point its backend at the simulated bus), the plant's `status()`, faults to
    inject and clear, a power cycle, and `stop()`. A run drives it through these alone."""

    buses: dict
    servos: int

    @abstractmethod
    def status(self) -> dict:
        """The plant's time (s), each device's torque_off and the contact applied so far
        (SimulatedRobot.status), as the simulator sees them now."""

    @abstractmethod
    def schedule_push(self, push: Push, origin: float = 0.0) -> None:
        """`push` from `origin` + push.start on the plant's clock (s)."""

    @abstractmethod
    def contact_log(self) -> dict:
        """The contact applied so far, row by row (Contacts.table)."""

    @abstractmethod
    def inject_fault(self, device_id, fault="silent") -> None:
        """The fault is in place when this returns: the next packet or frame sees it."""

    @abstractmethod
    def clear_faults(self) -> None: ...

    @abstractmethod
    def power_cycle(self) -> None:
        """Every device off and on (SimulatedRobot.power_cycle) before the next packet or frame."""

    @abstractmethod
    def stop(self) -> None: ...

    @abstractmethod
    def describe(self, config: RobotConfig, clock: str) -> list[str]:
        """What is served where, in a line a bus."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


class Served(SimulatedBuses):
    """A simulated robot's buses served in this process, started and stopped together."""

    def __init__(self, robot: SimulatedRobot, servers: dict, buses: dict, where: dict):
        self.robot, self.servers, self.buses = robot, servers, buses
        self.where = where          # bus -> where it is served, in words

    def inject_fault(self, device_id, fault="silent") -> None:
        """The fault is in place when this returns: the next packet or frame sees it."""
        with self.robot.lock:
            self.robot.inject_fault(device_id, fault)

    def clear_faults(self) -> None:
        with self.robot.lock:
            self.robot.clear_faults()

    def status(self) -> dict:
        """The plant's time, whether each device's torque is off, the contact (SimulatedRobot.status)."""
        with self.robot.lock:
            return self.robot.status()

    def schedule_push(self, push: Push, origin: float = 0.0) -> None:
        with self.robot.lock:
            self.robot.schedule_push(push, origin)

    def contact_log(self) -> dict:
        with self.robot.lock:
            return self.robot.contact_log()

    def power_cycle(self) -> None:
        """Every device off and on (SimulatedRobot.power_cycle), between two packets or frames."""
        with self.robot.lock:
            self.robot.power_cycle()

    @property
    def servos(self) -> int:
        return len(self.robot.drives)

    def stop(self) -> None:
        for server in self.servers.values():
            server.stop()
        for options in self.buses.values():
            if "can_bus" in options:
                options["can_bus"].shutdown()

    def describe(self, config: RobotConfig, clock: str) -> list[str]:
        return [f"simulated {config.buses[name].kind} bus '{name}': {len(config.joints_on(name))} devices of "
                f"'{config.name}' on {where} ({clock})" for name, where in self.where.items()]


def simulated_arm(config: RobotConfig, obstacles=()):
    """A simulated arm's one bus, in this process, to be served by its caller (QEMU's controller:
    servodyn.loop.qemu.FirmwareLink on the emulator's UART)."""
    return SimulatedRobot(config, obstacles=obstacles).port()


def serve(config: RobotConfig, mode: str = "lockstep", *, process: bool | None = None, can: str = "virtual",
          q0=None, start: bool = True, lab: Lab | None = None, obstacles=()) -> SimulatedBuses:
    """The configuration's buses simulated and served (`mode`: "lockstep" or "realtime"): a
    SimProcess for one Dynamixel or Feetech bus of a configuration file (unless process=False, or q0 is given),
    else a `Served` robot in this process (CAN buses on python-can's virtual interface, or with
    can="slcan" on an SLCAN adapter's pseudo-terminal). `lab`: the robot on a simulated lab bench
    (sim/lab.py), in the child process too. `obstacles`: hal/contact_spec's Plane and Sphere, in the
    plant from its start."""
    if mode not in MODES:
        raise SimProcessError(f"a simulated bus runs {' or '.join(MODES)}, not {mode!r}")
    kinds = [bus.kind for bus in config.buses.values()]
    if process is None:
        process = kinds in (["dynamixel"], ["feetech"]) and config.path is not None and q0 is None
    if process:
        return SimProcess(config.path, mode, lab=lab, obstacles=obstacles)
    robot = SimulatedRobot(config, q0=q0, bench=lab, obstacles=obstacles)
    servers, buses, where = {}, {}, {}
    for name, bus in config.buses.items():
        # the first bus's server keeps the real-time clock; the others follow it
        own = mode if not servers else "lockstep"
        port = robot.port(name)
        if bus.kind == "can" and can == "virtual":
            channel = f"servodyn-{id(robot):x}-{name}"
            # lock-step: the motors answer in the loop's thread when it waits for them (no thread
            # hand-over per frame); real time: from the server's thread
            servers[name] = VirtualCanServer(port, channel, mode=own, threaded=mode == "realtime")
            buses[name] = {"can_bus": servers[name].host_bus()}
            where[name] = f"python-can's virtual channel {channel}"
        elif bus.kind == "can":
            servers[name] = SlcanServer(port, mode=own)
            buses[name] = {"port": servers[name].path, "interface": "slcan"}
            where[name] = f"an SLCAN adapter on {servers[name].path}"
        else:
            servers[name] = PtyServer(port, own)
            buses[name] = {"port": servers[name].path}
            where[name] = servers[name].path
        buses[name]["reply_timeout"] = PTY_REPLY_TIMEOUT[bus.kind]
    if mode == "realtime" and len(servers) > 1:
        robot.free_running()         # the first server's clock alone moves the plant
    served = Served(robot, servers, buses, where)
    if start:
        for server in servers.values():
            server.start()
    return served


class SimProcess(SimulatedBuses):
    """The simulated bus of a configuration file in a child process, on a pseudo-terminal."""

    def __init__(self, config_path, mode: str = "lockstep", start_timeout: float = 60.0, lab: Lab | None = None,
                 obstacles=()):
        if mode not in MODES:
            raise SimProcessError(f"a simulated bus runs {' or '.join(MODES)}, not {mode!r}")
        self._control, child = socket.socketpair()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "servodyn.sim.serve", "--config", str(config_path), "--mode", mode,
             "--control-fd", str(child.fileno()), "--parent", str(os.getpid()),
             *(["--lab", lab.to_json()] if lab is not None else []),
             *(["--obstacles", json.dumps([to_dict(o) for o in obstacles])] if obstacles else [])],
            pass_fds=(child.fileno(),), stdin=subprocess.DEVNULL)
        child.close()
        self._control.settimeout(start_timeout)
        self._buffer = b""
        try:
            hello = self._receive()
        except SimProcessError:
            self.stop()
            raise
        if not hello.get("ok"):
            self.stop()
            raise SimProcessError(f"simulated bus: {hello.get('error')}")
        self.path, self.servos, self.bus = hello["path"], hello["servos"], hello["bus"]
        self.kind = hello.get("kind", "dynamixel")
        self._control.settimeout(10.0)

    def _receive(self) -> dict:
        while b"\n" not in self._buffer:
            try:
                data = self._control.recv(4096)
            except (OSError, socket.timeout) as err:
                raise SimProcessError(f"simulated bus: no answer from its process ({err})") from None
            if not data:
                raise SimProcessError(f"simulated bus: its process ended (exit status {self.process.poll()})")
            self._buffer += data
        line, self._buffer = self._buffer.split(b"\n", 1)
        return json.loads(line)

    def request(self, op: str, **args) -> dict:
        try:
            self._control.sendall((json.dumps({"op": op, **args}) + "\n").encode())
        except OSError as err:
            raise SimProcessError(f"simulated bus: its process is gone ({err})") from None
        answer = self._receive()
        if not answer.get("ok", False):
            raise SimProcessError(f"simulated bus: {answer.get('error', 'refused')}")
        return answer

    def inject_fault(self, device_id: int, fault: str | int = "silent") -> None:
        self.request("fault", id=device_id, fault=fault)

    def clear_faults(self) -> None:
        self.request("clear")

    def pause(self, seconds: float) -> None:
        """Freeze the simulator for `seconds` from now (PtyServer.pause), as a stalled bus: its answer
        comes first, then nothing moves; a request meanwhile waits for the end of the pause."""
        self.request("pause", seconds=seconds)

    def status(self) -> dict:
        return self.request("status")

    def schedule_push(self, push: Push, origin: float = 0.0) -> None:
        self.request("push", push=to_dict(push), origin=float(origin))

    def contact_log(self) -> dict:
        answer = self.request("contact_log")
        return {"columns": answer["columns"], "rows": answer["rows"]}

    def power_cycle(self) -> None:
        self.request("power_cycle")

    def describe(self, config: RobotConfig, clock: str) -> list[str]:
        return [f"simulated bus: {self.servos} virtual servos of '{config.name}' on {self.path} ({clock}, its own "
                f"process), the plant integrated by RK4 at {plant_step(config.control_period) * 1e3:g} ms"]

    @property
    def buses(self) -> dict:
        """The options that point the bus's backend at the simulated bus."""
        return {self.bus: {"port": self.path, "reply_timeout": PTY_REPLY_TIMEOUT[self.kind]}}

    def stop(self) -> None:
        """Ask the child to end, and make sure it has."""
        if self.process.poll() is None:
            try:
                self._control.sendall(b'{"op": "quit"}\n')
            except OSError:
                pass
            try:
                self.process.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._control.close()


def _die_with_parent(parent: int) -> None:
    """SIGTERM when the parent process ends (Linux prctl PR_SET_PDEATHSIG), and a check that it
    has not ended already before the call."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)        # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        pass                                           # elsewhere: the control socket's end stops it
    if os.getppid() != parent:
        sys.exit(0)


class ContactPtyServer(PtyServer):
    """The child's server: PtyServer's control requests, and the contact's (`push`: a push from an
    origin on the plant's clock; `contact_log`: the ground truth row by row)."""

    def _request(self, request: dict) -> dict:
        op = request.get("op")
        if op not in ("push", "contact_log"):
            return super()._request(request)
        try:
            with self._lock:
                if op == "push":
                    self.arm.schedule_push(from_dict(request["push"]), float(request.get("origin", 0.0)))
                    return {"ok": True}
                return {"ok": True, **self.arm.contact_log()}
        except (InputError, ValueError, KeyError, TypeError) as err:
            return {"ok": False, "error": str(err)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.sim.serve",
                                     description="the simulated bus in a child process (SimProcess)")
    parser.add_argument("--config", required=True)
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    parser.add_argument("--control-fd", type=int, required=True)
    parser.add_argument("--parent", type=int, required=True)
    parser.add_argument("--lab", default=None, help="the lab bench, as Lab.to_json gives it")
    parser.add_argument("--obstacles", default=None, help="obstacles, a JSON list of hal.contact_spec.to_dict's")
    args = parser.parse_args(argv)
    _die_with_parent(args.parent)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    control = socket.socket(fileno=args.control_fd)
    try:
        lab = Lab.from_json(args.lab) if args.lab is not None else None
        obstacles = [from_dict(o) for o in json.loads(args.obstacles)] if args.obstacles else ()
        arm = SimulatedRobot(load_config(args.config), bench=lab, obstacles=obstacles).port()
    except Exception as err:     # reported to the parent as one line, never a traceback
        control.sendall((json.dumps({"ok": False, "error": str(err)}) + "\n").encode())
        return 2
    server = ContactPtyServer(arm, args.mode)
    gc.freeze()      # the set-up's objects (model, tables, numpy) out of every later collection
    control.sendall((json.dumps({"ok": True, "path": server.path, "servos": len(arm.servos), "bus": arm.name,
                             "kind": arm.robot.config.buses[arm.name].kind}) + "\n").encode())
    try:
        # in real time the simulated servos answer ahead of everything else, as hardware does
        with realtime_priority(SIMULATOR_PRIORITY, "the simulated bus") if args.mode == "realtime" else nullcontext():
            server.serve_forever(control)
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
