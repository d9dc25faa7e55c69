"""The `servodyn` command line."""

from __future__ import annotations

import argparse
import gc
import math
import os
import re
import signal
import sys
import time
import warnings
from contextlib import nullcontext
from pathlib import Path

import numpy as np

from ..control.motion import check_limits
from ..control.timing import OVERRUN_TOLERANCE
from ..control.trajectory import TrajectoryError, read_trajectory_csv, write_columns_csv
from ..mocap.skeleton import UNITS as _UNITS
from ..model import ModelError, builtin_models, load_model
from ..readable import fixed
from .argtypes import OneLineParser, count


UNIT_NAMES = tuple(_UNITS)


class CliError(Exception):
    """A user-facing failure: printed as one line, exit status `code` (default 2)."""

    def __init__(self, message: str, code: int = 2):
        super().__init__(message)
        self.code = code


def _load(name: str):
    try:
        return load_model(name)
    except ModelError as err:
        raise CliError(str(err)) from None


def cmd_models(args) -> None:
    print(f"{'name':<12} {'bodies':>6} {'dofs':>5} {'mass kg':>8}  dofs")
    for name in builtin_models():
        model = load_model(name)
        print(f"{name:<12} {model.nbody:>6} {model.nq:>5} {model.total_mass:>8.2f}  {', '.join(model.dof_names)}")


def catalogue() -> dict:
    """The built-in models, configurations and motions, with what a newcomer picks them by."""
    from ..control.motion import builtin_motions
    from ..hal.config import builtin_configs, load_config
    from ..model.files import read_toml
    models = []
    for name in builtin_models():
        model = load_model(name)
        models.append({"name": name, "bodies": model.nbody, "dofs": model.nq, "mass_kg": round(model.total_mass, 3)})
    configs = []
    for name in builtin_configs():
        config = load_config(name)
        configs.append({"name": name, "model": config.model_ref,
                        "buses": {bus.name: bus.kind for bus in config.buses.values()},
                        "servos": sorted({j.servo.name for j in config.joints}),
                        "control_period_s": config.control_period})
    motions = []
    for name, path in builtin_motions().items():
        data = read_toml(path, CliError)
        frames = data.get("keyframe", [])
        times = [f.get("t") for f in frames if isinstance(f, dict)]
        motions.append({"name": name, "model": data.get("model"), "keyframes": len(frames),
                        "duration_s": float(times[-1] - times[0]) if len(times) > 1 else 0.0})
    return {"models": models, "configurations": configs, "motions": motions}


def cmd_list(args) -> None:
    import json
    found = catalogue()
    if args.json:
        print(json.dumps(found, indent=1))
        return
    print("models (servodyn torques/export/view MODEL):")
    for m in found["models"]:
        print(f"  {m['name']:<16} {m['bodies']:>3} bodies {m['dofs']:>3} dofs {m['mass_kg']:>7.2f} kg")
    print("configurations (servodyn swing --config CONFIG, validate CONFIG MOTION, view CONFIG):")
    for c in found["configurations"]:
        buses = ", ".join(f"{name} ({kind})" for name, kind in c["buses"].items())
        print(f"  {c['name']:<16} model {c['model']}, bus {buses}, {', '.join(c['servos'])}, "
              f"{c['control_period_s'] * 1e3:g} ms period")
    print("motions (--motion NAME; or a keyframe .toml or trajectory .csv file):")
    for m in found["motions"]:
        print(f"  {m['name']:<16} {m['keyframes']} keyframes, {m['duration_s']:g} s, for model {m['model']}")


def cmd_torques(args) -> None:
    model = _load(args.model)
    if model.nq != model.nv:
        raise CliError(f"{args.model}: a trajectory CSV gives one angle per dof; this model has "
                       "quaternion coordinates (a free root or ball joints)")
    try:
        traj = read_trajectory_csv(args.trajectory, model.dof_names)
        if not args.ignore_limits:
            check_limits(traj, model, origin=str(args.trajectory), velocity=args.max_velocity,
                         acceleration=args.max_acceleration)
    except TrajectoryError as err:
        raise CliError(str(err)) from None
    start = time.perf_counter()
    try:
        tau = model.inverse_dynamics(traj.q, traj.qd, traj.qdd)
    except FloatingPointError as err:
        row = int(re.search(r"row (\d+)", str(err)).group(1))
        raise CliError(f"{args.trajectory}: t = {traj.t[row]:.3f} s (sample {row + 1}): the torques overflow "
                       "double precision (qd or qdd far too large)") from None
    elapsed = time.perf_counter() - start
    write_columns_csv(args.output, traj.t, "tau", model.dof_names, tau)
    how = "qd, qdd from a C2 spline of q" if traj.derived else "qd, qdd from the file"
    print(f"{len(traj.t)} samples, {model.nq} dofs ({how}): inverse dynamics in "
          f"{elapsed * 1e3:.2f} ms ({elapsed / len(traj.t) * 1e6:.2f} us per sample) -> {args.output}")
    peak = np.abs(tau).max(axis=0)
    for name, value in sorted(zip(model.dof_names, peak), key=lambda x: -x[1])[:args.top]:
        print(f"  peak |tau| {name:<24} {fixed(value, 3):>9} N·m")


def cmd_export(args) -> None:
    model = _load(args.model)
    out = Path(args.output)
    if out.suffix.lower() != ".urdf":
        raise CliError(f"{out}: export writes URDF; name the file .urdf")
    out.parent.mkdir(parents=True, exist_ok=True)
    model.to_urdf(out)
    print(f"{model.name}: {model.nbody} bodies, {model.nq} dofs -> {out}")


def cmd_experiment(args) -> None:
    from .experiments import EXPERIMENTS
    EXPERIMENTS[args.name](Path(args.out))


def _overrun_tolerance(ms: float | None) -> float | None:
    """--overrun-tolerance in s; CliError unless a finite number of ms >= 0."""
    if ms is None:
        return None
    if not math.isfinite(ms) or ms < 0:
        raise CliError(f"--overrun-tolerance must be a finite number of ms >= 0, got {ms:g}")
    return ms * 1e-3


def cmd_swing(args) -> int | None:
    from ..errors import ServodynError
    from ..loop.run import Declined, RunOptions
    from ..report.swing import play
    viewer = feed = None
    try:
        if args.view:
            from .view import live_viewer
            viewer, feed = live_viewer(args.config, args.view_host, args.view_port)
        options = RunOptions(motion=args.motion, time_scale=args.time_scale, feedforward=not args.no_feedforward,
                             realtime=args.realtime, force=args.force, native=args.native, port=args.port,
                             overrun_tolerance=_overrun_tolerance(args.overrun_tolerance), hold=args.hold,
                             dry_run=args.dry_run)
        summary = play(args.config, options, Path(args.out), observer=feed.observe if feed else None,
                       confirm=None if args.yes else _confirm)
    except Declined as err:
        if viewer is not None:
            viewer.close()
        raise CliError(str(err), err.exit_code) from None
    except (ServodynError, ValueError) as err:
        if viewer is not None:
            viewer.close()
        if args.verbose and getattr(err, "violations", None):      # the validator's refusal, in full
            print("\n".join(f"  {line}" for line in err.violations), flush=True)
        raise CliError(str(err)) from None
    if viewer is not None and (summary.get("signal") or summary.get("error")):
        viewer.close()
    if summary.get("signal"):       # a safe stop asked for: the shell's status for that signal
        print(f"servodyn: the swing stopped: {summary['error']}, torque off (log up to then in {args.out})",
              file=sys.stderr)
        return 128 + signal.Signals[summary["signal"]].value
    if summary.get("error"):
        raise CliError(f"the swing stopped: {summary['error']} (log up to then in {args.out})",
                       summary["exit_code"])
    if viewer is not None:
        from .view import replay_after_live
        replay_after_live(viewer, feed, Path(args.out))


def _confirm(question: str) -> bool:
    """A yes/no question before a real arm moves (tools/config_patch.ask)."""
    from .prompt import ask
    return ask(question, False)


def cmd_sim(args) -> None:
    """The configuration's buses simulated, each on a pseudo-terminal (a CAN bus behind an SLCAN
    adapter), one plant behind all of them (servodyn.sim.serve.serve); lock-step advances the
    plant when every bus has had its tick's commands."""
    from ..hal.config import load_config
    from ..hal.errors import ConfigError
    from ..hal.realtime import SIMULATOR_PRIORITY, realtime_priority
    from ..sim.lab import Lab
    from ..sim import serve as simulator
    mode = "lockstep" if args.lockstep else "realtime"
    bench = None
    if args.factory or args.connect is not None or args.bench is not None:
        connected = None if args.connect is None else [d.strip() for d in args.connect.split(",") if d.strip()]
        bench = Lab(factory=args.factory, store=args.bench, connected=connected)
    try:
        config = load_config(args.config)
        served = simulator.serve(config, mode, process=False, can="slcan", start=False, lab=bench)
    except (ConfigError, ValueError) as err:
        raise CliError(str(err)) from None
    robot, paths = served.robot, {name: options["port"] for name, options in served.buses.items()}
    kinds = {bus.kind for bus in config.buses.values()}
    if bench is not None:
        _announce_bench(args, config, robot, paths)
    else:
        _announce(args, config, robot, paths, kinds)
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
    finally:
        served.stop()


def cmd_ports(args) -> int:
    from .ports import run_ports
    return run_ports(args.root, as_json=args.json)


def _announce(args, config, robot, paths: dict, kinds: set) -> None:
    """`servodyn sim`'s first lines: each bus, where it is served, and how to connect a swing."""
    for name, bus in config.buses.items():
        if bus.kind == "can":
            devices = ", ".join(f"{m.can_id}->0x{m.feedback_id:X} {m.spec.name}" for m in robot.port(name).motors)
            print(f"simulated CAN bus '{name}' of '{config.name}' (SLCAN adapter, {bus.baud} bit/s): "
                  f"{devices} on {paths[name]}", flush=True)
        else:
            ids = ", ".join(str(j.id) for j in config.joints_on(name))
            print(f"simulated Dynamixel bus '{name}' of '{config.name}' ({bus.baud} baud): servos {ids} on "
                  f"{paths[name]}", flush=True)

    def swing(path_of):
        return f"servodyn swing --config {args.config} " + " ".join(
            f"--port {name}={path_of(name)}" if len(paths) > 1 else f"--port {path_of(name)}" for name in paths)
    if kinds == {"dynamixel"}:
        print(f"connect with: {swing(paths.get)}{_paced(args)}   (Ctrl-C stops)", flush=True)
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
        print(f"simulated {'CAN' if bus.kind == 'can' else 'Dynamixel'} bus '{name}' of '{config.name}' on a bench "
              f"({state}{', else as the store holds them' if args.bench else ''}; wired: "
              f"{', '.join(sorted(wired, key=dofs.index)) or 'nothing'}) on {paths[name]}", flush=True)
    if args.bench:
        print(f"the bench's store: {args.bench} (each device's memory and each horn's mounting)", flush=True)
    print("(Ctrl-C stops)", flush=True)


def _paced(args) -> str:
    """The swing's option that matches the simulator's clock: a plant on the wall clock wants a
    loop paced by it (lock-step, one period per command, wants the loop as fast as it goes)."""
    return "" if args.lockstep else " --realtime"


def cmd_codegen(args) -> None:
    from ..hal.errors import ConfigError
    from .codegen import write
    try:
        paths = write(args.config, Path(args.out), args.motion)
    except (ConfigError, ValueError) as err:
        raise CliError(str(err)) from None
    print("wrote " + ", ".join(str(p) for p in paths))


def cmd_firmware(args) -> None:
    from ..hal.errors import ConfigError
    from .hil import FirmwareError, run_firmware
    try:
        summary = run_firmware(args.board, elf=args.elf, config=args.config, out=Path(args.out),
                               icount_shift=args.icount_shift, say=print)
    except (ConfigError, FirmwareError) as err:
        raise CliError(str(err)) from None
    if summary["fault"] != "none":
        raise CliError(f"the firmware stopped on a fault: {summary['fault']} "
                       f"(servo {summary['fault_servo']}, tick {summary['fault_tick']})")


def cmd_validate(args) -> int:
    from ..hal.config import load_config
    from ..hal.errors import ConfigError
    from ..report.validation import expand_motions, validate, validate_many
    options = dict(time_scale=args.time_scale, payload=args.payload, payload_body=args.payload_body,
                   payload_com=args.payload_com, supply_voltage=args.supply_voltage, margin=args.margin,
                   repeat=args.repeat, ambient=args.ambient, fit=args.fit, retime_motion=args.retime,
                   simulate_motion=args.simulate)
    try:
        config = load_config(args.config)
        motions = expand_motions(args.motion)
        if len(args.motion) == 1 and motions == args.motion:       # one motion: its report, as always
            report = validate(config, motions[0], out=Path(args.out), **options)
            return 0 if report["passed"] else 1
        return validate_many(config, motions, jobs=args.jobs, out=Path(args.out), **options)["code"]
    except (ConfigError, ValueError) as err:
        raise CliError(str(err)) from None


def cmd_size(args) -> int:
    from .size import SizingError, progress_line, run_size, text
    try:
        report = run_size(args.model, args.motion, time_scale=args.time_scale, payload=args.payload,
                          supply_voltage=args.supply_voltage, margin=args.margin, family=args.family,
                          objective=args.objective, jobs=args.jobs, repeat=args.repeat, out=Path(args.out),
                          yes=args.yes, say=print, progress=None if args.json else progress_line)
    except (SizingError, ValueError) as err:
        raise CliError(str(err)) from None
    if args.json:
        import json
        print(json.dumps(report, indent=1))
    else:
        print(text(report))
    return 0 if report["passed"] else 1


def cmd_excite(args) -> int:
    from .excite import ExciteError, run
    try:
        return run(args.config, args.duration, args.joints, Path(args.out), harmonics=args.harmonics,
                   margin=args.margin, seed=args.seed, heat=args.heat)
    except ExciteError as err:
        raise CliError(str(err)) from None


def cmd_identify(args) -> int:
    from .identify import IdentifyError, run
    try:
        return run(args.config, args.logs, args.payload_body, args.known_payload, args.arm, Path(args.out),
                   cutoff=args.cutoff, apply_to=args.write, apply=args.apply, yes=args.yes,
                   warn=lambda line: print(line, file=sys.stderr))
    except IdentifyError as err:
        raise CliError(str(err)) from None


def cmd_view(args) -> None:
    from .view import ViewError, open_view, serve_forever
    try:
        viewer = open_view(args.subject, log=args.log, motion=args.motion, time_scale=args.time_scale,
                           host=args.host, port=args.port, save_to=Path(args.save) if args.save else None,
                           source=args.source)
    except ViewError as err:
        raise CliError(str(err)) from None
    serve_forever(viewer)


def _mocap(run):
    """Run a mocap command; its bad input (a file, a name map, a model that is no arm) is one line."""
    from ..control.trajectory import TrajectoryError as _TrajectoryError
    from ..hal.errors import ConfigError
    from ..mocap import BvhError, RetargetError, SkeletonError
    from .mocap import MocapError
    try:
        return run()
    except (BvhError, SkeletonError, RetargetError, MocapError, ConfigError, _TrajectoryError) as err:
        raise CliError(str(err)) from None


def cmd_mocap_info(args) -> None:
    from .mocap import mocap_info
    _mocap(lambda: mocap_info(args.clip, map_file=args.map, unit=args.unit, as_json=args.json))


def cmd_retarget(args) -> int:
    from ..hal.config import load_config
    from .mocap import run_retarget

    def run():
        config = load_config(args.config) if args.config else None
        model = None if config else _load(args.model or "human_arm")
        return run_retarget(args.clip, model=model, config=config, arm=args.arm, frames=args.frames, time=args.time,
                            unit=args.unit, map_file=args.map, method=args.method, twist_deg=args.twist,
                            output=args.output, report_dir=args.report)
    report = _mocap(run)
    return 1 if report["flags"] else 0


def cmd_export_bvh(args) -> int:
    from .mocap import export_bvh
    model = _load(args.model)
    if Path(args.output).exists() and not _confirm_overwrite(args.output, args.yes):
        print(f"{args.output}: kept as it was, nothing written (--yes overwrites)", file=sys.stderr)
        return 1
    _mocap(lambda: export_bvh(args.motion, model, args.output, order=args.order, unit=args.unit, rest=args.rest,
                              rate=args.rate))
    return 0


def _confirm_overwrite(path: str, yes: bool) -> bool:
    """A file that exists is replaced only when the user says so (a clip may be a capture)."""
    from .prompt import ask
    return ask(f"{path} exists: overwrite it?", yes)


def cmd_ik(args) -> int:
    from .ik import IkInputError, parse_triple, pose_report, read_targets, solve_pose, solve_targets, write_path
    from ..model import ik
    model = _load(args.model)
    try:
        if (args.to is None) == (args.path is None):
            raise IkInputError("give either --to X,Y,Z (one pose) or --path TARGETS.csv -o MOTION.csv")
        if args.path is None:
            rpy = None if args.rpy is None else parse_triple(args.rpy, "--rpy")
            result = solve_pose(model, parse_triple(args.to, "--to"), rpy, args.swivel, args.end)
            print("\n".join(pose_report(model, result, args.end)))
            return 0
        if args.output is None:
            raise IkInputError("--path needs -o MOTION.csv, the trajectory it writes")
        if args.rpy is not None:
            raise IkInputError("--rpy is for --to; a path takes roll,pitch,yaw columns in its file")
        if not (args.dt > 0 and math.isfinite(args.dt)):
            raise IkInputError(f"--dt must be a positive number of seconds, got {args.dt}")
        if args.max_speed is not None and not (args.max_speed > 0):
            raise IkInputError(f"--max-speed must be a positive number of rad/s, got {args.max_speed}")
        targets = read_targets(args.path)
        shown = [0]

        def progress(i, n):
            if n >= 200 and i * 10 // n > shown[0]:
                shown[0] = i * 10 // n
                print(f"  {i}/{n} samples", file=sys.stderr, flush=True)
        traj, result = solve_targets(model, targets, args.dt, args.max_speed, args.swivel, args.end, progress)
    except IkInputError as err:
        raise CliError(str(err)) from None
    except ik.IkError as err:
        if type(err) is ik.IkError:
            raise CliError(str(err)) from None
        raise CliError(str(err), 1) from None
    write_path(model, traj, args.output)
    worst = int(np.argmax(result.position_error))
    print(f"{len(traj.t)} samples every {args.dt:g} s ({traj.t[-1]:.3f} s), {model.nv} dofs -> {args.output}")
    print(f"hand error: largest {result.position_error.max() * 1e3:.3g} mm at t = {traj.t[worst]:.3f} s, "
          f"{np.degrees(result.rotation_error.max()):.3g}°; {int(result.slowed.sum())} samples held back by "
          f"--max-speed; reach up to {result.reach.max():.3f}")
    return 1 if result.position_error.max() > args.tolerance else 0


def cmd_demo(args) -> None:
    from .demo import run_demo
    run_demo(args.model, Path(args.out))


def _bringup(run):
    """A bring-up command (tools/bringup.py): its one-line errors and exit status."""
    from .bringup import BringUpError
    try:
        return run()
    except BringUpError as err:
        raise CliError(str(err), err.code) from None


def cmd_scan(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.scan(args.port, args.baud, args.config, args.json))


def cmd_setup(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.setup(args.config, args.joint, args.port, args.yes))


def cmd_doctor(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.doctor(args.config, args.port, args.json))


def cmd_monitor(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.monitor(args.config, args.port, args.count, args.rate))


def cmd_calibrate(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.calibrate(args.config, args.port, args.joint, args.margin, args.yes, args.write))


def cmd_reboot(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.reboot(args.config, args.port, args.yes))


def cmd_clear_errors(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.clear_errors(args.config, args.port))


def cmd_torque(args) -> int:
    from . import bringup
    return _bringup(lambda: bringup.torque_off(args.config, args.port))


def _version() -> str:
    """The installed package's version (its metadata), or the source tree's when not installed."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("servodyn")
    except PackageNotFoundError:
        from .. import __version__
        return __version__


class _Formatter(argparse.HelpFormatter):
    """argparse measures the subcommands' names one indent short of where it prints them, so a
    name as long as 'experiment' pushed its help to a line of its own: measured where printed."""

    def add_argument(self, action):
        super().add_argument(action)
        if isinstance(action, argparse._SubParsersAction) and action.choices:
            longest = max(map(len, action.choices)) + self._current_indent + self._indent_increment
            self._action_max_length = max(self._action_max_length, longest)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="servodyn", formatter_class=_Formatter,
        description="Closed-form inverse and direct dynamics for a servo-driven humanoid arm.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("list", help="list the built-in models, configurations and motions",
                       description="List what servodyn ships: models, robot configurations and motions, "
                       "each by the name the other commands take.")
    p.add_argument("--json", action="store_true", help="as JSON, for scripts")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("models", help="list the built-in models with their bodies and dofs",
                       description="List the built-in models: bodies, dofs, mass and dof names.")
    p.set_defaults(func=cmd_models)

    p = sub.add_parser("torques", help="offline inverse dynamics of a trajectory CSV",
                       description="Feed-forward joint torques of a trajectory. The CSV has a header "
                       "t, q_<dof> for every dof, and optionally qd_<dof>, qdd_<dof> (otherwise "
                       "derived from a C2 cubic spline of q). SI units.")
    p.add_argument("model", help="built-in model name, .urdf or .toml file")
    p.add_argument("trajectory", help="trajectory CSV")
    p.add_argument("-o", "--output", required=True, help="torque CSV to write (t, tau_<dof>)")
    p.add_argument("--top", type=count(0), default=7, help="how many peak torques to print (default 7)")
    p.add_argument("--max-velocity", type=float, default=None, metavar="RAD_S",
                   help="refuse a trajectory faster than this at any dof")
    p.add_argument("--max-acceleration", type=float, default=None, metavar="RAD_S2",
                   help="refuse a trajectory accelerating harder than this at any dof")
    p.add_argument("--ignore-limits", action="store_true",
                   help="skip the trajectory checks: joint limits, and --max-velocity and "
                        "--max-acceleration when given")
    p.set_defaults(func=cmd_torques)

    p = sub.add_parser("export", help="write a model as URDF",
                       description="Write a model (built-in or file) as URDF, with its solids as visuals.")
    p.add_argument("model", help="built-in model name, .urdf or .toml file")
    p.add_argument("output", help="URDF file to write")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("experiment", help="run one of the paper's experiments",
                       description="The paper's experiments (section 4): pendulum (Fig. 5), still "
                       "(Fig. 6), swing (Figs. 7-8), and numbers (tracking and energy drift against "
                       "control mode, step ratio and integrator). Writes CSV, PNG and summary.json.")
    p.add_argument("name", choices=["pendulum", "still", "swing", "numbers"])
    p.add_argument("--out", default=None, help="output folder (default out/<name>)")
    p.set_defaults(func=cmd_experiment)

    p = sub.add_parser("swing", help="play a motion on servos (the simulated bus by default)",
                       description="Validate the motion against the servos' limits, home the arm, play it "
                       "under closed-form control and log it. Without --port the simulated Dynamixel bus "
                       "is started and used. The log streams to OUT/swing_log.csv (on disk at least every "
                       "100 ms); OUT/summary.json is written at the end. Exit status: 0 the whole swing, "
                       "2 a bad input, 130 SIGINT and 143 SIGTERM (a safe stop too: torque off, log and "
                       "summary written); after a safe stop on a fault (one line says which) the "
                       "firmware's fault codes: 10 a servo or the bus did not answer, 11 a servo's "
                       "hardware error, 12 a corrupt or refused reply, 13 a non-finite desired or "
                       "measured state, 15 a joint beyond its limits.")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    p.add_argument("--port", action="append", default=None, metavar="PATH|BUS=PATH",
                   help="the real bus's serial port or CAN channel (default: the configuration's; 'auto' there "
                        "means the simulated bus); a configuration with several buses names each: --port "
                        "shoulder=/dev/ttyACM0 --port wrist=/dev/ttyUSB0")
    p.add_argument("--out", default="out/swing", help="output folder (default out/swing)")
    p.add_argument("--no-feedforward", action="store_true", help="PD only, no inverse dynamics")
    p.add_argument("--time-scale", type=float, default=None,
                   help="play the swing this many times slower (default: the configuration's)")
    p.add_argument("--realtime", action="store_true",
                   help="pace the loop and the simulated plant by the wall clock (default lock-step on a simulated "
                        "bus; a real bus always runs in real time); on the simulated Dynamixel bus the loop, "
                        "the simulator and the kernel's tty work share one CPU (root: the kernel's work "
                        "queues are steered there for the run)")
    p.add_argument("--overrun-tolerance", type=float, default=None, metavar="MS",
                   help="in real time, how far (ms) the loop may fall behind its period schedule before it stops "
                        f"safely (overrun, exit 14; default {OVERRUN_TOLERANCE * 1e3:g})")
    p.add_argument("--motion", default="tennis_forehand", metavar="NAME|FILE",
                   help="built-in motion, keyframe file or trajectory CSV (default tennis_forehand)")
    p.add_argument("--force", action="store_true",
                   help="play a motion the validator refuses (on the simulated bus only)")
    p.add_argument("--verbose", action="store_true",
                   help="when the validator refuses the motion, list every violation (not only the first)")
    p.add_argument("--native", action="store_true",
                   help="the firmware's loop as a Linux process plays it (build/fw/native, `make fw`)")
    p.add_argument("--yes", action="store_true",
                   help="on a real port, move without asking (the homing distances are still printed)")
    p.add_argument("--hold", type=float, default=None, metavar="S",
                   help="instead of the motion, hold the pose the arm is in for S seconds under the controller, "
                        "and log it")
    p.add_argument("--dry-run", action="store_true",
                   help="torque off: read the arm and log the planned homing with the torques the controller "
                        "would send, sending none")
    p.add_argument("--view", action="store_true",
                   help="show the arm live in a browser page (servodyn view), then the logged run")
    p.add_argument("--view-port", type=int, default=8080, metavar="N", help="the page's port (default 8080)")
    p.add_argument("--view-host", default="127.0.0.1", help="the page's address (default 127.0.0.1)")
    p.set_defaults(func=cmd_swing)

    p = sub.add_parser("view", help="the arm in 3-D in a browser: play, compare, shape keyframes",
                       description="Serve a page with the arm drawn from its solids: play, pause and scrub a "
                       "motion or a logged run (the planned arm as a ghost, the measured one solid, angle, "
                       "tracking error and torque plots, each joint coloured by its torque's share of the "
                       "servo's limit), or edit a keyframe motion and see its torques and the validator's "
                       "verdict at once.")
    p.add_argument("subject", nargs="?", default="replica", metavar="CONFIG|MODEL",
                   help="robot configuration or model, by name or file (default replica)")
    p.add_argument("--log", default=None, metavar="DIR", help="a run's folder (swing_log.csv) to replay")
    p.add_argument("--motion", default=None, metavar="NAME|FILE",
                   help="built-in motion, keyframe file (editable) or trajectory CSV (default tennis_forehand)")
    p.add_argument("--time-scale", type=float, default=None,
                   help="play the motion this many times slower (default: the configuration's for the forehand)")
    p.add_argument("--save", default=None, metavar="FILE",
                   help="where 'Save keyframes' writes (default out/view/<motion>.toml)")
    p.add_argument("--source", default=None, metavar="CLIP.bvh",
                   help="overlay the captured arm the --motion CSV was retargeted from (servodyn retarget)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("sim", help="serve the simulated bus on a pseudo-terminal",
                       description="Serve the simulated bus of a configuration on a pseudo-terminal: "
                       "Dynamixel, or an SLCAN adapter for a CAN configuration.")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    p.add_argument("--lockstep", action="store_true",
                   help="advance the plant one period per command transaction (default: real time)")
    p.add_argument("--factory", action="store_true",
                   help="a bench of devices as they leave the factory (Dynamixel: ID 1 at 57600 baud), their horns "
                        "mounted otherwise than the configuration says (zeros off, one joint reversed), unless the "
                        "--bench store holds them")
    p.add_argument("--connect", default=None, metavar="DOF[,DOF...]",
                   help="only these joints' devices are wired to their bus (default every one); the others neither "
                        "hear nor answer, their joints hang limp")
    p.add_argument("--bench", default=None, metavar="FILE",
                   help="the bench's store, a JSON file of each device's non-volatile memory (by dof) and each "
                        "horn's mounting: read at start, written whenever a memory changes, so the bench carries "
                        "over to the next run")
    p.set_defaults(func=cmd_sim)

    p = sub.add_parser("ports", help="list serial adapters and CAN links, and what is in their way",
                       description="The USB serial adapters (device, stable by-id name, VID:PID, product, the "
                       "adapter recognised, FTDI latency timer, the process holding it) and SocketCAN links "
                       "(state, bit rate), each port's problems with their fixes. Changes nothing.")
    p.add_argument("--json", action="store_true", help="as JSON, for scripts")
    p.add_argument("--root", type=Path, default=Path("/"), help=argparse.SUPPRESS)   # a stand-in /dev, /sys, /proc
    p.set_defaults(func=cmd_ports)

    # ---- bring-up: from a box of servos to an arm that moves (tools/bringup.py)
    port_help = ("the bus's serial port or CAN channel (default: the configuration's); a configuration with "
                 "several buses names each: --port shoulder=can0 --port wrist=/dev/ttyUSB0")

    def bus_options(p):
        """--config and --port, as every bring-up command on a configuration's buses takes them."""
        p.add_argument("--config", required=True, help="robot configuration")
        p.add_argument("--port", action="append", default=None, metavar="PATH|BUS=PATH", help=port_help)
    p = sub.add_parser("scan", help="find servos at every ID and baud rate (broadcast ping)",
                       description="Protocol 2.0 broadcast ping at each baud rate (57600 first, a new servo's rate, "
                       "then 4.5M down to 9600): each servo's ID, model, firmware and rate. With --config, what "
                       "differs from it, each with its fix. Exit 0 found (and as configured), 1 nothing found or "
                       "findings, 2 bad input.")
    p.add_argument("--port", action="append", default=None, metavar="PATH|BUS=PATH", help=port_help)
    p.add_argument("--baud", default="all", metavar="all|RATE,...", help="the rates to try (default all)")
    p.add_argument("--config", default=None, help="robot configuration to compare with (and its ports)")
    p.add_argument("--json", action="store_true",
                   help="print a list of objects with id, model_number, model, firmware, baud")
    p.set_defaults(func=cmd_scan)

    p = sub.add_parser("setup", help="make one new servo a joint of the configuration",
                       description="With only that servo connected: find it at any ID and baud rate, check its "
                       "model, show what it will write (ID, Return Delay Time 0, Drive Mode reverse bit clear, "
                       "Homing Offset 0, Current Limit, the bus's baud rate last), ask, write it to the EEPROM "
                       "with torque off and find it again at its new ID and rate.")
    bus_options(p)
    p.add_argument("--joint", required=True, metavar="DOF", help="the joint this servo drives")
    p.add_argument("--yes", action="store_true", help="write without asking")
    p.set_defaults(func=cmd_setup)

    p = sub.add_parser("doctor", help="check the host, the port and every servo (read only)",
                       description="Read only. The port (exists, permission, not held by another program, "
                       "latency timer) and every servo: present at its ID and rate, model, firmware >= 45, Drive "
                       "Mode, Homing Offset, Status Return Level, Current Limit against the configuration, input "
                       "voltage against [supply], Hardware Error Status, the Bus Watchdog. One line per finding "
                       "with its fix. Exit 0 all well, 1 findings, 2 bad input.")
    bus_options(p)
    p.add_argument("--json", action="store_true",
                   help='print {"findings": [{"joint", "id", "check", "found", "expected", "fix"}, ...]}')
    p.set_defaults(func=cmd_doctor)

    p = sub.add_parser("monitor", help="torque off, every joint live in SI and raw units",
                       description="Switch torque off on every servo, then show every joint's position, speed, "
                       "current, temperature, voltage and error, in SI and in register units, refreshed in place "
                       "until Ctrl-C.")
    bus_options(p)
    p.add_argument("--rate", type=float, default=10.0, metavar="HZ", help="refreshes per second (default 10)")
    p.add_argument("--count", type=count(1, what="refreshes"), default=None, metavar="N",
                   help="stop after N refreshes (default: until Ctrl-C)")
    p.set_defaults(func=cmd_monitor)

    p = sub.add_parser("calibrate", help="find each joint's direction, zero and stops by hand",
                       description="Torque off; for each joint you move it in its + direction (its `direction`), "
                       "put it in its zero pose from both sides (`zero_offset`, their mean) and move it to both "
                       "stops (`position_limits`, a margin inside). The configuration is then patched, its "
                       "comments and layout kept, after the change is shown and confirmed; a built-in "
                       "configuration's patched copy goes to ./NAME.toml.")
    bus_options(p)
    p.add_argument("--joint", action="append", default=None, metavar="DOF", help="only this joint (repeatable)")
    p.add_argument("--margin", type=float, default=3.0, metavar="DEG",
                   help="how far inside the stops the limits go (default 3 degrees)")
    p.add_argument("--write", default=None, metavar="FILE",
                   help="write the patched configuration here (default: the configuration itself)")
    p.add_argument("--yes", action="store_true", help="write without asking")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("reboot", help="reboot every servo (clears a latched hardware error)",
                       description="REBOOT every servo of the configuration (a latched hardware error, such as "
                       "an overload, is cleared only so or by a power cycle), then read each one's error back.")
    bus_options(p)
    p.add_argument("--yes", action="store_true", help="reboot without asking")
    p.set_defaults(func=cmd_reboot)

    p = sub.add_parser("clear-errors", help="clear what can be cleared without a reboot, and say the rest",
                       description="Clear a tripped Bus Watchdog on every servo (a CAN motor's error), then read "
                       "each one's error back; a latched hardware error needs `servodyn reboot`.")
    bus_options(p)
    p.set_defaults(func=cmd_clear_errors)

    p = sub.add_parser("torque", help="torque off on every servo of every bus: the panic button",
                       description="Torque off on every servo of every bus of the configuration (a broadcast, so "
                       "a servo at an unexpected ID too), then read each one back.")
    p.add_argument("state", choices=["off"], help="off")
    bus_options(p)
    p.set_defaults(func=cmd_torque)

    p = sub.add_parser("codegen", help="write a configuration and its motion as C for the firmware",
                       description="Write a robot configuration and a keyframe motion as C source "
                       "(servodyn_gen.h, servodyn_gen.c) for the firmware.")
    p.add_argument("--config", default="replica", help="robot configuration (default replica)")
    p.add_argument("--motion", default="tennis_forehand", help="motion (default tennis_forehand)")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.set_defaults(func=cmd_codegen)

    p = sub.add_parser("firmware", help="run the firmware under QEMU on the simulated bus (HIL)",
                       description="Run the firmware under QEMU against the simulated bus "
                       "(hardware in the loop).")
    p.add_argument("--board", default="an386", choices=("an386", "an500"),
                   help="QEMU board: an386 = Cortex-M4F (default), an500 = Cortex-M7")
    p.add_argument("--elf", default=None, help="firmware image (default build/fw/BOARD/servodyn-fw.elf; "
                                               "`make fw` builds it)")
    p.add_argument("--config", default="replica", help="robot configuration the image was generated for")
    p.add_argument("--icount-shift", type=count(0, 10, "QEMU takes shifts up to 10"), default=3,
                   help="QEMU -icount shift: 2^N ns of emulated time per instruction (default 3: "
                        "125 MIPS, a fast Cortex-M4; 7 for the budget figures)")
    p.add_argument("--out", default="out/firmware", help="output folder (default out/firmware)")
    p.set_defaults(func=cmd_firmware)

    p = sub.add_parser("validate", help="check a motion against the servos' limits before it runs",
                       description="Samples the motion every control period, computes its joint torques "
                       "(RNEA, gravity and payload included) and checks each joint against its position "
                       "and speed limits, the servo's torque-speed envelope at the supply voltage, its "
                       "current limit and winding temperature, the supply's rating, the bus's time per "
                       "tick and the range the wire can command. Exit status 0 pass, 1 fail, 2 bad input.")
    p.add_argument("config", help="robot configuration: built-in name or .toml file")
    p.add_argument("motion", nargs="+", help="built-in motion, keyframe file (.toml) or trajectory CSV (.csv); "
                   "several, a folder of CSVs or a glob ('logs/*.csv'): one verdict each, OUT/<motion>/ "
                   "each report, OUT/summary.json, exit status the worst")
    p.add_argument("--jobs", type=count(1, 256, "processes"), default=1, metavar="N",
                   help="validate several motions in N processes (default 1)")
    p.add_argument("--time-scale", type=float, default=None, metavar="S",
                   help="play the motion S times slower (default 1: as written)")
    p.add_argument("--payload", type=float, default=0.0, metavar="KG", help="a point mass carried at the hand")
    p.add_argument("--payload-body", default=None, metavar="BODY", help="the body carrying it (default: the last)")
    p.add_argument("--payload-com", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="where on that body, m in its frame (default: its centre of mass)")
    p.add_argument("--supply-voltage", type=float, default=None, metavar="V",
                   help="supply voltage (default: the configuration's)")
    p.add_argument("--margin", type=float, default=1.0, metavar="F",
                   help="fraction of each limit allowed (default 1.0; 0.8 keeps 20%% in reserve)")
    p.add_argument("--repeat", type=count(1, what="plays"), default=1, metavar="N", help="plays in a row, for the heat (default 1)")
    p.add_argument("--ambient", type=float, default=25.0, metavar="C", help="ambient temperature (default 25 °C)")
    p.add_argument("--fit", action="store_true", help="also find the smallest time scale at which every check passes")
    p.add_argument("--retime", action="store_true",
                   help="also re-time the path with TOPP-RA to the limits, check it densely and write it as "
                        "OUT/retimed.csv (servodyn swing --motion plays it)")
    p.add_argument("--simulate", action="store_true",
                   help="also play the motion on the simulated servos and compare where they saturate "
                        "with the prediction")
    p.add_argument("--out", default="out/validate", help="output folder (default out/validate)")
    p.set_defaults(func=cmd_validate)

    units = ", ".join(UNIT_NAMES)
    p = sub.add_parser("mocap", help="what a motion capture file (BVH) holds",
                       description="Motion capture files (BVH).")
    mocap = p.add_subparsers(dest="mocap_command", metavar="COMMAND")
    mocap.required = True
    p = mocap.add_parser("info", help="joints, frames, unit, up axis, rest frame and the arms found",
                         description="Joints and their channel orders, frames, rate and duration, the unit and up "
                         "axis guessed from the skeleton, whether frame 0 is a rest pose, the arm chains found by "
                         "the name tables (CMU/cgspeed, Mixamo, Motive, Xsens) and warnings.")
    p.add_argument("clip", metavar="CLIP.bvh")
    p.add_argument("--map", default=None, metavar="FILE",
                   help="TOML naming the arm's joints: [right] and/or [left] with thorax, clavicle (optional), "
                        "upper_arm, forearm, hand")
    p.add_argument("--unit", default=None, choices=UNIT_NAMES, help=f"the file's unit ({units}; default: guessed)")
    p.add_argument("--json", action="store_true", help="as JSON, for scripts")
    p.set_defaults(func=cmd_mocap_info)

    p = sub.add_parser("retarget", help="a captured arm (BVH) as a motion of the model's arm",
                       description="Retarget the arm of a BVH clip onto a model: each segment's orientation "
                       "relative to the thorax, split along the model's own dof axes, the elbow's hinge fitted from "
                       "the motion, outliers out, soft limits 2° inside the hard ones, an 8 Hz zero-phase low-pass, "
                       "a C2 lead-in from rest; written as a trajectory CSV with its qd and qdd (validate, swing "
                       "and view read it). Exit status 0 retargeted, 1 retargeted but flagged, 2 bad input.")
    p.add_argument("clip", metavar="CLIP.bvh")
    target = p.add_mutually_exclusive_group()
    target.add_argument("--model", default=None, help="model to retarget onto (default human_arm)")
    target.add_argument("--config", default=None, metavar="FILE",
                        help="robot configuration: its model, and validate --fit's time scale in the report")
    p.add_argument("--arm", default="right", choices=("right", "left"), help="which arm of the clip (default right)")
    p.add_argument("--frames", default=None, metavar="A:B", help="frames A to B-1 (default: all but a rest frame 0)")
    p.add_argument("--time", default=None, metavar="A:B", help="seconds A to B of the clip")
    p.add_argument("--unit", default=None, choices=UNIT_NAMES, help=f"the file's unit ({units}; default: guessed)")
    p.add_argument("--map", default=None, metavar="FILE", help="TOML naming the arm's joints (see mocap info)")
    p.add_argument("--method", default="angles", choices=("angles", "ik"), help="segment angles (default) or IK")
    p.add_argument("--twist", type=float, default=None, metavar="DEG",
                   help="the elbow axis's twist about the upper arm (default: fitted from the motion)")
    p.add_argument("-o", "--output", default=None, metavar="FILE",
                   help="trajectory CSV to write (default out/retarget/<clip>.csv)")
    p.add_argument("--report", default=None, metavar="DIR", help="write DIR/report.json and DIR/retarget.png")
    p.set_defaults(func=cmd_retarget)

    p = sub.add_parser("export-bvh", help="a motion of a model's arm as a BVH clip (Blender, retarget)",
                       description="Write a motion as a BVH clip: a standing figure in the CMU naming whose right "
                       "arm moves, its lengths the model's, Y up; retarget reads it back.")
    p.add_argument("motion", metavar="MOTION", help="built-in motion, keyframe file or trajectory CSV")
    p.add_argument("--model", default="human_arm", help="the motion's model (default human_arm)")
    p.add_argument("--order", default="ZXY", help="rotation channel order of every joint (default ZXY)")
    p.add_argument("--unit", default="cm", choices=UNIT_NAMES, help=f"the file's unit ({units}; default cm)")
    p.add_argument("--rest", default="hang", choices=("hang", "tpose"),
                   help="the pose of all channels zero: the hanging arm (default) or a T-pose")
    p.add_argument("--rate", type=float, default=120.0, help="frames per second (default 120)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.bvh", help="the file to write")
    p.add_argument("--yes", action="store_true", help="overwrite OUT.bvh without asking")
    p.set_defaults(func=cmd_export_bvh)

    p = sub.add_parser("size", help="choose each joint's servo so that the motions pass",
                       description="Choose a servo per joint from the catalogue (the Dynamixel and CAN servos "
                       "servodyn drives) so that every motion passes every check of `servodyn validate`, each "
                       "chosen servo's housing and rotor mounted on the model (a heavier wrist servo loads the "
                       "shoulder): from the hand inwards, the lightest that passes (or, --objective margin, the "
                       "lightest set with the largest reserve). Writes OUT/config.toml and OUT/model.toml, "
                       "validates them on every motion, and OUT/size.json. When nothing passes it names the "
                       "joint and check, and the time scale at which a set would. Exit status 0 a set passes, "
                       "1 none does, 2 bad input.")
    p.add_argument("model", help="model: built-in name or servodyn model file (.toml)")
    p.add_argument("--motion", action="append", required=True, metavar="M",
                   help="built-in motion, keyframe file or trajectory CSV (repeatable: every one must pass)")
    p.add_argument("--time-scale", type=float, default=1.0, metavar="S",
                   help="play the motions S times slower (default 1: as written)")
    p.add_argument("--payload", type=float, default=0.0, metavar="KG", help="a point mass carried at the hand")
    p.add_argument("--supply-voltage", type=float, default=None, metavar="V",
                   help="supply voltage (default: each of the family's nominal voltages, the best result)")
    p.add_argument("--margin", type=float, default=1.0, metavar="F",
                   help="fraction of each limit allowed (default 1.0; 0.8 keeps 20%% in reserve)")
    p.add_argument("--family", choices=sizing_families(), default="dynamixel",
                   help="which servos: dynamixel, can or any (default dynamixel)")
    p.add_argument("--objective", choices=("mass", "margin"), default="mass",
                   help="the lightest set (default), or the set with the largest reserve")
    p.add_argument("--repeat", type=count(1, 10_000, "plays"), default=1, metavar="N",
                   help="plays in a row, for the heat (default 1)")
    p.add_argument("--jobs", type=count(1, 256, "processes"), default=1, metavar="N",
                   help="spread the motions over N processes (default 1)")
    p.add_argument("--out", default="out/size", help="output folder (default out/size)")
    p.add_argument("--yes", action="store_true", help="overwrite OUT/config.toml and OUT/model.toml without asking")
    p.add_argument("--json", action="store_true", help="print the report as JSON (no progress on stderr)")
    p.set_defaults(func=cmd_size)

    p = sub.add_parser("ik", help="joint angles that put the hand at a point (or along a path)",
                       description="Inverse kinematics of the hand (the origin of the last body, the wrist centre "
                       "of the built-in arms) in the model's base frame (x forward, y left, z up): closed form for "
                       "an S-R-S arm (human_arm, the replicas), bounded damped least squares otherwise. One pose "
                       "with --to; a hand path with --path TARGETS.csv (columns t,x,y,z and optionally "
                       "roll,pitch,yaw in rad) -o MOTION.csv, a trajectory CSV that validate, swing and view read. "
                       "Exit status 0 solved, 1 refused (out of reach, no swivel inside the limits, a path held "
                       "back past --tolerance), 2 bad input.")
    p.add_argument("model", help="model: built-in name, .urdf or .toml")
    p.add_argument("--to", default=None, metavar="X,Y,Z",
                   help="hand position, m (--to=-0.1,0,0 when the first number is negative)")
    p.add_argument("--rpy", default=None, metavar="R,P,Y",
                   help="hand orientation, degrees (roll, pitch, yaw; URDF convention); default: any")
    p.add_argument("--swivel", type=float, default=None, metavar="DEG",
                   help="elbow swivel about the shoulder-wrist line, 0 = elbow down (default: nearest 0 "
                        "inside the limits; along a path, the previous sample's)")
    p.add_argument("--path", default=None, metavar="CSV", help="targets file: t,x,y,z[,roll,pitch,yaw]")
    p.add_argument("-o", "--output", default=None, metavar="CSV", help="trajectory to write (with --path)")
    p.add_argument("--dt", type=float, default=0.01, metavar="S", help="path sampling period (default 0.01 s)")
    p.add_argument("--max-speed", type=float, default=None, metavar="RAD/S",
                   help="no dof turns faster along the path (default: no bound)")
    p.add_argument("--tolerance", type=float, default=1e-3, metavar="M",
                   help="hand error a path may keep where the speed bound holds it back (default 0.001 m)")
    p.add_argument("--end", default=None, metavar="BODY", help="the hand body (default: r_hand, else the last)")
    p.set_defaults(func=cmd_ik)

    p = sub.add_parser("excite", help="write an exciting trajectory for servodyn identify",
                       description="A finite Fourier series per joint (Swevers et al.), its coefficients chosen "
                       "for a well conditioned identification, starting and ending at rest, written as a "
                       "trajectory CSV for servodyn swing --motion. The margin: each joint stays inside its "
                       "position limits less --margin of its range at both ends and under 0.6 of its velocity "
                       "limit; then servodyn validate checks it on the configuration, and while it fails every "
                       "excursion is scaled by 0.85. With --heat, a heating run for the thermal constants instead "
                       "(README: the heating run). Exit status 0 written, 2 bad input.")
    p.add_argument("--config", required=True, help="robot configuration: built-in name or .toml file")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="seconds, whole periods of about 10 s (default 30); with --heat the whole run (default "
                        "3 of the slowest heated joint's thermal time constants each side of the move, at most "
                        "600 s, the longest a swing plays)")
    p.add_argument("--joints", nargs="+", default=None, metavar="DOF",
                   help="only these joints move (default all); with --heat, only these are heated")
    p.add_argument("--heat", action="store_true",
                   help="a heating run instead, for the thermal constants: hold a pose gravity loads, then rest "
                        "where the arm hangs while the windings cool; every winding predicted within half its "
                        "headroom (temperature limit less 25 °C) on the configured thermal constants")
    p.add_argument("--harmonics", type=count(2, what="harmonics"), default=5, metavar="N",
                   help="harmonics per joint (default 5)")
    p.add_argument("--margin", type=float, default=0.1, metavar="F",
                   help="fraction of each joint's range kept clear at both ends (default 0.1)")
    p.add_argument("--seed", type=count(0, what="seed"), default=0, help="the optimiser's start (default 0)")
    p.add_argument("--out", default="out/excite/excitation.csv", metavar="CSV",
                   help="trajectory CSV to write (default out/excite/excitation.csv)")
    p.set_defaults(func=cmd_excite)

    p = sub.add_parser("identify", help="friction, armature, torque constants, payload from logs",
                       description="Least squares on swing logs (t, q_*, current_*; torque = current x "
                       "torque_constant x gear_ratio): per joint Coulomb and viscous friction, armature, "
                       "with --known-payload a torque-constant scale, from temperature_* columns the thermal "
                       "resistance and time constant; the payload's mass and centre of mass at a body. q and "
                       "the current go through one 4th-order Butterworth low-pass forwards and backwards "
                       "(zero lag, -6 dB at --cutoff) before q is differentiated twice. Writes "
                       "OUT/identified.json, OUT/patch.toml and OUT/torque_fit.png; what the logs cannot "
                       "determine is reported so, never invented. Exit status 0 done, 1 patch declined, "
                       "2 bad input.")
    p.add_argument("--config", required=True, help="robot configuration: built-in name or .toml file")
    p.add_argument("logs", nargs="+", metavar="LOG", help="swing_log.csv files (or their folders)")
    p.add_argument("--payload-body", default=None, metavar="BODY", help="the body carrying the payload (default: the last)")
    p.add_argument("--known-payload", type=float, default=0.0, metavar="KG",
                   help="the last LOG carried this mass more, at the payload body's centre of mass (as validate "
                        "--payload puts it): makes each joint's torque-constant scale identifiable")
    p.add_argument("--arm", action="store_true",
                   help="the whole arm's base inertial parameters instead of a payload")
    p.add_argument("--cutoff", type=float, default=10.0, metavar="HZ", help="the low-pass's cut-off (default 10 Hz)")
    p.add_argument("--out", default="out/identify", help="output folder (default out/identify)")
    p.add_argument("--apply", action="store_true",
                   help="also patch the configuration (comments kept), after showing the change and asking")
    p.add_argument("--write", default=None, metavar="FILE", help="with --apply: write the patched configuration here")
    p.add_argument("--yes", action="store_true", help="with --apply: write without asking")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("demo", help="torque profile of a sample reach of the built-in arm",
                       description="Torque profile of a sample reach of the built-in arm: CSV and PNG.")
    p.add_argument("--model", default="human_arm", help="model (default human_arm)")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.set_defaults(func=cmd_demo)
    return parser


def sizing_families() -> tuple[str, ...]:
    return ("dynamixel", "can", "any")


def _file_error(err: OSError, args) -> str:
    """One line for a file the command could not read or write: the path and the reason. A
    write that fails on close (a full device) carries no file name; the command's output does."""
    path = err.filename or getattr(args, "output", None) or getattr(args, "out", None)
    if isinstance(err, IsADirectoryError):
        reason = "is a folder, not a file"
    elif isinstance(err, (FileExistsError, NotADirectoryError)):
        reason = "is a file where a folder is needed"
    else:
        reason = err.strerror or str(err)
    return f"{path}: {reason}" if path else reason


# numpy's floating-point warnings: raised as errors in a command, so a result computed from an
# overflow or a 0/0 is never printed beside a warning the user cannot act on
NUMPY_WARNINGS = r"(overflow|invalid value|divide by zero) encountered"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "command", None) == "experiment" and args.out is None:
        args.out = f"out/{args.name}"
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=NUMPY_WARNINGS, category=RuntimeWarning)
        return _run(args)


def _run(args) -> int:
    try:
        return args.func(args) or 0
    except RuntimeWarning as err:
        print(f"servodyn: error: a computation left the range of double precision ({err}): an input "
              "is far outside what the model and the servos allow", file=sys.stderr)
        return 2
    except (CliError, ModelError, TrajectoryError, FloatingPointError) as err:
        print(f"servodyn: error: {err}", file=sys.stderr)
        return getattr(err, "code", 2)
    except BrokenPipeError:        # `servodyn list | head`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as err:
        print(f"servodyn: error: {_file_error(err, args)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("servodyn: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
