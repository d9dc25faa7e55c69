"""`servodyn torques MODEL TRAJ.csv -o OUT.csv`: feed-forward torques of a trajectory, offline."""

from __future__ import annotations

import re
import time

import numpy as np

from ...control.motion import check_limits
from ...control.trajectory import read_trajectory_csv, write_columns_csv
from ...errors import InputError
from ...model import load_model
from ...readable import fixed
from .argtypes import count
from .common import CliError, describe, say


def add_arguments(p) -> None:
    describe(p, "Feed-forward joint torques of a trajectory. The CSV has a header t, q_<dof> for every dof, and "
             "optionally qd_<dof>, qdd_<dof> (otherwise derived from a C2 cubic spline of q). SI units. The peak "
             "torques are printed (stdout).", "servodyn torques human_arm reach.csv -o tau.csv")
    p.add_argument("model", help="built-in model name, .urdf or .toml file")
    p.add_argument("trajectory", help="trajectory CSV")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv", help="torque CSV to write (t, tau_<dof>)")
    p.add_argument("--top", type=count(0), default=7, help="how many peak torques to print (default 7)")
    p.add_argument("--max-velocity", type=float, default=None, metavar="RAD_S",
                   help="refuse a trajectory faster than this at any dof")
    p.add_argument("--max-acceleration", type=float, default=None, metavar="RAD_S2",
                   help="refuse a trajectory accelerating harder than this at any dof")
    p.add_argument("--ignore-limits", action="store_true",
                   help="skip the trajectory checks: joint limits, and --max-velocity and --max-acceleration when "
                        "given")


def run(args) -> int:
    model = load_model(args.model)
    if model.nq != model.nv:
        raise CliError(f"{args.model}: a trajectory CSV gives one angle per dof; this model has "
                       "quaternion coordinates (a free root or ball joints)")
    traj = read_trajectory_csv(args.trajectory, model.dof_names)
    if not args.ignore_limits:
        check_limits(traj, model, origin=str(args.trajectory), velocity=args.max_velocity,
                     acceleration=args.max_acceleration)
    start = time.perf_counter()
    try:
        tau = model.inverse_dynamics(traj.q, traj.qd, traj.qdd)
    except FloatingPointError as err:
        row = int(re.search(r"row (\d+)", str(err)).group(1))
        raise InputError(f"{args.trajectory}: t = {traj.t[row]:.3f} s (sample {row + 1}): the torques overflow "
                         "double precision (qd or qdd far too large)") from None
    elapsed = time.perf_counter() - start
    write_columns_csv(args.output, traj.t, "tau", model.dof_names, tau)
    how = "qd, qdd from a C2 spline of q" if traj.derived else "qd, qdd from the file"
    say(f"{len(traj.t)} samples, {model.nq} dofs ({how}): inverse dynamics in "
        f"{elapsed * 1e3:.2f} ms ({elapsed / len(traj.t) * 1e6:.2f} us per sample) -> {args.output}")
    peak = np.abs(tau).max(axis=0)
    for name, value in sorted(zip(model.dof_names, peak), key=lambda x: -x[1])[:args.top]:
        print(f"  peak |tau| {name:<24} {fixed(value, 3):>9} N·m")
    return 0
