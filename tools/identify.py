"""`servodyn identify`: the arm's friction, armature, torque-constant scales, payload and heat from
swing logs (servodyn.identification), written as DIR/identified.json, a TOML patch of the
configuration (DIR/patch.toml; `--apply` patches the configuration itself, comments kept, after
showing the change and asking), a plot of measured against predicted torque per joint
(DIR/torque_fit.png) and a table on stdout."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import tomlkit

from ..errors import ServodynError
from ..hal.config import load_config
from ..hal.errors import ConfigError
from ..identification import (FILTER_HZ, FILTER_ORDER, REL_SIGMA_MAX, IdentificationError, Parameter,
                              fit_thermal, identify, measured_torque, prepare,
                              read_rows)
from ..identification.signals import DECIMATED_HZ, SignalError
from ..loop.log import PER_DOF, RunLogError, read_run_log
from ..hal.config_patch import ConfigPatch
from ..report.plots import _pyplot, short

THERMAL_KEYS = ("thermal_resistance_k_w", "thermal_time_constant_s")


class IdentifyError(ServodynError):
    """A one-line reason the command cannot go on (exit status 2)."""


def _columns(path: str) -> set | None:
    """The quantities (q, current, temperature, ...) whose columns the log's header has, or None
    when it cannot be read (read_run_log then says why)."""
    file = Path(path) / "swing_log.csv" if Path(path).is_dir() else Path(path)
    try:
        with open(file, newline="") as f:
            header = f.readline().strip().split(",")
    except (OSError, UnicodeDecodeError):
        return None
    return {name.rsplit("_", 1)[0] for name in header} | {p for p in ("q", "current", "temperature")
                                                          if any(h.startswith(p + "_") for h in header)}


def _read(path: str, model, joints, cutoff: float):
    """A log's prepared samples, and its raw current and temperature for the heat (None when absent)."""
    have = _columns(path)
    if have is not None and "q" in have and "current" not in have:
        raise IdentifyError(f"{path}: no current_<dof> columns: the servos' current was not logged, and the "
                            "torque is read from it (current x torque_constant x gear_ratio)")
    need = ("q", "current") + (("temperature",) if have and "temperature" in have and "temperature" in PER_DOF else ())
    try:
        log = read_run_log(path, model, need=need)
    except RunLogError as err:
        raise IdentifyError(str(err)) from None
    current = np.asarray(log.current, dtype=float)
    if not np.any(current):
        raise IdentifyError(f"{path}: the current is zero throughout: no torque to identify from")
    try:
        prepared = prepare(log.t, log.q, measured_torque(current, joints), cutoff_hz=cutoff, origin=str(path))
    except SignalError as err:
        raise IdentifyError(str(err)) from None
    temperature = getattr(log, "temperature", None)
    if temperature is not None and np.isnan(np.asarray(temperature, dtype=float)).all():
        temperature = None
    return prepared, (np.asarray(log.t), current, temperature)


def _thermal(raw_logs, joints, dof_names) -> dict:
    """Per joint, the thermal fit of the longest log with a temperature column (or why none). The
    readings are the rows the servos' values change on the grid of (identification.read_rows); the
    ambient is the coolest servo's first reading (the one that had worked least before the log)."""
    out = {}
    with_heat = [r for r in raw_logs if r[2] is not None]
    if not with_heat:
        why = "not determined: no log has a temperature_<dof> column"
        return {dof: {k: Parameter(None, None, why) for k in THERMAL_KEYS} for dof in dof_names}
    t, current, temperature = max(with_heat, key=lambda r: r[0][-1] - r[0][0])
    rows = read_rows(temperature)
    first = [temperature[rows, j][np.isfinite(temperature[rows, j])] for j in range(len(dof_names))]
    ambient = min((float(f[0]) for f in first if len(f)), default=None)
    for j, dof in enumerate(dof_names):
        fit = fit_thermal(t, current[:, j], temperature[:, j], joints[j].servo.winding_resistance,
                          ambient=ambient, rows=rows)
        out[dof] = {"thermal_resistance_k_w": fit.resistance_k_w, "thermal_time_constant_s": fit.time_constant_s}
        if fit.bound is not None:
            for key, bound in zip(THERMAL_KEYS, fit.bound):
                out[dof][key].bound = bound
    return out


def report(config, paths, estimate, thermal, payload_body, known_payload, cutoff) -> dict:
    """identified.json's content."""
    joints = {}
    for dof in estimate.dof_names:
        entry = {k: p.as_json() for k, p in estimate.joints[dof].items()}
        entry.update({k: p.as_json() for k, p in thermal[dof].items()})
        joints[dof] = entry
    payload = None
    if estimate.payload is not None:
        com = estimate.payload["com_m"]
        known = all(p.determined for p in com)
        payload = {"body": estimate.payload["body"], "mass_kg": estimate.payload["mass_kg"].as_json(),
                   "com_m": {"value": [p.value for p in com] if known else None,
                             "std": [p.std for p in com] if known else None}}
        if not known:
            payload["com_m"]["note"] = next(p.note for p in com if not p.determined)
    not_determined = list(estimate.notes)
    for dof, entry in joints.items():
        for key, value in entry.items():
            if value["value"] is None and "never moves" not in value.get("note", "") and key not in THERMAL_KEYS:
                not_determined.append(f"{dof} {key}: {value['note']}")
        # the heat: one line per joint (the two constants come from one fit)
        heat = [k for k in THERMAL_KEYS if entry[k]["value"] is None]
        if heat:
            not_determined.append(f"{dof} {' and '.join(heat)}: {entry[heat[0]]['note']}")
    out = {"config": config.name, "logs": [str(p) for p in paths],
           "filter": {"kind": "Butterworth low-pass, forwards and backwards (scipy sosfiltfilt)",
                      "order": FILTER_ORDER, "cutoff_hz": cutoff, "lag_s": 0.0, "decimated_hz": DECIMATED_HZ,
                      "gain_at_cutoff_db": -6.0},
           "known_payload_kg": known_payload, "joints": joints, "payload": payload,
           "residual_rms_nm": estimate.residual_rms_nm, "condition_number": estimate.condition_number,
           "equations": estimate.rows, "not_determined_above_relative_std": REL_SIGMA_MAX,
           "not_determined": not_determined}
    if estimate.base:
        out["base_parameters"] = {name: p.as_json() for name, p in estimate.base}
    return out


def patch_values(result: dict, config) -> tuple[dict, dict | None]:
    """The configuration keys the data determine: per dof, and the [payload] table (or None). The
    payload identified is what the arm carries beyond the configuration's model, so a configured
    [payload] and it make the patch's one point mass."""
    per_joint = {}
    for dof, entry in result["joints"].items():
        values = {k: v["value"] for k, v in entry.items() if v["value"] is not None}
        if values:
            per_joint[dof] = values
    payload = result["payload"]
    if not payload or payload["mass_kg"]["value"] is None or payload["com_m"]["value"] is None:
        return per_joint, None
    mass, com = payload["mass_kg"]["value"], np.array(payload["com_m"]["value"])
    before = getattr(config, "payload", None)
    if before is not None and before.body == payload["body"] and before.mass > 0:
        # a payload without com_m sits at the body's centre of mass, which it then leaves unchanged
        b = config.model.body_names.index(before.body)
        c0 = np.array(before.com) if before.com is not None else np.asarray(config.model.bodies[b].com, dtype=float)
        total = before.mass + mass
        if total <= 0:
            return per_joint, None
        com = (before.mass * c0 + mass * com) / total
        mass = total
    return per_joint, {"body": payload["body"], "mass_kg": float(mass), "com_m": [float(c) for c in com]}


def patch_toml(result: dict, config) -> str:
    """DIR/patch.toml: the identified keys as [[joint]] tables and a [payload] table."""
    per_joint, payload = patch_values(result, config)
    doc = tomlkit.document()
    doc.add(tomlkit.comment(f"servodyn identify: from {', '.join(result['logs'])} on '{result['config']}'"))
    doc.add(tomlkit.comment("values the logs determine; copy into the configuration, or use identify --apply"))
    joints = tomlkit.aot()
    for dof, values in per_joint.items():
        table = tomlkit.table()
        table.add("dof", dof)
        for key, value in values.items():
            table.add(key, float(f"{value:.6g}"))
        joints.append(table)
    doc.add("joint", joints)
    if payload:
        table = tomlkit.table()
        table.add("body", payload["body"])
        table.add("mass_kg", float(f"{payload['mass_kg']:.6g}"))
        table.add("com_m", [float(f"{c:.6g}") for c in payload["com_m"]])
        doc.add("payload", table)
    return tomlkit.dumps(doc)


def fit_figure(path: Path, estimate, title: str) -> None:
    """Measured (filtered) and predicted torque per joint, the logs one after the other."""
    plt = _pyplot()
    n = len(estimate.dof_names)
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.6 * n + 1), sharex=True, squeeze=False)
    offset = 0.0
    for name, t, measured, predicted in estimate.fits:
        tt = t - t[0] + offset
        for j, ax in enumerate(axes[:, 0]):
            ax.plot(tt, measured[:, j], color="0.3", lw=1.0, label="measured" if offset == 0 else None)
            ax.plot(tt, predicted[:, j], color="tab:red", lw=0.8, label="predicted" if offset == 0 else None)
        offset = tt[-1] + 0.5
    for j, ax in enumerate(axes[:, 0]):
        rms = estimate.residual_rms_nm[estimate.dof_names[j]]
        ax.set_ylabel("N·m", fontsize=8)
        ax.set_title(f"{short(estimate.dof_names[j])}: residual {'-' if rms is None else f'{rms:.3g} N·m rms'}",
                     fontsize=8, loc="left")
    axes[0, 0].legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time (s), logs one after the other")
    fig.suptitle(short(title), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _cell(p: dict, digits: int = 3) -> str:
    if p["value"] is None:
        return "—"
    return f"{p['value']:.{digits}g} ±{p['std']:.1g}"


def summary(result: dict) -> str:
    """The table on stdout: per joint the numbers with their standard errors; the payload; the fit."""
    cols = [("friction_coulomb_nm", "Fc N·m"), ("friction_viscous_nm_s", "Fv N·m·s"), ("armature_kg_m2", "Ia kg·m²"),
            ("torque_constant_scale", "Kt scale"), ("thermal_resistance_k_w", "Rth K/W"),
            ("thermal_time_constant_s", "τth s")]
    width = max(len(d) for d in result["joints"]) + 1
    lines = [f"{'joint':<{width}}" + "".join(f"{h:>17}" for _, h in cols) + f"{'resid N·m':>11}"]
    for dof, entry in result["joints"].items():
        rms = result["residual_rms_nm"][dof]
        lines.append(f"{dof:<{width}}" + "".join(f"{_cell(entry[k]):>17}" for k, _ in cols)
                     + f"{'—' if rms is None else f'{rms:.3g}':>11}")
    payload = result["payload"]
    if payload:
        com = payload["com_m"]
        where = ("—" if com["value"] is None else
                 "(" + ", ".join(f"{v * 1e3:.1f}±{s * 1e3:.1g}" for v, s in zip(com["value"], com["std"])) + ") mm")
        lines.append(f"payload at {payload['body']}: {_cell(payload['mass_kg'])} kg, com {where}")
    base = result.get("base_parameters")
    if base:
        found = sum(v["value"] is not None for v in base.values())
        lines.append(f"the arm's base parameters: {found} of {len(base)} determined (identified.json: base_parameters)")
    unheated = {dof: entry["thermal_resistance_k_w"]["note"] for dof, entry in result["joints"].items()
                if entry["thermal_resistance_k_w"]["value"] is None}
    if unheated and len(set(unheated.values())) == 1 and len(unheated) == len(result["joints"]):
        lines.append(f"thermal constants {next(iter(unheated.values()))}")
    else:
        lines.extend(f"{dof}: thermal constants {note}" for dof, note in unheated.items())
    lines.append(f"condition number {result['condition_number']:.3g} over {result['equations']} equations; "
                 "— = not determined (see identified.json)")
    return "\n".join(lines)


def run(config_name: str, paths: list[str], payload_body: str | None, known_payload: float, arm: bool,
        out: Path, cutoff: float = FILTER_HZ, apply_to: str | None = None, apply: bool = False,
        confirm=None, say=print, warn=print, loaded: str | None = None) -> int:
    """`loaded`: the one of `paths` whose run carried `known_payload` kg more (default: the last)."""
    try:
        config = load_config(config_name)
    except ConfigError as err:
        raise IdentifyError(str(err)) from None
    model = config.model
    by_dof = {j.dof: j for j in config.joints}
    missing = [d for d in model.dof_names if d not in by_dof]
    if missing:
        raise IdentifyError(f"'{config.name}': no [[joint]] for dof {missing[0]}: its current cannot be read as torque")
    joints = [by_dof[d] for d in model.dof_names]
    if not (math.isfinite(cutoff) and cutoff > 0):
        raise IdentifyError(f"--cutoff must be a positive number of Hz, got {cutoff:g}")
    if loaded is not None and loaded not in paths:
        raise IdentifyError(f"{loaded}: not one of the logs given ({', '.join(map(str, paths))}), so it cannot be "
                            "the one that carried the known payload")
    read = [_read(p, model, joints, cutoff) for p in paths]
    try:
        estimate = identify(model, joints, [r[0] for r in read], payload_body=payload_body,
                            known_payload=known_payload, arm=arm, names=[str(p) for p in paths],
                            loaded=None if loaded is None else paths.index(loaded))
    except IdentificationError as err:
        raise IdentifyError(str(err)) from None
    for note in estimate.notes:
        warn(f"servodyn identify: {note}")
    # the logs' torque used the effective constant (the configured one x its scale so far): the
    # scale found multiplies that one
    for joint in joints:
        found = estimate.joints[joint.dof]["torque_constant_scale"]
        if found.determined:
            s0 = getattr(joint, "torque_constant_scale", 1.0)
            estimate.joints[joint.dof]["torque_constant_scale"] = Parameter(found.value * s0, found.std * s0)
    thermal = _thermal([r[1] for r in read], joints, model.dof_names)
    result = report(config, paths, estimate, thermal, payload_body, known_payload, cutoff)
    out.mkdir(parents=True, exist_ok=True)
    (out / "identified.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / "patch.toml").write_text(patch_toml(result, config))
    fit_figure(out / "torque_fit.png", estimate, f"{config.name}: measured and predicted joint torque")
    say(summary(result))
    say(f"wrote {out / 'identified.json'}, {out / 'patch.toml'}, {out / 'torque_fit.png'}")
    if apply or apply_to:
        return _apply(config, result, apply_to, confirm, say)
    return 0


def _apply(config, result: dict, target: str | None, confirm, say) -> int:
    """The configuration patched with the determined values, comments kept, after asking."""
    per_joint, payload = patch_values(result, config)
    try:
        patch = ConfigPatch.of(config, target)
        for dof, values in per_joint.items():
            patch.set_joint(dof, **values)
        if payload:
            patch.set_table("payload", **payload)
        return patch.offer(confirm or (lambda question: False), say)
    except (ConfigError, OSError) as err:
        raise IdentifyError(str(err)) from None
