"""A motion validated and reported: `validate` runs the validation layer (servodyn.validation: the
limits, the checks, the winding model, the uniform fit and the TOPP-RA retime) and writes
DIR/report.json with its figures; with `simulate_motion` the motion is also played on the simulated
servos under the swing's controller (`simulate`). `validate_many` does it for many motions in
parallel. `servodyn validate` is the command over it (exit 0 pass, 1 fail, 2 bad input).
"""

from __future__ import annotations

import glob
import json
import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..control.motion import motion_path
from ..control.trajectory import TrajectoryError, write_trajectory_csv
from ..errors import InputError
from ..hal.config import supply_voltage_error
from ..loop.run import Run, RunOptions
from ..sim.serve import serve
from ..model import ModelError
from ..readable import fixed
from ..validation import AMBIENT, CHECKS, Judgement, Limits, Result, fit_time_scale, judge, retime
from ..validation import people
from .plots import envelope_figure, limits_in_time_figure
from .swing import report_run

MAX_REPEAT = 10_000         # plays of a motion for the heat: hours of even a short motion


# ---------------------------------------------------------------------------- confirmed by simulation

SATURATION_UNITS = 3          # command steps between the asked and the delivered torque that count
TRACKING_TOLERANCE = math.radians(5.0)   # what a passing motion must track within on the simulated bus
MAX_LAG = 3                   # ticks between a command and the read that sees its current, at most


def simulate(config, motion: str, scale: float, result: Result, limits: Limits, out: Path, say=print) -> dict:
    """Play the motion on the simulated servos of any configuration (lock-step) under the swing's
    controller and compare with the prediction. A servo saturates where it delivers less torque
    than the controller asked for: its drive ran out of voltage against the back-EMF (the
    envelope) or the HAL clamped the command at the current limit. The run's own states say so:
    each read's current through the joint's torque per ampere (torque constant × gear, as each
    backend converts) against the torque commanded `lag` ticks before (measured from the run), by more than
    SATURATION_UNITS of the wire's command step. Per joint: the first saturated tick against the
    validator's first torque_speed or current violation; and the whole run's tracking."""
    run = Run(config, RunOptions(motion=motion, time_scale=scale, force=True), serve=serve, say=say)
    summary = run.play(out)          # its progress said, a line a second of motion
    log = run.log
    report_run(out, log, summary, run.config, say=lambda *a, **k: None)      # the figure, not the table
    t = np.asarray(log.t)
    asked = np.asarray(log.tau).reshape(len(t), -1)                       # N m commanded, per tick
    delivered = np.asarray(log.current).reshape(len(t), -1) * (limits.torque_constant * limits.gear)
    step = np.maximum(limits.command_step, 1e-3 * limits.torque_constant * limits.gear)
    # a read sees the current of a command written a tick or two before it (a Dynamixel's fast
    # sync read the one before, a CAN motor's reply to its command frame the state before that):
    # per joint, the lag that matches the run best
    def lag_of(j):
        fits = [float(np.median(np.abs(asked[:-k, j] - delivered[k:, j]))) if len(t) > k else math.inf
                for k in range(1, MAX_LAG + 1)]
        return 1 + int(np.argmin(fits))
    lags = [lag_of(j) for j in range(asked.shape[1])]
    joints = {}
    for j, dof in enumerate(config.model.dof_names):
        lag = lags[j]
        hits = np.flatnonzero(np.abs(asked[:-lag, j]) - np.abs(delivered[lag:, j]) > SATURATION_UNITS * step[j])
        observed = float(t[hits[0]]) if hits.size else None
        over = (result.ratios["torque_speed"][:, j] > 1) | (result.ratios["current"][:, j] > 1)
        predicted = float(result.t[np.argmax(over)]) if over.any() else None
        joints[dof] = {"predicted_s": predicted, "saturated_s": observed,
                       "ticks_apart": None if predicted is None or observed is None
                       else int(round((observed - predicted) / limits.period))}
    # after the first saturation the arm leaves the plan, so the later joints' times are the run's,
    # not the prediction's: the first of each is the comparison that holds
    predicted = [(row["predicted_s"], dof) for dof, row in joints.items() if row["predicted_s"] is not None]
    observed = [(row["saturated_s"], dof) for dof, row in joints.items() if row["saturated_s"] is not None]
    first = {"predicted": dict(zip(("t_s", "dof"), min(predicted))) if predicted else None,
             "saturated": dict(zip(("t_s", "dof"), min(observed))) if observed else None}
    if first["predicted"] and first["saturated"]:
        first["ticks_apart"] = int(round((first["saturated"]["t_s"] - first["predicted"]["t_s"]) / limits.period))
    return {"completed": summary["completed"], "tracking_max_rad": summary.get("tracking_max_rad"),
            "tracks": summary.get("tracking_max_rad", math.inf) <= TRACKING_TOLERANCE, "first": first,
            "joints": joints, "read_lag_ticks": dict(zip(config.model.dof_names, lags))}


# ---------------------------------------------------------------------------- the report

def joint_table(result: Result, dof_names) -> dict:
    """Per joint: peaks, the worst check and its ratio, pass or fail, each check's peak ratio."""
    table = {}
    for j, dof in enumerate(dof_names):
        peaks = {name: float(result.ratios[name][:, min(j, result.ratios[name].shape[1] - 1)].max(initial=0.0))
                 for name in CHECKS}
        worst = max(peaks, key=lambda name: peaks[name] / result.allowed(name))   # nearest its bound
        when = {name: float(result.t[int(np.argmax(result.ratios[name][:, min(j, result.ratios[name].shape[1] - 1)]))])
                for name in CHECKS}
        table[dof] = {
            "peak_torque_nm": float(np.abs(result.tau[:, j]).max()),
            "peak_speed_rad_s": float(np.abs(result.qd[:, j]).max()),
            "peak_current_a": float(result.current[:, j].max()),
            "peak_temperature_c": float(result.temperature[:, j].max()),
            "worst_check": worst, "worst_ratio": peaks[worst],
            "passed": all(peaks[name] <= result.allowed(name) for name in CHECKS),
            "checks": peaks, "worst_at_s": when,
        }
    return table


def make_report(config, judged: Judgement, *, margin: float, repeat: int, ambient: float,
                payload: dict | None) -> dict:
    path, scale, result, limits = judged.path, judged.time_scale, judged.result, judged.limits
    return {
        "passed": result.passed, "motion": path.name, "config": config.name, "time_scale": scale,
        "duration_s": float(result.t[-1]), "supply_voltage": limits.voltage, "margin": margin,
        "repeat": repeat, "ambient_c": ambient, "payload": payload,
        "sample_period_s": float(result.t[1] - result.t[0]) if len(result.t) > 1 else limits.period,
        "samples": len(result.t),
        "joints": joint_table(result, config.model.dof_names),
        "violations": judged.violations,
        "supply": {"peak_current_a": float(result.supply_current.max()), "peak_power_w": float(result.power.max()),
                   "current_limit_a": limits.supply_current},
        "bus": [{"bus": name, "seconds_per_tick": seconds, "what": text} for name, seconds, text in limits.wire],
        "command_quantization_nm": dict(zip(config.model.dof_names, map(float, limits.command_step))),
    }


# ---------------------------------------------------------------------------- the command

def validate(config, motion: str, *, time_scale: float | None = None, payload: float = 0.0, payload_body=None,
             payload_com=None, supply_voltage: float | None = None, margin: float = 1.0, repeat: int = 1,
             ambient: float = AMBIENT, fit: bool = False, retime_motion: bool = False, simulate_motion: bool = False,
             near_people: bool = False, out: Path | None = None, say=print) -> dict:
    """Validate `motion` on the configuration's servos; the report (and its files in `out`). The
    time scale is the configuration's for the motion (RobotConfig.time_scale_for: what a swing plays
    it at) unless given. `near_people`: also ISO/TS 15066's transient-contact speeds near people
    (validation.people), which the verdict then includes, and the fastest time scale they pass."""
    told = time_scale is not None
    if not told:
        time_scale = config.time_scale_for(motion)
    if not (math.isfinite(time_scale) and time_scale > 0):
        raise InputError(f"--time-scale must be a positive number, got {time_scale}")
    if not (math.isfinite(margin) and 0 < margin <= 10):
        raise InputError(f"--margin must be a fraction of each limit in (0, 10], got {margin}")
    if not 1 <= repeat <= MAX_REPEAT:
        raise InputError(f"--repeat must be from 1 to {MAX_REPEAT} plays (the winding settles within a few "
                         f"thermal time constants: minutes of play), got {repeat}")
    if not math.isfinite(ambient) or ambient >= min(j.servo.temperature_limit for j in config.joints):
        raise InputError(f"--ambient must be a temperature below the servos' limits, got {ambient}")
    model = config.model
    payload_info = None
    if payload or payload_body or payload_com is not None:
        model = model.with_payload(payload, payload_body, payload_com)
        payload_info = {"mass_kg": payload, "body": payload_body or model.body_names[-1],
                        "com_m": None if payload_com is None else [float(x) for x in payload_com]}
    voltage = supply_voltage if supply_voltage is not None else config.supply.voltage
    why = supply_voltage_error(voltage, config.joints)
    if why:
        raise InputError(f"--supply-voltage {why}")
    judged = judge(config, motion_path(motion, model), time_scale, model=model, voltage=voltage, margin=margin,
                   repeat=repeat, ambient=ambient)
    path, limits, result = judged.path, judged.limits, judged.result
    report = make_report(config, judged, margin=margin, repeat=repeat, ambient=ambient, payload=payload_info)
    say(f"validate '{path.name}' on '{config.name}': {report['duration_s']:.3f} s at time scale {time_scale:g}, "
        f"{report['samples']} samples every {report['sample_period_s'] * 1e3:g} ms, supply {voltage:g} V, "
        f"margin {margin:g}{f', {repeat} plays' if repeat > 1 else ''}"
        + ("" if told or time_scale == 1 else f" ({config.name}'s time scale for {path.name}, as a swing plays "
                                              "it; --time-scale S to change it)"))
    say(summary_table(report))
    if report["violations"]:
        say(f"\nFAIL: {report['violations'][0]['message']}")
        more = len(report["violations"]) - 1
        if more:
            say(f"  ({more} more: every check and joint over its limit is in report.json)")
    else:
        say("\nPASS: every joint within every limit")
    if near_people:
        near_people_report(report, model, result, path, limits.period, margin, say)
    if fit:
        scale, how = fit_time_scale(model, limits, path, margin, repeat, ambient)
        report["fit_time_scale"] = scale
        report["fit_how"] = how
        say(f"fit: {'time scale ' + format(scale, '.4f') + f' ({path.duration * scale:.3f} s)' if scale else 'none'} — {how}")
    if retime_motion:
        traj, checked, info = retime(model, limits, path, margin, repeat, ambient)
        if traj is None:
            report["retime"] = {"passed": False, "why": info}
            say(f"retime: {info}")
        else:
            report["retime"] = {"passed": True, **info}
            fitted = report.get("fit_time_scale")
            durations = f"as written {path.duration:.3f} s" + (f", uniform fit {path.duration * fitted:.3f} s"
                                                               if fitted else "")
            plans = f"{info['tries']} plan{'s' if info['tries'] > 1 else ''}"
            say(f"retime (TOPP-RA): {info['duration_s']:.3f} s, passes the dense check ({plans}, "
                f"{info['seconds']:.2f} s); {durations}")
    if simulate_motion:
        if payload_info is not None:
            config = replace(config, model=model)
        say("simulating: the motion played on the simulated servos under the swing's controller ...")
        report["simulation"] = simulate(config, motion, time_scale, result, limits,
                                        (out or Path("out/validate")) / "simulation", say)
        say(simulation_summary(report["simulation"]))
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if report.get("retime", {}).get("passed"):
            write_trajectory_csv(out / "retimed.csv", traj, model.dof_names)
            report["retime"]["file"] = str(out / "retimed.csv")
        text = report_json(report)         # strict JSON, or one error before any file is drawn
        say("drawing the figures ...")
        title = f"{path.name} on {config.name}, time scale {time_scale:g}, {voltage:g} V"
        envelope_figure(out / "envelopes.png", result, limits, model.dof_names, title)
        limits_in_time_figure(out / "current_temperature.png", result, limits, model.dof_names, title)
        (out / "report.json").write_text(text)
        files = [out / "report.json", out / "envelopes.png", out / "current_temperature.png"]
        if report.get("retime", {}).get("passed"):
            files.append(out / "retimed.csv")
        if "simulation" in report:
            files.append(f"{out / 'simulation'}/ (swing_log.csv, summary.json, swing_tracking.png)")
        say("wrote " + ", ".join(map(str, files)))
    return report


def report_json(report: dict) -> str:
    """The report as strict JSON (no NaN or Infinity tokens, which JSON has not); ValueError naming
    the first entry that is not a finite number."""
    try:
        return json.dumps(report, indent=1, allow_nan=False) + "\n"
    except ValueError:
        def first(value, where):
            if isinstance(value, float) and not math.isfinite(value):
                return f"{where} = {value}"
            items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
            return next((found for key, item in items if (found := first(item, f"{where}.{key}" if where else str(key)))),
                        None)
        raise ValueError(f"report.json: {first(report, '')} is not a finite number, which JSON cannot hold (the "
                         "inputs took a check out of the range it computes in)") from None


def summary_table(report: dict) -> str:
    short = {"position": "pos", "speed": "speed", "torque_speed": "τ-ω", "current": "current",
             "temperature": "heat", "supply": "supply", "bus": "bus", "command_range": "command"}
    lines = [f"  {'dof':<24}" + "".join(f"{short[c]:>8}" for c in CHECKS) + "   verdict"]
    for dof, row in report["joints"].items():
        cells = "".join(f"{fixed(row['checks'][c]):>8}" for c in CHECKS)
        lines.append(f"  {dof:<24}{cells}   {'PASS' if row['passed'] else 'FAIL (' + row['worst_check'] + ')'}")
    lines.append(f"  (peak ratio to each limit: up to {report['margin']:g} passes, up to 1 for position)")
    return "\n".join(lines)


def near_people_report(report: dict, model, result: Result, path, period: float, margin: float, say=print) -> None:
    """`near_people` and `near_people_time_scale` into the report (its verdict into `passed`), and
    their table said."""
    weightless = people.weightless_model(model)
    checked = people.near_people(model, result, margin, weightless)
    scale, how = people.fit_near_people(model, path, period, margin, weightless)
    report["near_people"] = checked
    report["near_people_time_scale"] = scale
    report["near_people_time_scale_how"] = how
    report["passed"] = report["passed"] and checked["passed"]
    say(near_people_table(checked))
    verdict = "PASS near people" if checked["passed"] else f"FAIL: {near_people_failure(checked)}"
    fastest = (f"time scale {scale:.4f} ({path.duration * scale:.3f} s)" if scale else "none") + f" — {how}"
    say(f"{verdict}\nnear people: the fastest passing {fastest}")


def near_people_failure(checked: dict | None) -> str | None:
    """One line for the first link too fast near people (None when every link passes)."""
    failing = [(name, link) for name, link in (checked or {}).get("links", {}).items() if not link["passed"]]
    if not failing:
        return None
    name, link = failing[0]
    more = f"; {len(failing) - 1} more link(s) too fast, in report.json" if len(failing) > 1 else ""
    return (f"near people, {name}'s {link['point']} reaches {fixed(link['worst_ratio'])} x the speed ISO/TS 15066 "
            f"permits against a {link['limiting_region']} ({fixed(link['permitted_speed_m_s'])} m/s at its effective "
            f"mass there){more}")


def near_people_table(checked: dict) -> str:
    """Per link and point: its peak speed, its effective mass at that peak, and per body region the
    worst ratio of its speed to the speed permitted there; the verdict names the limiting region."""
    regions = list(checked["regions"])
    lines = ["near people (ISO/TS 15066 transient contact): speed / permitted speed, worst sample, per region",
             f"  {'link':<22}{'point':>7}{'peak m/s':>9}{'m_eff kg':>9}" + "".join(f"{r:>10}" for r in regions)
             + "   verdict"]
    for name, link in checked["links"].items():
        for key, point in link["points"].items():
            cells = "".join(f"{fixed(point['regions'][r]['worst_ratio']):>10}" for r in regions)
            mass = "rest" if point["effective_mass_kg"] is None else fixed(point["effective_mass_kg"])
            verdict = "PASS" if point["passed"] else f"FAIL ({point['limiting_region']})"
            lines.append(f"  {name:<22}{key:>7}{fixed(point['peak_speed_m_s']):>9}{mass:>9}{cells}   {verdict}")
    lines.append("  (com: the link's centre of mass; tip: the hand's solids' farthest point; m_eff: along the velocity")
    lines.append(f"  at the peak, armature included; up to {checked['allowed_ratio']:g} passes; "
                 f"{', '.join(people.NO_CONTACT)}: no contact at any speed)")
    return "\n".join(lines)


def simulation_summary(sim: dict) -> str:
    lines = [f"simulated (lock-step, the swing's controller): {'completed' if sim['completed'] else 'stopped'}, "
             f"tracking max {math.degrees(sim['tracking_max_rad'] or 0):.2f} deg"]
    first = sim["first"]
    if first["predicted"] and first["saturated"]:
        lines.append(f"  first saturation: predicted {first['predicted']['dof']} at {first['predicted']['t_s']:.3f} s, "
                     f"simulated {first['saturated']['dof']} at {first['saturated']['t_s']:.3f} s "
                     f"({first['ticks_apart']:+d} ticks); the later ones follow a run that has left the plan:")
    for dof, row in sim["joints"].items():
        if row["predicted_s"] is None and row["saturated_s"] is None:
            continue
        fmt = lambda t: "never" if t is None else f"{t:.3f} s"
        lines.append(f"  {dof:<24} predicted {fmt(row['predicted_s'])}, saturated {fmt(row['saturated_s'])}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- many motions at once

GLOB_CHARACTERS = "*?["


def expand_motions(specs: list[str]) -> list[str]:
    """The motions named: a folder stands for its trajectory CSVs, a glob for its matches (each in
    name order); anything else is one motion. ValueError for a folder or glob that names none."""
    found = []
    for spec in specs:
        path = Path(spec)
        if path.is_dir():
            matches = sorted(str(p) for p in path.glob("*.csv"))
            what = f"folder {spec} holds no trajectory CSV (*.csv)"
        elif any(c in spec for c in GLOB_CHARACTERS):
            matches = sorted(glob.glob(spec))
            what = f"{spec} matches no file"
        else:
            matches, what = [spec], ""
        if not matches:
            raise InputError(what)
        found += matches
    return found


def _folders(motions: list[str]) -> list[str]:
    """One output folder name per motion, its file's stem (a suffix where two share one)."""
    names, seen = [], {}
    for spec in motions:
        stem = Path(spec).stem or "motion"
        seen[stem] = seen.get(stem, 0) + 1
        names.append(stem if seen[stem] == 1 else f"{stem}_{seen[stem]}")
    return names


_MANY: dict = {}        # the parent's configuration and options, inherited by forked workers


def _validate_one(index: int) -> dict:
    """One motion of many: its report's verdict, or its one-line error; its printout kept."""
    config, motions, folders, options, out = (_MANY[k] for k in ("config", "motions", "folders", "options", "out"))
    lines = []
    say = lambda *a, **k: lines.append(" ".join(map(str, a)))
    target = out / folders[index] if out is not None else None
    try:
        report = validate(config, motions[index], out=target, say=say, **options)
    except (TrajectoryError, ModelError, ValueError) as err:
        return {"motion": motions[index], "error": str(err), "code": 2}
    finally:
        if target is not None and lines:
            target.mkdir(parents=True, exist_ok=True)
            (target / "validate.txt").write_text("\n".join(lines) + "\n")
    worst = max(report["joints"].items(), key=lambda item: item[1]["worst_ratio"] /
                (1.0 if item[1]["worst_check"] == "position" else report["margin"]))
    return {"motion": motions[index], "name": report["motion"], "passed": report["passed"],
            "code": 0 if report["passed"] else 1, "duration_s": report["duration_s"],
            "worst": {"dof": worst[0], "check": worst[1]["worst_check"], "ratio": worst[1]["worst_ratio"]},
            "first_violation": report["violations"][0]["message"] if report["violations"] else
            near_people_failure(report.get("near_people")),
            "fit_time_scale": report.get("fit_time_scale"),
            **({"near_people_time_scale": report["near_people_time_scale"]} if "near_people" in report else {}),
            "report": str(target / "report.json") if target is not None else None}


def validate_many(config, motions: list[str], *, jobs: int = 1, out: Path | None = None, say=print,
                  **options) -> dict:
    """Validate each motion as `validate` does, spread over `jobs` processes (forked, so each
    inherits the configuration and the loaded C core); one verdict line per motion, in the order
    given, each report in OUT/<motion>/. The summary's `code` is the worst: 2 a motion that
    cannot be read, 1 one that fails, 0 all pass."""
    if not 1 <= jobs <= 256:
        raise InputError(f"--jobs must be from 1 to 256 processes, got {jobs}")
    folders = _folders(motions)
    _MANY.update(config=config, motions=motions, folders=folders, options=options, out=out)
    if jobs > 1 and len(motions) > 1:
        context = multiprocessing.get_context("fork")
        with ProcessPoolExecutor(min(jobs, len(motions)), mp_context=context) as pool:
            results = list(pool.map(_validate_one, range(len(motions))))
    else:
        results = [_validate_one(k) for k in range(len(motions))]
    for r in results:
        say(verdict_line(r))
    code = max(r["code"] for r in results)
    summary = {"passed": code == 0, "code": code, "config": config.name, "jobs": jobs, "motions": results}
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
        say(f"{sum(r['code'] == 0 for r in results)} of {len(results)} pass; wrote {out / 'summary.json'} and a "
            "folder per motion")
    return summary


def verdict_line(result: dict) -> str:
    if "error" in result:
        return f"ERROR {result['motion']}: {result['error']}"
    worst = result["worst"]
    head = f"{'PASS' if result['passed'] else 'FAIL'} {result['motion']} ({result['duration_s']:.3f} s)"
    if result["passed"]:
        return f"{head}: nearest a limit {worst['dof']} {worst['check']} {fixed(worst['ratio'])}"
    return f"{head}: {result['first_violation']}"
