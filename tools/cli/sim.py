"""`servodyn sim`: a configuration's buses simulated, each on a pseudo-terminal (its path, the data
other programs connect to, on stdout)."""

from __future__ import annotations

import gc
import sys
import time
from contextlib import nullcontext

from ...hal.config import load_config
from ...hal.realtime import SIMULATOR_PRIORITY, realtime_priority
from ...sim.console import start_console
from ...sim.lab import Lab
from ...sim import serve as simulator
from .argtypes import obstacle
from .common import describe

KIND_NAMES = {"dynamixel": "Dynamixel", "feetech": "Feetech", "can": "CAN"}    # a bus kind in the banner


def add_arguments(p) -> None:
    describe(p, "Serve the simulated bus of a configuration on a pseudo-terminal: Dynamixel, or an SLCAN adapter "
             "for a CAN configuration. One plant behind all its buses; lock-step advances it when every bus has had "
             "its tick's commands.", "servodyn sim --config replica_can --lockstep")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    p.add_argument("--lockstep", action="store_true",
                   help="advance the plant one period per command transaction (default: real time)")
    p.add_argument("--factory", action="store_true",
                   help="a bench of devices as they leave the factory (Dynamixel: ID 1 at 57600 baud; Feetech: ID 1 at 1000000), their horns "
                        "mounted otherwise than the configuration says (zeros off, one joint reversed), unless the "
                        "--bench store holds them")
    p.add_argument("--console", action="store_true",
                   help="read the hand's commands (move, push, zero, release, where) from standard input even "
                        "when it is not a terminal (on a terminal they are read anyway)")
    p.add_argument("--connect", default=None, metavar="DOF[,DOF...]",
                   help="only these joints' devices are wired to their bus (default every one); the others neither "
                        "hear nor answer, their joints hang limp")
    p.add_argument("--obstacle", type=obstacle, action="append", default=[], metavar="SPEC",
                   help="an obstacle in the plant from the start, as `servodyn swing --obstacle`: plane:NX,NY,NZ,D[@K] "
                        "or sphere:X,Y,Z,R[@K] (m, K in N/m, default 40000); repeatable")
    p.add_argument("--bench", default=None, metavar="FILE",
                   help="the bench's store, a JSON file of each device's non-volatile memory (by dof) and each "
                        "horn's mounting: read at start, written whenever a memory changes, so the bench carries "
                        "over to the next run")


def run(args) -> int:
    mode = "lockstep" if args.lockstep else "realtime"
    bench = None
    if args.factory or args.connect is not None or args.bench is not None:
        connected = None if args.connect is None else [d.strip() for d in args.connect.split(",") if d.strip()]
        bench = Lab(factory=args.factory, store=args.bench, connected=connected)
    config = load_config(args.config)
    served = simulator.serve(config, mode, process=False, can="slcan", start=False, lab=bench,
                             obstacles=tuple(args.obstacle))
    robot, paths = served.robot, {name: options["port"] for name, options in served.buses.items()}
    kinds = {bus.kind for bus in config.buses.values()}
    if bench is not None:
        _announce_bench(args, config, robot, paths)
    else:
        _announce(args, config, robot, paths, kinds)
    if args.console or (sys.stdin is not None and sys.stdin.isatty()):
        # a hand on the simulated arm, typed here: what a person does by hand during bring-up
        print("type `help` for the hand on the arm (move JOINT DEG, push JOINT +|-, zero, release, where)"
              + ("; the hand moves while the plant runs: without --lockstep" if args.lockstep else ""), flush=True)
        start_console(served, sys.stdin, lambda *a, **k: print(*a, **k, flush=True))
    gc.freeze()        # the set-up's objects out of every later collection, as the swing's simulator
    try:
        if len(served.servers) == 1 and kinds == {"dynamixel"}:
            # in real time the servos answer ahead of everything else, as the swing's own simulator does
            with nullcontext() if args.lockstep else realtime_priority(SIMULATOR_PRIORITY, "the simulated bus"):
                next(iter(served.servers.values())).serve_forever()   # in this thread, blocked on the pty
        else:
            for server in served.servers.values():
                server.start()
            while True:
                time.sleep(0.5)
    except KeyboardInterrupt:
        print(f"\nstopped after {robot.time:.2f} s of simulated time", flush=True)
        contact = robot.status()["contact"]
        if contact and contact["onset_time"] is not None:
            print(f"contact: first at {contact['onset_time']:.3f} s on {contact['body']}, peak "
                  f"{contact['peak_force_n']:.1f} N on {contact['peak_body']}", flush=True)
    finally:
        served.stop()
    return 0


def _announce(args, config, robot, paths: dict, kinds: set) -> None:
    """`servodyn sim`'s first lines: each bus, where it is served, and how to connect a swing."""
    for name, bus in config.buses.items():
        if bus.kind == "can":
            devices = ", ".join(f"{m.can_id}->0x{m.feedback_id:X} {m.spec.name}" for m in robot.port(name).motors)
            print(f"simulated CAN bus '{name}' of '{config.name}' (SLCAN adapter, {bus.baud} bit/s): "
                  f"{devices} on {paths[name]}", flush=True)
        else:
            ids = ", ".join(str(j.id) for j in config.joints_on(name))
            print(f"simulated {KIND_NAMES[bus.kind]} bus '{name}' of '{config.name}' ({bus.baud} baud): "
                  f"servos {ids} on {paths[name]}", flush=True)

    def swing(path_of):
        return f"servodyn swing --config {args.config} " + " ".join(
            f"--port {name}={path_of(name)}" if len(paths) > 1 else f"--port {path_of(name)}" for name in paths)
    # the swing asks the bus which clock this is (hal.served_clock) and keeps it
    clock = "lock-step" if args.lockstep else "real time"
    if kinds <= {"dynamixel", "feetech"}:      # serial buses on pseudo-terminals
        print(f"connect with: {swing(paths.get)}   (the swing learns the plant's clock, {clock}, from the bus; "
              "Ctrl-C stops)", flush=True)
    elif len(paths) == 1:
        path, bus = next(iter(paths.values())), next(iter(config.buses.values()))
        print(f"connect with: can.Bus(interface=\"slcan\", channel=\"{path}\", bitrate={bus.baud})"
              + (f"  or  {swing(paths.get)}" if args.lockstep else "") + "   (Ctrl-C stops)", flush=True)
    elif args.lockstep:
        print(f"connect with: {swing(paths.get)}   (Ctrl-C stops)", flush=True)
    if "can" in kinds and not args.lockstep:
        # a swing paced by the wall clock cannot keep its period through an SLCAN pseudo-terminal
        print(f"a swing: serve with --lockstep, then {swing(lambda name: 'PATH')} (an SLCAN pseudo-terminal carries a "
              f"tick slower than the {config.control_period * 1e3:g} ms period; real time needs SocketCAN; "
              "Ctrl-C stops)", flush=True)


def _announce_bench(args, config, robot, paths: dict) -> None:
    """`servodyn sim` on a bench: each bus and where it is served, what is wired, where the store
    is. No swing to suggest: the devices want bringing up first."""
    dofs = list(config.model.dof_names)
    for name, bus in config.buses.items():
        wired = [j.dof for j in config.joints_on(name) if j.dof in robot.bench.connected]
        state = "factory-fresh" if args.factory else "set up as configured"
        print(f"simulated {KIND_NAMES[bus.kind]} bus '{name}' of '{config.name}' on a bench "
              f"({state}{', else as the store holds them' if args.bench else ''}; wired: "
              f"{', '.join(sorted(wired, key=dofs.index)) or 'nothing'}) on {paths[name]}", flush=True)
    if args.bench:
        print(f"the bench's store: {args.bench} (each device's memory and each horn's mounting)", flush=True)
    swing = f"servodyn swing --config {args.config} " + " ".join(
        f"--port {name}={path}" if len(paths) > 1 else f"--port {path}" for name, path in paths.items())
    can = any(bus.kind == "can" for bus in config.buses.values())
    print(f"once set up and calibrated: {swing}"
          + ("   (this bench serves in real time: a CAN swing needs --lockstep here)" if can and not args.lockstep
             else f"   (the swing learns the plant's clock, {'lock-step' if args.lockstep else 'real time'}, "
                  "from the bus)") + "   (Ctrl-C stops)", flush=True)
