"""The motion-capture verbs: `servodyn mocap info CLIP.bvh` (what a clip holds: data, on stdout),
`servodyn retarget CLIP.bvh` (a captured arm as a motion) and `servodyn export-bvh MOTION`."""

from __future__ import annotations

from pathlib import Path

from ...hal.config import load_config
from ...mocap.export import ORDERS, REST_POSES
from ...mocap.skeleton import UNITS
from ...model import load_model
from .prompt import ask
from ..mocap import export_bvh as write_clip, mocap_info, run_retarget
from .common import Verb, describe, say

UNIT_HELP = ", ".join(UNITS)


def _mocap_arguments(p) -> None:
    describe(p, "Motion capture files (BVH).", "servodyn mocap info clip.bvh --json")
    mocap = p.add_subparsers(dest="mocap_command", metavar="COMMAND")
    mocap.required = True
    info = mocap.add_parser("info", help="joints, frames, unit, up axis, rest frame and the arms found",
                            formatter_class=p.formatter_class)
    describe(info, "Joints and their channel orders, frames, rate and duration, the unit and up axis guessed from the "
             "skeleton, whether frame 0 is a rest pose, the arm chains found by the name tables (CMU/cgspeed, "
             "Mixamo, Motive, Xsens) and warnings.", "servodyn mocap info clip.bvh --map names.toml")
    info.add_argument("clip", metavar="CLIP.bvh")
    info.add_argument("--map", default=None, metavar="FILE",
                      help="TOML naming the arm's joints: [right] and/or [left] with thorax, clavicle (optional), "
                           "upper_arm, forearm, hand")
    info.add_argument("--unit", default=None, choices=list(UNITS), help=f"the file's unit ({UNIT_HELP}; default: "
                                                                         "guessed)")
    info.add_argument("--json", action="store_true", help="as JSON, for scripts")


def _mocap(args) -> int:
    mocap_info(args.clip, map_file=args.map, unit=args.unit, as_json=args.json, say=print)
    return 0


def _retarget_arguments(p) -> None:
    describe(p, "Retarget the arm of a BVH clip onto a model: each segment's orientation relative to the thorax, "
             "split along the model's own dof axes, the elbow's hinge fitted from the motion, outliers out, soft "
             "limits 2° inside the hard ones, an 8 Hz zero-phase low-pass, a C2 lead-in from rest; written as a "
             "trajectory CSV with its qd and qdd (validate, swing and view read it).",
             "servodyn retarget clip.bvh --config replica -o motion.csv --report out/retarget",
             exits="0 retargeted, 1 retargeted but flagged")
    p.add_argument("clip", metavar="CLIP.bvh")
    target = p.add_mutually_exclusive_group()
    target.add_argument("--model", default=None, help="model to retarget onto (default human_arm)")
    target.add_argument("--config", default=None, metavar="FILE",
                        help="robot configuration: its model, and validate --fit's time scale in the report")
    p.add_argument("--arm", default="right", choices=("right", "left"), help="which arm of the clip (default right)")
    p.add_argument("--frames", default=None, metavar="A:B", help="frames A to B-1 (default: all but a rest frame 0)")
    p.add_argument("--time", default=None, metavar="A:B", help="seconds A to B of the clip")
    p.add_argument("--unit", default=None, choices=list(UNITS), help=f"the file's unit ({UNIT_HELP}; default: guessed)")
    p.add_argument("--map", default=None, metavar="FILE", help="TOML naming the arm's joints (see mocap info)")
    p.add_argument("--method", default="angles", choices=("angles", "ik"), help="segment angles (default) or IK")
    p.add_argument("--twist", type=float, default=None, metavar="DEG",
                   help="the elbow axis's twist about the upper arm (default: fitted from the motion)")
    p.add_argument("-o", "--output", default=None, metavar="FILE",
                   help="trajectory CSV to write (a file; default out/retarget/<clip>.csv)")
    p.add_argument("--report", default=None, metavar="DIR", help="write DIR/report.json and DIR/retarget.png")


def _retarget(args) -> int:
    config = load_config(args.config) if args.config else None
    model = None if config else load_model(args.model or "human_arm")
    report = run_retarget(args.clip, model=model, config=config, arm=args.arm, frames=args.frames, time=args.time,
                          unit=args.unit, map_file=args.map, method=args.method, twist_deg=args.twist,
                          output=args.output, report_dir=args.report, say=say)
    return 1 if report["flags"] else 0


def _export_bvh_arguments(p) -> None:
    describe(p, "Write a motion as a BVH clip: a standing figure in the CMU naming whose right arm moves, its lengths "
             "the model's, Y up; retarget reads it back.", "servodyn export-bvh tennis_forehand -o forehand.bvh")
    p.add_argument("motion", metavar="MOTION", help="built-in motion, keyframe file or trajectory CSV")
    p.add_argument("--model", default="human_arm", help="the motion's model (default human_arm)")
    p.add_argument("--order", default="ZXY", help=f"rotation channel order of every joint ({', '.join(ORDERS)}; "
                                                  "default ZXY)")
    p.add_argument("--unit", default="cm", choices=list(UNITS), help=f"the file's unit ({UNIT_HELP}; default cm)")
    p.add_argument("--rest", default=REST_POSES[0], choices=REST_POSES,
                   help="the pose of all channels zero: the hanging arm (default) or a T-pose")
    p.add_argument("--rate", type=float, default=120.0, help="frames per second (default 120)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.bvh", help="the file to write")
    p.add_argument("--yes", action="store_true", help="overwrite OUT.bvh without asking")


def _export_bvh(args) -> int:
    model = load_model(args.model)
    # a file that exists is replaced only when the user says so (a clip may be a capture)
    if Path(args.output).exists() and not ask(f"{args.output} exists: overwrite it?", args.yes, say):
        say(f"{args.output}: kept as it was, nothing written (--yes overwrites)")
        return 1
    write_clip(args.motion, model, args.output, order=args.order, unit=args.unit, rest=args.rest, rate=args.rate,
               say=say)
    return 0


mocap = Verb(_mocap_arguments, _mocap)
retarget = Verb(_retarget_arguments, _retarget)
export_bvh = Verb(_export_bvh_arguments, _export_bvh)
