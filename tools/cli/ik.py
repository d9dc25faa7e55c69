"""`servodyn ik MODEL --to X,Y,Z` (one pose, printed: data on stdout) or `--path TARGETS.csv -o
MOTION.csv` (a hand path as a trajectory)."""

from __future__ import annotations

import numpy as np

from .argtypes import positive
from ..ik import IkInputError, parse_triple, pose_report, read_targets, solve_pose, solve_targets, write_path
from ...model import load_model
from .common import describe, say


def add_arguments(p) -> None:
    describe(p, "Inverse kinematics of the hand (the origin of the last body, the wrist centre of the built-in arms) "
             "in the model's base frame (x forward, y left, z up): closed form for an S-R-S arm (human_arm, the "
             "replicas), bounded damped least squares otherwise. One pose with --to; a hand path with --path "
             "TARGETS.csv (columns t,x,y,z and optionally roll,pitch,yaw in rad) -o MOTION.csv, a trajectory CSV "
             "that validate, swing and view read.",
             "servodyn ik human_arm --to 0.3,-0.2,0.1 --rpy 0,0,90",
             exits="0 solved, 1 refused (out of reach, no swivel inside the limits, a path held back past "
                   "--tolerance)")
    p.add_argument("model", help="model: built-in name, .urdf or .toml")
    p.add_argument("--to", default=None, metavar="X,Y,Z",
                   help="hand position, m (--to=-0.1,0,0 when the first number is negative)")
    p.add_argument("--rpy", default=None, metavar="R,P,Y",
                   help="hand orientation, degrees (roll, pitch, yaw; URDF convention); default: any")
    p.add_argument("--swivel", type=float, default=None, metavar="DEG",
                   help="elbow swivel about the shoulder-wrist line, 0 = elbow down (default: nearest 0 inside the "
                        "limits; along a path, the previous sample's)")
    p.add_argument("--path", default=None, metavar="CSV", help="targets file: t,x,y,z[,roll,pitch,yaw]")
    p.add_argument("-o", "--output", default=None, metavar="CSV", help="trajectory to write (a file; with --path)")
    p.add_argument("--dt", type=positive, default=0.01, metavar="S", help="path sampling period (default 0.01 s)")
    p.add_argument("--max-speed", type=positive, default=None, metavar="RAD/S",
                   help="no dof turns faster along the path (default: no bound)")
    p.add_argument("--tolerance", type=float, default=1e-3, metavar="M",
                   help="hand error a path may keep where the speed bound holds it back (default 0.001 m)")
    p.add_argument("--end", default=None, metavar="BODY", help="the hand body (default: r_hand, else the last)")


def run(args) -> int:
    model = load_model(args.model)
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
    targets = read_targets(args.path)
    shown = [0]

    def progress(i, n):
        if n >= 200 and i * 10 // n > shown[0]:
            shown[0] = i * 10 // n
            say(f"  {i}/{n} samples")
    traj, result = solve_targets(model, targets, args.dt, args.max_speed, args.swivel, args.end, progress)
    write_path(model, traj, args.output)
    worst = int(np.argmax(result.position_error))
    say(f"{len(traj.t)} samples every {args.dt:g} s ({traj.t[-1]:.3f} s), {model.nv} dofs -> {args.output}")
    say(f"hand error: largest {result.position_error.max() * 1e3:.3g} mm at t = {traj.t[worst]:.3f} s, "
        f"{np.degrees(result.rotation_error.max()):.3g}°; {int(result.slowed.sum())} samples held back by "
        f"--max-speed; reach up to {result.reach.max():.3f}")
    return 1 if result.position_error.max() > args.tolerance else 0
