"""Which servo at each joint makes these motions pass, as light as possible (or with the largest
reserve): `run_size` sizes (servodyn.validation.sizing), writes and validates, and reports; `servodyn
size` is the command over it.

Writes DIR/config.toml and DIR/model.toml (the model file with the chosen servos' housings in
place of its own, its comments kept), validates the written files on every motion as `servodyn
validate` does, and DIR/size.json. Exit status 0: a set that passes; 1: none in the catalogue
(the report says which joint and check, and the time scale at which a set would pass); 2: bad input.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import tomlkit

from ..control.motion import motion_path
from ..hal.config import load_config
from ..readable import fixed
from ..validation import judge
from ..validation import sizing
from ..validation.sizing import SizingError

SHOWN = 6             # candidates per joint in the printed table (every one is in size.json)


def _voltages(family: str, voltage: float | None, model_ref: str) -> list[float]:
    if voltage is not None:
        if not (math.isfinite(voltage) and 0 < voltage <= 100):
            raise SizingError(f"--supply-voltage must be a voltage from 0 to 100 V, got {voltage:g}")
        return [voltage]
    return sizing.supply_voltages(family, model_ref)


def _check_inputs(time_scale, margin, payload, jobs, repeat):
    if not (math.isfinite(time_scale) and 0 < time_scale <= sizing.FIT_GRID[1]):
        raise SizingError(f"--time-scale must be a positive number up to {sizing.FIT_GRID[1]:g}, got {time_scale}")
    if not (math.isfinite(margin) and 0 < margin <= 1):
        raise SizingError(f"--margin must be a fraction of each limit in (0, 1], got {margin}")
    if not (math.isfinite(payload) and 0 <= payload <= 100):
        raise SizingError(f"--payload must be a mass from 0 to 100 kg, got {payload}")
    if not 1 <= jobs <= 256:
        raise SizingError(f"--jobs must be from 1 to 256 processes, got {jobs}")
    if not 1 <= repeat <= 10_000:
        raise SizingError(f"--repeat must be from 1 to 10000 plays, got {repeat}")


def run_size(model_ref: str, motions: list[str], *, time_scale: float = 1.0, payload: float = 0.0,
             supply_voltage: float | None = None, margin: float = 1.0, family: str = "dynamixel",
             objective: str = "mass", jobs: int = 1, repeat: int = 1, out: Path | None = None,
             confirm=None, say=print, progress=None) -> dict:
    """Size, write and validate; the report (see the module's docstring)."""
    _check_inputs(time_scale, margin, payload, jobs, repeat)
    if not motions:
        raise SizingError("give at least one --motion")
    sizing.catalogue(family)                      # a family that exists, before any work
    if objective not in sizing.OBJECTIVES:
        raise SizingError(f"--objective must be one of {', '.join(sizing.OBJECTIVES)}, got {objective!r}")
    data, folder, ref = sizing.load_model_data(model_ref)
    base_model = sizing.model_from_dict(data, origin=Path(ref).stem, folder=folder)
    paths = [motion_path(m, base_model) for m in motions]
    tries = []
    for voltage in _voltages(family, supply_voltage, model_ref):
        try:
            problem = sizing.problem(model_ref, paths, family=family, voltage=voltage, time_scale=time_scale,
                                     margin=margin, payload=payload, repeat=repeat)
        except SizingError as err:
            if supply_voltage is not None:
                raise
            if progress:
                progress(f"  {voltage:g} V: {err}")
            continue
        if progress:
            progress(f"sizing '{base_model.name}' for {', '.join(p.name for p in paths)} at {voltage:g} V, "
                     f"{family} servos ({len(problem.limits)} usable), from the hand inwards")
        outcome = sizing.size(problem, objective, jobs, fit=False,
                              progress=(lambda dof, row: progress(f"  {dof:<24} {row.servo if row else 'none passes'}"))
                              if progress else None)
        tries.append((problem, outcome))
    if not tries:
        raise SizingError(f"no {family} servo of the catalogue runs at any supply voltage tried")
    problem, outcome = min(tries, key=lambda t: _rank(t[0], t[1], objective))
    if not outcome["sizing"].passed:
        if progress:
            progress(f"no set passes at time scale {time_scale:g}: finding the time scale at which one does")
        outcome["fit"] = sizing.fit_scale(problem)
    report = _report(problem, outcome, family, objective, [p.voltage for p, _ in tries])
    report["by_voltage"] = [_at_voltage(p, o) for p, o in tries]
    if outcome["sizing"].passed:
        report["files"] = _write(problem, outcome, out, confirm, say) if out is not None else {}
        if out is not None:
            report["validated"] = _validate_written(out, problem, paths, motions)
            report["passed"] = all(v["passed"] for v in report["validated"].values())
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "size.json").write_text(json.dumps(report, indent=1, allow_nan=False) + "\n")
        report.setdefault("files", {})["report"] = str(out / "size.json")
    return report


def _rank(problem, outcome, objective):
    """Passing first; then the lightest bill (mass) or the smallest worst ratio (margin)."""
    found = outcome["sizing"]
    if not found.passed:
        return (1, found.failed_dof and -len(found.choice), 0.0)
    mass = sum(sizing.part_mass(s) for s in found.choice.values())
    worst = max(_row(found, d).score for d in found.choice)
    return (0, mass, worst) if objective == "mass" else (0, worst, mass)


def _count(choice: dict) -> dict:
    """A bill: each servo chosen and how many, in the order first chosen."""
    return {name: list(choice.values()).count(name) for name in dict.fromkeys(choice.values())}


def _at_voltage(problem, outcome) -> dict:
    """One supply voltage tried: whether a set passed there, its servo mass, or where it failed (the
    joint, and each of its candidates' worst check and ratio)."""
    found = outcome["sizing"]
    out = {"voltage": problem.voltage, "passed": found.passed}
    if found.passed:
        out["servo_mass_kg"] = sum(sizing.part_mass(s) for s in found.choice.values())
        out["choice"] = dict(found.choice)
    else:
        out["failed_dof"] = found.failed_dof
        out["candidates"] = [{"servo": r.servo, "worst_check": r.worst_check, "worst_ratio": r.worst_ratio}
                             for r in found.rows[found.failed_dof] if r.why_not is None]
    return out


def _row(found, dof):
    return next(r for r in found.rows[dof] if r.servo == found.choice[dof])


def _report(problem, outcome, family, objective, voltages) -> dict:
    found = outcome["sizing"]
    joints = {}
    for dof, place in zip(problem.dofs, problem.places):
        rows = found.rows.get(dof, [])
        entry = {"servo": found.choice.get(dof), "original": place.original,
                 "candidates": [{"servo": r.servo, "mass_kg": r.mass_kg, "worst_check": r.worst_check,
                                 "worst_ratio": r.worst_ratio, "passed": r.passed, "motion": r.motion,
                                 "why_not": r.why_not} for r in rows]}
        if dof in found.choice:
            row = _row(found, dof)
            entry.update(mass_kg=row.mass_kg, worst_check=row.worst_check, worst_ratio=row.worst_ratio,
                         motion=row.motion)
        orig = next((r for r in rows if r.servo == place.original), None)
        if orig is not None and dof in found.choice and orig.servo != found.choice[dof] and orig.worst_ratio is not None:
            entry["original_worst"] = {"check": orig.worst_check, "ratio": orig.worst_ratio,
                                       "spare_kg": orig.mass_kg - entry["mass_kg"]}
        joints[dof] = entry
    report = {"passed": found.passed, "model": problem.model_ref, "motions": [m.name for m in problem.motions],
              "time_scale": problem.time_scale, "supply_voltage": problem.voltage, "voltages_tried": voltages,
              "margin": problem.margin, "payload_kg": problem.payload, "family": family, "objective": objective,
              "control_period_s": problem.period, "joints": joints}
    if found.passed:
        report["servo_mass_kg"] = sum(sizing.part_mass(s) for s in found.choice.values())
        report["bill"] = _count(found.choice)
    if outcome["reached_margin"] is not None:
        report["reached_margin"] = outcome["reached_margin"]
    if not found.passed:
        rows = found.rows[found.failed_dof]
        nearest = min((r for r in rows if r.why_not is None), key=lambda r: r.score)
        report["failure"] = {"dof": found.failed_dof, "check": nearest.worst_check, "ratio": nearest.worst_ratio,
                             "servo": nearest.servo, "motion": nearest.motion,
                             "outboard": dict(found.choice)}
        fit = outcome["fit"]
        report["fit"] = fit
        if fit and fit["choice"]:
            report["fit"]["servo_mass_kg"] = sum(sizing.part_mass(s) for s in fit["choice"].values())
    return report


# ---------------------------------------------------------------------------- the files

def _write(problem, outcome, out: Path, confirm, say) -> dict:
    found = outcome["sizing"]
    targets = {"config": out / "config.toml", "model": out / "model.toml"}
    there = [p for p in targets.values() if p.exists()]
    if there and not (confirm is not None and confirm(f"{', '.join(map(str, there))} exist: overwrite?")):
        raise SizingError(f"{there[0]} exists and was kept (give --yes to overwrite, or another --out)")
    out.mkdir(parents=True, exist_ok=True)
    targets["model"].write_text(_model_text(problem, found))
    targets["config"].write_text(_config_text(problem, found))
    return {k: str(v) for k, v in targets.items()}


def _model_text(problem, found) -> str:
    """The model file with the chosen servos mounted, its own comments kept (tomlkit)."""
    path = Path(problem.model_ref)
    doc = tomlkit.parse(path.read_text())
    for k, entry in enumerate(doc["body"]):
        if "from" in entry:           # sizing edits the whole body: write it whole
            doc["body"][k] = problem.data["body"][k]
    for place in sorted(problem.places, key=lambda h: h.solid is None):
        sizing.mount(doc, place, found.choice[place.dof])
    for place in problem.places:
        if place.solid is not None and place.original != found.choice[place.dof]:
            doc["body"][place.carrier]["solid"][place.solid]["part"].comment(f"sized: in place of {place.original}")
    doc["name"] = f"{doc['name']}_sized"
    doc["description"] = (str(doc.get("description", "")).rstrip() + "\n\nSized by `servodyn size`: "
                          + ", ".join(f"{d} {s}" for d, s in found.choice.items()) + ".\n")
    header = (f"# {path.stem}, sized by `servodyn size` for {', '.join(m.name for m in problem.motions)} at time "
              f"scale {problem.time_scale:g}, {problem.voltage:g} V:\n# each dof's servo mounted as a part in place "
              "of the model's own (its horn face and shaft axis kept).\n")
    return header + tomlkit.dumps(doc)


def _config_text(problem, found) -> str:
    data = sizing.config_data(f"{Path(problem.model_ref).stem}_sized", "model.toml", problem.dofs, found.choice,
                              problem.voltage, problem.period, problem.servos)
    lines = [f"# Sized by `servodyn size` for {', '.join(m.name for m in problem.motions)} at time scale "
             f"{problem.time_scale:g}, margin {problem.margin:g}, {problem.voltage:g} V"
             + (f", payload {problem.payload:g} kg" if problem.payload else "") + ".",
             "# Each servo drives its joint at the horn; ids from 1 in model order on each bus. Set each",
             "# joint's direction and zero_offset to how it is mounted (`servodyn calibrate` finds them).",
             "", f"name = {json.dumps(data['name'])}", 'model = "model.toml"    # beside this file', ""]
    for name, bus in data["bus"].items():
        lines.append(f"[bus.{name}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in bus.items()]
        lines.append("")
    for joint in data["joint"]:
        row = _row(found, joint["dof"])
        lines.append(f"[[joint]]    # {row.servo}, {row.mass_kg * 1e3:.0f} g: worst {row.worst_check} "
                     f"{fixed(row.worst_ratio)} ({row.motion})")
        lines += [f"{k} = {json.dumps(v)}" for k, v in joint.items()]
        lines.append("")
    lines += ["[supply]", f"voltage = {problem.voltage!r}", ""]
    if "control" in data:
        lines += ["[control]", f"period = {problem.period!r}    # s: every bus's tick within "
                  f"{sizing.BUS_SHARE:.0%} of it on the wire", ""]
    return "\n".join(lines)


def _validate_written(out: Path, problem, paths, motions) -> dict:
    """The written configuration, loaded as `servodyn validate` loads it, on every motion."""
    config = load_config(out / "config.toml")
    model = config.model.with_payload(problem.payload) if problem.payload else config.model
    verdicts = {}
    for spec, path in zip(motions, paths):
        judged = judge(config, motion_path(spec, model), problem.time_scale, model=model, voltage=problem.voltage,
                       margin=problem.margin, repeat=problem.repeat)
        first = judged.violations[0]["message"] if judged.violations else None
        verdicts[path.name] = {"passed": judged.passed, "first_violation": first}
    return verdicts


# ---------------------------------------------------------------------------- the printout

def text(report: dict) -> str:
    lines = [f"size '{Path(report['model']).stem}' for {', '.join(report['motions'])} at time scale "
             f"{report['time_scale']:g}, {report['supply_voltage']:g} V, margin {report['margin']:g} "
             f"({100 * (1 - report['margin']):.0f} % of each limit in reserve), "
             f"{report['family']} servos, objective {report['objective']}"]
    lines.append(f"  {'dof':<22} {'chosen':<11} {'g':>4}  {'worst check':<13}{'ratio':>6}   candidates (mass "
                 "order: servo worst-check ratio)")
    for dof, j in report["joints"].items():
        shown = [c for c in j["candidates"] if c["why_not"] is None][:SHOWN]
        cells = "  ".join(f"{c['servo']} {_short(c['worst_check'])} {fixed(c['worst_ratio'])}"
                          + ("" if c["passed"] else "✗") for c in shown)
        if j["servo"]:
            lines.append(f"  {dof:<22} {j['servo']:<11} {j['mass_kg'] * 1e3:>4.0f}  {j['worst_check']:<13}"
                         f"{fixed(j['worst_ratio']):>6}   {cells}")
        elif j["candidates"] and j["candidates"][0]["worst_check"]:
            lines.append(f"  {dof:<22} {'—':<11} {'':>4}  {'':<13}{'':>6}   {cells}")
        else:
            lines.append(f"  {dof:<22} {'(not reached)':<11}")
    lines.append("  (ratio: the peak share of the limit over every motion; ✗ over what the margin allows)")
    left_out = _left_out(report)
    if left_out:
        lines.append("  not candidates: " + "; ".join(f"{', '.join(names)} ({why})" for why, names in left_out.items()))
    for tried in report.get("by_voltage", []):
        if tried["voltage"] != report["supply_voltage"] and tried["passed"]:
            kinds = ", ".join(f"{n} × {name}" for name, n in _count(tried["choice"]).items())
            lines.append(f"  at {tried['voltage']:g} V a set passes too: {kinds}; servos {tried['servo_mass_kg']:.3f} kg")
        elif tried["voltage"] != report["supply_voltage"]:
            over = ", ".join(f"{c['servo']} {_short(c['worst_check'])} {fixed(c['worst_ratio'])}"
                             for c in tried["candidates"])
            lines.append(f"  at {tried['voltage']:g} V none passes: {tried['failed_dof']} over its limit with every "
                         f"servo ({over})")
    if report["passed"] or "servo_mass_kg" in report:
        bill = ", ".join(f"{n} × {name}" for name, n in report["bill"].items())
        lines.append(f"bill: {bill}; servos {report['servo_mass_kg']:.3f} kg")
        spare = [(dof, j) for dof, j in report["joints"].items() if "original_worst" in j]
        for dof, j in spare:
            o = j["original_worst"]
            if o["spare_kg"] > 0:
                lines.append(f"  margin to spare at {dof}: its {j['original']} peaks at {fixed(o['ratio'])} of its "
                             f"{o['check']} limit; the {j['servo']}, {o['spare_kg'] * 1e3:.0f} g lighter, suffices")
        if report.get("reached_margin") is not None:
            lines.append(f"largest reserve: every joint within {report['reached_margin']:.3f} of its limits "
                         f"(bisection to {sizing.MARGIN_TOLERANCE:.0%})")
    if "failure" in report:
        f = report["failure"]
        lines.append(f"NONE PASSES: at {f['dof']} even the {f['servo']} peaks at {fixed(f['ratio'])} of its "
                     f"{f['check']} limit ({f['motion']}), with the lightest passing servos outboard of it")
        fit = report.get("fit")
        if fit and fit["time_scale"]:
            lines.append(f"  played {fit['time_scale']:.3f}× slower a set passes ({fit['servo_mass_kg']:.3f} kg): "
                         + ", ".join(f"{d} {s}" for d, s in fit["choice"].items()))
        elif fit:
            lines.append(f"  {fit['how']}")
    for name, v in report.get("validated", {}).items():
        lines.append(f"validate {name} on the written configuration: {'PASS' if v['passed'] else 'FAIL: ' + v['first_violation']}")
    files = report.get("files", {})
    if files:
        lines.append("wrote " + ", ".join(files.values()))
    return "\n".join(lines)


def _left_out(report: dict) -> dict:
    """The servos sizing never picks and why, grouped by the reason: {why: [servo, ...]}."""
    first = next(iter(report["joints"].values()), {"candidates": []})
    grouped: dict[str, list[str]] = {}
    for c in first["candidates"]:
        if c["why_not"]:
            grouped.setdefault(c["why_not"], []).append(c["servo"])
    return grouped


def _short(check: str | None) -> str:
    return {"torque_speed": "τ-ω", "command_range": "command", "temperature": "heat"}.get(check, check or "?")


def progress_line(message: str) -> None:
    print(message, file=sys.stderr, flush=True)
