"""`servodyn size MODEL --motion M...`: a servo per joint so that every motion passes (the report
on stdout, as text or --json; progress on stderr)."""

from __future__ import annotations

import json
from pathlib import Path

from ...validation.sizing import FAMILIES, OBJECTIVES, SIZING_MARGIN, default_family
from .argtypes import count, number, positive
from ...report.sizing import run_size, text
from .common import describe, out_folder, say
from .prompt import ask


def add_arguments(p) -> None:
    describe(p, "Choose a servo per joint from the catalogue (the Dynamixel, CAN and Feetech servos servodyn drives) "
             "so that every motion passes every check of `servodyn validate`, each chosen servo's housing and rotor "
             "mounted on the model (a heavier wrist servo loads the shoulder): from the hand inwards, the lightest that "
             "passes (or, --objective margin, the lightest set with the largest reserve). Writes OUT/config.toml and "
             "OUT/model.toml, validates them on every motion, and OUT/size.json. When nothing passes it names the "
             "joint and check, and the time scale at which a set would.",
             "servodyn size human_arm --motion tennis_forehand --time-scale 3 --family any",
             "servodyn size so101 --motion so101_pick --supply-voltage 12 --out out/so101",
             exits="0 a set passes, 1 none does")
    p.add_argument("model", help="model: built-in name or servodyn model file (.toml)")
    p.add_argument("--motion", action="append", required=True, metavar="M",
                   help="built-in motion, keyframe file or trajectory CSV (repeatable: every one must pass)")
    p.add_argument("--time-scale", type=positive, default=1.0, metavar="S",
                   help="play the motions S times slower (default 1: as written)")
    p.add_argument("--payload", type=float, default=0.0, metavar="KG", help="a point mass carried at the hand")
    p.add_argument("--supply-voltage", type=float, default=None, metavar="V",
                   help="supply voltage (default: each of the family's nominal voltages, the best result)")
    p.add_argument("--margin", type=number(0, 1, "of each limit", above=True), default=SIZING_MARGIN, metavar="F",
                   help=f"fraction of each limit allowed (default {SIZING_MARGIN:g}: {100 * (1 - SIZING_MARGIN):.0f}%% "
                        "of every limit kept in reserve for what the model does not know — friction, a supply "
                        "that sags, a warm room; 1 keeps none)")
    p.add_argument("--family", choices=FAMILIES, default=None,
                   help=f"which servos: {', '.join(FAMILIES)} (any: Dynamixel and CAN; default: the bus kind of the "
                        f"model's built-in configurations where they share one, e.g. feetech for so101, else "
                        f"{FAMILIES[0]})")
    p.add_argument("--objective", choices=OBJECTIVES, default=OBJECTIVES[0],
                   help=f"{OBJECTIVES[0]}: the lightest set (default); {OBJECTIVES[1]}: the set with the largest "
                        "reserve")
    p.add_argument("--repeat", type=count(1, 10_000, "plays"), default=1, metavar="N",
                   help="plays in a row, for the heat (default 1)")
    p.add_argument("--jobs", type=count(1, 256, "processes"), default=1, metavar="N",
                   help="spread the motions over N processes (default 1)")
    out_folder(p, "out/size")
    p.add_argument("--yes", action="store_true", help="overwrite OUT/config.toml and OUT/model.toml without asking")
    p.add_argument("--json", action="store_true", help="print the report as JSON (no progress on stderr)")


def run(args) -> int:
    report = run_size(args.model, args.motion, time_scale=args.time_scale, payload=args.payload,
                      supply_voltage=args.supply_voltage, margin=args.margin,
                      family=args.family or default_family(args.model),
                      objective=args.objective, jobs=args.jobs, repeat=args.repeat, out=Path(args.out),
                      confirm=lambda question: ask(question, args.yes, say), say=say,
                      progress=None if args.json else say)
    print(json.dumps(report, indent=1) if args.json else text(report))
    return 0 if report["passed"] else 1
