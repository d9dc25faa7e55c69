"""`servodyn validate CONFIG MOTION...`: a motion checked against the servos' limits before it runs.
The verdict table is the command's result, on stdout (validate's one `say` also carries its
"wrote" lines there)."""

from __future__ import annotations

from pathlib import Path

from ...hal.config import load_config
from ...validation import AMBIENT
from ...validation.lerobot import FEATURES
from ...validation.lerobot_motion import CUTOFF_HZ, UNITS
from ...validation.lerobot_report import validate_dataset
from .argtypes import count, positive
from ...report.validation import expand_motions, validate, validate_many
from .common import CliError, describe, out_folder


def add_arguments(p) -> None:
    describe(p, "Samples the motion every control period, computes its joint torques (RNEA, gravity and payload "
             "included) and checks each joint against its position and speed limits, the servo's torque-speed "
             "envelope at the supply voltage, its current limit and winding temperature, the supply's rating, the "
             "bus's time per tick and the range the wire can command.",
             "servodyn validate replica tennis_forehand --time-scale 4 --fit",
             "servodyn validate --config replica_can 'logs/*.csv' --jobs 2",
             "servodyn validate replica tennis_forehand --near-people",
             "servodyn validate so101 --lerobot ~/datasets/pick_cube --episode 0 3 --jobs 2 --out out/pick_cube",
             exits="0 pass, 1 fail (with --lerobot: every episode passes / one fails)")
    p.add_argument("subjects", nargs="*", metavar="[CONFIG] MOTION",
                   help="robot configuration (built-in name or .toml file; or give it as --config), then the "
                        "motions: built-in motion, keyframe file (.toml) or trajectory CSV (.csv); several, a folder "
                        "of CSVs or a glob ('logs/*.csv'): one verdict each, OUT/<motion>/ each report, "
                        "OUT/summary.json, exit status the worst")
    p.add_argument("--config", default=None, help="robot configuration (then every positional is a motion)")
    p.add_argument("--jobs", type=count(1, 256, "processes"), default=1, metavar="N",
                   help="validate several motions in N processes (default 1)")
    p.add_argument("--time-scale", type=positive, default=None, metavar="S",
                   help="play the motion S times slower (default: the configuration's for the motion, as a swing "
                        "plays it — its time scale for the forehand, 1 for any other motion)")
    p.add_argument("--payload", type=float, default=0.0, metavar="KG",
                   help="a point mass carried at the hand")
    p.add_argument("--payload-body", default=None, metavar="BODY", help="the body carrying it (default: the last)")
    p.add_argument("--payload-com", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="where on that body, m in its frame (default: its centre of mass)")
    p.add_argument("--supply-voltage", type=float, default=None, metavar="V",
                   help="supply voltage (default: the configuration's)")
    p.add_argument("--margin", type=float, default=1.0, metavar="F",
                   help="fraction of each limit allowed (default 1.0; 0.8 keeps 20%% in reserve)")
    p.add_argument("--repeat", type=count(1, what="plays"), default=1, metavar="N",
                   help="plays in a row, for the heat (default 1)")
    p.add_argument("--ambient", type=float, default=AMBIENT, metavar="C",
                   help=f"ambient temperature (default {AMBIENT:g} °C)")
    p.add_argument("--fit", action="store_true", help="also find the smallest time scale at which every check passes")
    p.add_argument("--near-people", action="store_true",
                   help="also check each link's peak speed against ISO/TS 15066's transient-contact limits per body "
                        "region (hand, lower arm, upper arm, chest; Tables A.2/A.3, with the link's effective mass "
                        "along its velocity, armature included; head and face: no contact at any speed), fail when "
                        "one is exceeded and name the fastest time scale that passes")
    p.add_argument("--retime", action="store_true",
                   help="also re-time the path with TOPP-RA to the limits, check it densely and write it as "
                        "OUT/retimed.csv (servodyn swing --motion plays it)")
    p.add_argument("--simulate", action="store_true",
                   help="also play the motion on the simulated servos and compare where they saturate with the "
                        "prediction")
    lerobot = p.add_argument_group("a LeRobot dataset (v3.0 or v2.1, read with pyarrow: pip install "
                                   "'servodyn[lerobot]'; docs/lerobot.md)")
    lerobot.add_argument("--lerobot", default=None, metavar="DATASET_DIR",
                         help="validate each episode of this dataset (its meta/info.json and data/ parquet files) "
                              "instead of a motion: a line each, OUT/report.json; --time-scale 1 unless given")
    lerobot.add_argument("--episode", type=count(0, what="an episode_index"), nargs="+", default=None, metavar="N",
                         help="only these episodes (default every one)")
    lerobot.add_argument("--feature", choices=FEATURES, default="action",
                         help="the joint positions to validate (default action: what the arm was told to do)")
    lerobot.add_argument("--units", choices=("auto", *UNITS), default="auto",
                         help="the body joints' units: degrees about the calibration's midpoint or the older "
                              "range_m100_100 (the gripper is always 0..100); default auto: from meta/info.json, "
                              "the values or the codebase version, said with the verdicts")
    lerobot.add_argument("--cutoff", type=positive, default=CUTOFF_HZ, metavar="HZ",
                         help=f"the zero-lag low-pass's cutoff before differentiating (default {CUTOFF_HZ:g} Hz)")
    out_folder(p, "out/validate")


def run(args) -> int:
    if args.lerobot is not None:
        return run_lerobot(args)
    if args.episode is not None:
        raise CliError("--episode picks episodes of a LeRobot dataset: give it with --lerobot DATASET_DIR")
    if not args.subjects:
        raise CliError("give a configuration and a motion: servodyn validate CONFIG MOTION")
    config_ref, motions = (args.config, args.subjects) if args.config else (args.subjects[0], args.subjects[1:])
    if not motions:
        raise CliError("give a motion after the configuration: servodyn validate CONFIG MOTION")
    options = dict(time_scale=args.time_scale, payload=args.payload, payload_body=args.payload_body,
                   payload_com=args.payload_com, supply_voltage=args.supply_voltage, margin=args.margin,
                   repeat=args.repeat, ambient=args.ambient, fit=args.fit, retime_motion=args.retime,
                   simulate_motion=args.simulate, near_people=args.near_people)
    config = load_config(config_ref)
    expanded = expand_motions(motions)
    if len(motions) == 1 and expanded == motions:       # one motion: its report, as always
        return 0 if validate(config, expanded[0], out=Path(args.out), say=print, **options)["passed"] else 1
    return validate_many(config, expanded, jobs=args.jobs, out=Path(args.out), say=print, **options)["code"]


def run_lerobot(args) -> int:
    """servodyn validate CONFIG --lerobot DIR: 0 every episode passes, 1 one fails, 2 a bad dataset."""
    config_ref = args.config or (args.subjects[0] if args.subjects else None)
    extra = args.subjects[1:] if not args.config else args.subjects
    if config_ref is None:
        raise CliError("give the configuration: servodyn validate CONFIG --lerobot DATASET_DIR")
    unused = [flag for flag, given in (("--fit", args.fit), ("--retime", args.retime), ("--simulate", args.simulate),
                                       ("--near-people", args.near_people), ("--payload", args.payload),
                                       ("--supply-voltage", args.supply_voltage is not None)) if given]
    if unused:
        raise CliError(f"{unused[0]} is not for --lerobot (each episode's fit time scale is always found)")
    if extra:
        raise CliError(f"--lerobot validates a dataset's episodes; '{extra[0]}' is a motion too: give one or the other")
    report = validate_dataset(load_config(config_ref), args.lerobot, feature=args.feature, units=args.units,
                              episodes=args.episode, time_scale=args.time_scale or 1.0, cutoff=args.cutoff,
                              margin=args.margin, repeat=args.repeat, ambient=args.ambient, jobs=args.jobs, out=Path(args.out), say=print)
    return report["code"]
