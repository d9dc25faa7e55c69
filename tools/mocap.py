"""`servodyn mocap info`, `servodyn retarget` and `servodyn export-bvh`: captured human motion in
and out, over the servodyn.mocap library.

retarget's exit status: 0 retargeted, 1 retargeted but flagged (the report says why), 2 bad input.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from ..control.motion import motion_path
from ..control.trajectory import write_trajectory_csv
from ..errors import ServodynError
from ..mocap import ArmTarget, Clip, find_arms, guess_axes, read_bvh, retarget, write_bvh
from ..mocap.bvh import MAX_RATE_HZ, MIN_RATE_HZ
from ..mocap.export import ORDERS, arm_clip
from ..mocap.skeleton import ROLES, UNITS, ArmChain, rest_frame, skeleton_height, guess_unit
from ..outputs import refuse_input_as_output
from ..report.plots import _pyplot, short
from ..report.validation import validate

# a retargeted motion is flagged (exit 1) past these
FLAG_LIMIT_FRACTION = 0.01        # frames of one dof outside its soft limits, clamped
FLAG_ELBOW_RESIDUAL_DEG = 10.0    # p95 of the forearm off the model's elbow hinge
FLAG_HAND_ERROR_MM = 50.0         # p95 of the hand's distance from the captured hand
FLAG_TORQUE_GRAVITY = 3.0         # a torque spike: a peak over the motion's largest gravity torque ...
FLAG_TORQUE_SPIKE = 3.0           # ... and over the dof's own 99th percentile (a glitch, not a fast motion)
FLAG_TIME_SCALE = 10.0            # validate --fit's scale beyond which the servos are far too slow


class MocapError(ServodynError, ValueError):
    """Bad input to a mocap command: one line."""


def _clip(path: str) -> Clip:
    return read_bvh(path)


def _arms(clip: Clip, map_file) -> dict[str, ArmChain]:
    arms = find_arms(clip, map_file)
    if not arms:
        raise MocapError(f"{clip.source}: no arm found by the name tables (CMU/cgspeed, Mixamo, Motive, Xsens): "
                         "name its joints with --map FILE (a TOML with [right] thorax, clavicle, upper_arm, "
                         "forearm, hand)")
    return arms


def describe(clip: Clip, map_file=None, unit: str | None = None) -> dict:
    """What `mocap info` says about a clip, as data."""
    arms = _arms(clip, map_file)
    axes, warnings = guess_axes(clip, arms)
    height = skeleton_height(clip, np.linalg.solve(axes.A, [0.0, 0.0, 1.0]))
    guessed = guess_unit(height)
    unit = unit or guessed
    chain = arms.get("right") or next(iter(arms.values()))
    drop, first, median = rest_frame(clip, chain)
    return {
        "file": clip.source, "frames": clip.frames, "rate_hz": clip.rate, "frame_time_s": clip.frame_time,
        "duration_s": clip.duration,
        "joints": [{"name": j.name, "parent": clip.joints[j.parent].name if j.parent >= 0 else None,
                    "channels": len(j.channels), "order": j.order, "end_site": j.end_site is not None}
                   for j in clip.joints],
        "unit": {"name": unit, "metres": UNITS[unit], "guessed": guessed, "height": height,
                 "height_m": height * UNITS[unit]},
        "up": axes.up, "forward": axes.forward,
        "rest_frame": {"frame0_is_rest": drop, "first_step_deg": math.degrees(first),
                       "median_step_deg": math.degrees(median)},
        "arms": {side: {"source": c.source, **c.names(clip)} for side, c in arms.items()},
        "warnings": clip.warnings + warnings,
    }


def info_text(d: dict) -> str:
    orders = {}
    for j in d["joints"]:
        orders.setdefault(j["order"] or "-", []).append(j["name"])
    lines = [f"{d['file']}: {len(d['joints'])} joints, {d['frames']} frames at {d['rate_hz']:.4g} Hz "
             f"({d['duration_s']:.2f} s)",
             f"unit: {d['unit']['name']} ({d['unit']['metres']:g} m{'' if d['unit']['name'] == d['unit']['guessed'] else ', given'}"
             f"; the skeleton is {d['unit']['height']:.4g} units = {d['unit']['height_m']:.2f} m tall); "
             f"up {d['up']}, forward {d['forward']}"]
    rest = d["rest_frame"]
    lines.append("rest: frame 0 is a rest pose (its step {:.1f}° against a median {:.2f}°): retarget drops it"
                 .format(rest["first_step_deg"], rest["median_step_deg"]) if rest["frame0_is_rest"]
                 else "rest: frame 0 moves like the others (kept); all channels zero is the rest pose")
    for side, arm in d["arms"].items():
        chain = ", ".join(f"{role.replace('_', ' ')} {arm[role]}" for role in ROLES if arm[role])
        lines.append(f"{side} arm ({arm['source']}): {chain}")
    lines.append("channel orders: " + "; ".join(f"{o} {len(n)} joint{'s' if len(n) > 1 else ''}"
                                                for o, n in orders.items()))
    six = [j["name"] for j in d["joints"] if j["channels"] == 6]
    if six:
        lines.append(f"6-channel joints: {', '.join(six)}")
    lines += [f"warning: {w}" for w in d["warnings"]]
    return "\n".join(lines)


def mocap_info(clip_path: str, map_file=None, unit=None, as_json=False, say=print) -> dict:
    d = describe(_clip(clip_path), map_file, unit)
    say(json.dumps(d, indent=1) if as_json else info_text(d))
    return d


# ---------------------------------------------------------------------------- retarget

def parse_span(text: str, what: str, kind) -> tuple:
    """'A:B' (either side may be empty) as two numbers or None."""
    parts = text.split(":")
    if len(parts) != 2:
        raise MocapError(f"--{what} '{text}': expected A:B (e.g. 120:1320, or 120: to the end)")
    try:
        out = tuple(kind(p) if p.strip() else None for p in parts)
    except ValueError:
        raise MocapError(f"--{what} '{text}': A and B must be {'whole ' if kind is int else ''}numbers") from None
    if any(v is not None and not (math.isfinite(v) and v >= 0) for v in out):
        raise MocapError(f"--{what} '{text}': A and B must be 0 or more")
    if None not in out and out[1] <= out[0]:
        raise MocapError(f"--{what} '{text}': B must come after A")
    return out


def frame_slice(clip: Clip, frames: str | None, time: str | None) -> slice | None:
    if frames and time:
        raise MocapError("give --frames or --time, not both")
    if frames:
        a, b = parse_span(frames, "frames", int)
    elif time:
        a, b = parse_span(time, "time", float)
        if a is not None and a > clip.duration:
            raise MocapError(f"--time {time}: starts at {a:g} s, after the clip's last frame ({clip.duration:.3f} s)")
        a = None if a is None else int(round(a / clip.frame_time))
        b = None if b is None or b > clip.duration else int(round(b / clip.frame_time)) + 1
    else:
        return None
    a = a or 0
    b = clip.frames if b is None else b
    if a >= clip.frames:
        raise MocapError(f"{clip.source}: the span starts at frame {a}, the clip has {clip.frames} (0 to "
                         f"{clip.frames - 1}, {clip.duration:.3f} s)")
    return slice(a, min(b, clip.frames))


def run_retarget(clip_path: str, *, model=None, config=None, arm: str = "right", frames=None, time=None,
                 unit=None, map_file=None, method: str = "angles", twist_deg: float | None = None,
                 output: str | Path | None = None, report_dir: str | Path | None = None, say=print) -> dict:
    """Retarget; the report (written to report_dir/report.json when given), `flags` non-empty when
    the result needs a look."""
    if twist_deg is not None and not math.isfinite(twist_deg):
        raise MocapError(f"--twist {twist_deg}: the elbow axis's twist about the upper arm is a finite number of degrees")
    output = Path(output) if output else Path("out/retarget") / f"{Path(clip_path).stem}.csv"
    refuse_input_as_output(output, "-o", {"the clip": clip_path, "--config": config and config.path, "--map": map_file})
    clip = _clip(clip_path)
    arms = _arms(clip, map_file)
    if arm not in arms:
        raise MocapError(f"{clip.source}: no {arm} arm found (found: {', '.join(arms)})")
    chain = arms[arm]
    axes, warnings = guess_axes(clip, arms)
    info = describe(clip, map_file, unit)
    robot_model = config.model if config is not None else model
    target = ArmTarget.of(robot_model)
    if arm == "left":
        warnings.append("the left arm is mirrored (left for right) onto the model's arm")
    span = frame_slice(clip, frames, time)
    twist = None if twist_deg is None else math.radians(twist_deg)
    shown = [0]

    def progress(i, n):          # IK takes a few ms a frame: a line every tenth of a long clip
        if n >= 500 and i * 10 // n > shown[0]:
            shown[0] = i * 10 // n
            print(f"  ik: {i}/{n} frames", file=sys.stderr, flush=True)
    result = retarget(clip, chain, axes, target, span, twist, method=method, progress=progress)
    traj = result.trajectory
    write_trajectory_csv(output, traj, robot_model.dof_names)
    report = {"clip": str(clip_path), "model": robot_model.name, "config": config.name if config else None,
              "arm": arm, "chain": chain.names(clip), "names_from": chain.source, "method": method,
              "unit": info["unit"], "up": axes.up, "forward": axes.forward, "motion": str(output),
              "duration_s": float(traj.t[-1]), **result.report, "warnings": clip.warnings + warnings}
    tau = robot_model.inverse_dynamics(traj.q, traj.qd, traj.qdd)
    gravity = robot_model.inverse_dynamics(traj.q, np.zeros_like(traj.q), np.zeros_like(traj.q))
    g_peak = float(np.abs(gravity).max())
    peak, p99 = np.abs(tau).max(axis=0), np.percentile(np.abs(tau), 99, axis=0)
    spikes = [d for d, a, b in zip(robot_model.dof_names, peak, p99)
              if a > FLAG_TORQUE_GRAVITY * g_peak and a > FLAG_TORQUE_SPIKE * b]
    report["torque"] = {"peak_nm": dict(zip(robot_model.dof_names, map(float, peak))),
                        "p99_nm": dict(zip(robot_model.dof_names, map(float, p99))),
                        "gravity_peak_nm": g_peak,
                        "peak_over_gravity": float(peak.max() / g_peak) if g_peak > 0 else None,
                        "spikes": spikes}
    if config is not None:
        try:
            checked = validate(config, str(output), fit=True, say=lambda *a, **k: None)
            report["validate"] = {"passed_as_captured": checked["passed"],
                                  "fit_time_scale": checked.get("fit_time_scale"), "fit_how": checked.get("fit_how")}
        except ValueError as err:          # the fit past the longest motion the validator plays
            report["validate"] = {"passed_as_captured": False, "fit_time_scale": None, "fit_how": str(err)}
    report["flags"] = flags(report)
    say(summary_text(report))
    if report_dir is not None:
        report_dir = Path(report_dir)
        report_dir.mkdir(parents=True, exist_ok=True)
        (report_dir / "report.json").write_text(json.dumps(report, indent=1) + "\n")
        retarget_figure(report_dir / "retarget.png", result, robot_model.dof_names,
                        f"{Path(clip_path).name} ({arm} arm) on {robot_model.name}")
        say(f"wrote {report_dir / 'report.json'}, {report_dir / 'retarget.png'}")
    return report


def flags(report: dict) -> list[str]:
    out = []
    count = report["frames"]["count"]
    for dof, hit in report["limit_hits"].items() if report["method"] == "angles" else ():
        if hit["frames"] > FLAG_LIMIT_FRACTION * count:
            out.append(f"{dof}: {hit['frames']} of {count} frames outside the soft limits (up to "
                       f"{hit['worst_deg']:.1f}° beyond), clamped")
    if report["elbow_residual_p95_deg"] > FLAG_ELBOW_RESIDUAL_DEG and report["method"] == "angles":
        out.append(f"the captured elbow is no hinge: the forearm leaves the model's elbow plane by "
                   f"{report['elbow_residual_p95_deg']:.1f}° (p95); --method ik fits the hand instead")
    hand = report["cartesian_error"]["hand"]["p95_mm"]
    if hand > FLAG_HAND_ERROR_MM:
        out.append(f"the hand is {hand:.0f} mm from the captured one (p95)")
    for dof in report["torque"]["spikes"]:
        out.append(f"{dof}: a torque spike, {report['torque']['peak_nm'][dof]:.1f} N·m against "
                   f"{report['torque']['p99_nm'][dof]:.1f} N·m at the 99th percentile (a glitch left in?)")
    fit = report.get("validate")
    if fit is not None:
        if fit["fit_time_scale"] is None:
            out.append(f"no time scale makes it pass validate ({fit['fit_how']})")
        elif fit["fit_time_scale"] > FLAG_TIME_SCALE:
            out.append(f"the servos need it {fit['fit_time_scale']:.1f}× slower")
    return out


def summary_text(r: dict) -> str:
    cal = r["calibration"]
    lines = [f"retarget {r['clip']} ({r['arm']} arm: {r['chain']['upper_arm']}, names {r['names_from']}) onto "
             f"'{r['model']}': {r['frames']['count']} frames from frame {r['frames']['first']}"
             f"{' (rest frame 0 dropped)' if r['frames']['rest_frame_dropped'] else ''} at {r['frames']['rate_hz']:.4g} Hz,"
             f" {r['lead_in_s']:.2f} s lead-in from rest (its first {r['eased_in_s']:g} s played from stillness),"
             f" {r['duration_s']:.2f} s in all",
             f"elbow axis: twist {cal['twist_deg']:.1f}° "
             + (f"fitted over {cal['frames']} frames (residual p95 {cal['residual_p95_deg_before']:.1f}° → "
                f"{cal['residual_p95_deg']:.1f}°)" if cal.get("fitted") else f"({cal['why']})"),
             f"limits: {sum(h['frames'] for h in r['limit_hits'].values())} dof-frames clamped "
             f"{r['soft_limit_margin_deg']:g}° inside; flips avoided {r['flips_avoided']}; outliers replaced "
             f"{sum(r['outliers_removed'].values())}",
             *([f"ik: {r['ik']['at_captured_swivel']} frames at the captured elbow's swivel, "
                f"{r['ik']['nearest_swivel']} at the nearest swivel inside the limits, {r['ik']['least_squares']} "
                "by bounded least squares"] if "ik" in r else []),
             f"Cartesian error: elbow {r['cartesian_error']['elbow']['p95_mm']:.1f} mm, hand "
             f"{r['cartesian_error']['hand']['p95_mm']:.1f} mm (p95)",
             f"peak torque {max(r['torque']['peak_nm'].values()):.2f} N·m "
             f"({r['torque']['peak_over_gravity']:.1f}× the largest gravity torque)"]
    if "validate" in r:
        fit = r["validate"]["fit_time_scale"]
        lines.append(f"validate on '{r['config']}': {'passes' if r['validate']['passed_as_captured'] else 'fails'} "
                     f"as captured; fit: " + (f"time scale {fit:.2f}" if fit else f"none ({r['validate']['fit_how']})"))
    lines.append(f"wrote {r['motion']}")
    lines += [f"warning: {w}" for w in r["warnings"]]
    lines += [f"flag: {f}" for f in r["flags"]]
    return "\n".join(lines)


def retarget_figure(path: Path, result, dof_names, title: str) -> None:
    """Each dof: the decomposition as read and the motion as written (clip frames)."""
    plt = _pyplot()
    fig, axes = plt.subplots(len(dof_names), 1, figsize=(9, 1.5 * len(dof_names)), sharex=True)
    t = result.capture.t
    for j, (ax, dof) in enumerate(zip(axes, dof_names)):
        ax.plot(t, np.degrees(result.q_raw[:, j]), color="0.6", lw=0.8, label="decomposed")
        ax.plot(t, np.degrees(result.q[:, j]), color="C0", lw=1.2, label="written (filtered, in the soft limits)")
        ax.set_ylabel(f"{dof.removeprefix('r_')}\n(deg)", fontsize=8)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[0].set_title(short(title))
    axes[-1].set_xlabel("t (s, from the first frame used)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# ---------------------------------------------------------------------------- export-bvh

def export_bvh(motion: str, model, output: str | Path, order: str = "ZXY", unit: str = "cm", rest: str = "hang",
               rate: float = 120.0, say=print) -> Clip:
    order = order.upper()
    if order not in ORDERS:
        raise MocapError(f"--order {order}: expected one of {', '.join(ORDERS)}")
    if unit not in UNITS:
        raise MocapError(f"--unit {unit}: expected one of {', '.join(UNITS)}")
    if not (math.isfinite(rate) and MIN_RATE_HZ <= rate <= MAX_RATE_HZ):
        raise MocapError(f"--rate {rate:g}: expected frames per second from {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g}")
    target = ArmTarget.of(model)
    path = motion_path(motion, model)
    traj = path.at_scale(1.0, 1.0 / rate)
    clip = arm_clip(target, traj.q, 1.0 / rate, order, unit, rest)
    write_bvh(output, clip)
    say(f"wrote {output}: '{path.name}' on '{model.name}', {clip.frames} frames at {rate:g} Hz, rotation order "
        f"{order}, unit {unit}, rest pose {rest}")
    return clip

