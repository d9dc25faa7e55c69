"""`servodyn identify --config FILE LOG...`: friction, armature, torque constants, payload from logs."""

from __future__ import annotations

from pathlib import Path

from ...identification.signals import FILTER_HZ
from .argtypes import number, positive
from ..actuator import run as run_actuator
from ..identify import run as run_identify
from .common import CliError, describe, out_folder, say
from .prompt import ask


def add_arguments(p) -> None:
    describe(p, "Least squares on swing logs (t, q_*, current_*; torque = current x torque_constant x gear_ratio): "
             "per joint Coulomb and viscous friction, armature, with --known-payload a torque-constant scale, from "
             "temperature_* columns the thermal resistance and time constant; the payload's mass and centre of mass "
             "at a body. q and the current go through one 4th-order Butterworth low-pass forwards and backwards "
             "(zero lag, -6 dB at --cutoff) before q is differentiated twice. Writes OUT/identified.json, "
             "OUT/patch.toml and OUT/torque_fit.png; what the logs cannot determine is reported so, never invented.",
             "servodyn identify --config replica out/bare out/loaded --known-payload 0.5 --out out/identify",
             "servodyn identify --actuator XL330-M288 bench/*.json --out out/identify",
             "servodyn identify --actuator STS3250 sts3250/*.json --out out/sts3250",
             exits="0 done, 1 patch declined")
    p.add_argument("--config", default=None, help="robot configuration: built-in name or .toml file (required "
                                                  "unless --actuator)")
    p.add_argument("--actuator", default=None, metavar="MODEL",
                   help="instead: the servo MODEL's motor (k_t, R, armature, friction, zero offset) from servo-bench "
                        "logs (JSON, docs/servo-bench.md) of position, supply and the PWM where logged (without "
                        "it, what the logs leave undetermined is printed); writes OUT/actuator.json")
    p.add_argument("logs", nargs="+", metavar="LOG", help="swing_log.csv files (or their folders); with --actuator, "
                                                          "bench logs (.json)")
    p.add_argument("--payload-body", default=None, metavar="BODY",
                   help="the body carrying the payload (default: the last)")
    p.add_argument("--known-payload", type=number(0, what="kg"), default=0.0, metavar="KG",
                   help="the LOG named by --loaded (default: the last LOG) carried this mass more, at the payload "
                        "body's centre of mass (as validate --payload puts it): makes each joint's torque-constant "
                        "scale identifiable")
    p.add_argument("--loaded", default=None, metavar="LOG",
                   help="with --known-payload: which LOG carried the payload (default: the last)")
    p.add_argument("--arm", action="store_true", help="the whole arm's base inertial parameters instead of a payload")
    p.add_argument("--cutoff", type=positive, default=FILTER_HZ, metavar="HZ",
                   help=f"the low-pass's cut-off (default {FILTER_HZ:g} Hz)")
    out_folder(p, "out/identify")
    p.add_argument("--apply", action="store_true",
                   help="also patch the configuration (comments kept), after showing the change and asking")
    p.add_argument("--write", default=None, metavar="FILE", help="with --apply: write the patched configuration here")
    p.add_argument("--yes", action="store_true", help="with --apply: write without asking")


def run(args) -> int:
    if args.actuator is not None:
        if args.config is not None:
            raise CliError("--actuator identifies a servo from bench logs: it takes no --config")
        return run_actuator(args.actuator, args.logs, Path(args.out), say=say)
    if args.config is None:
        raise CliError("identify needs --config (or --actuator MODEL for servo-bench logs)")
    return run_identify(args.config, args.logs, args.payload_body, args.known_payload, args.arm, Path(args.out),
                        cutoff=args.cutoff, apply_to=args.write, apply=args.apply,
                        confirm=lambda question: ask(question, args.yes, say), say=say, warn=say,
                        loaded=args.loaded)
