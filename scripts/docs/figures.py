"""The figures the documents quote, produced by the commands that print them.

The README and the folder READMEs hold cog blocks (`<!-- [[[cog ... ]]] -->` … `<!-- [[[end]]] -->`)
whose generators call the functions here: each runs the real command (`servodyn swing`,
`servodyn validate`, `servodyn experiment`, `servodyn demo`) in a scratch folder, reads what it
printed or wrote (summary.json, report.json) and prints the document's text with the figures
filled in. `make docs` rewrites the blocks; `tests/test_docs.py` runs the same with `--check`, so
a change that moves a figure fails `make test` until the document moves with it
(scripts/docs/docs.py runs cog on every document).

Each command runs once per cog process, whatever the number of blocks quoting it (`run` is
cached): cog processes every document in one process.

Only deterministic figures: the lock-step swing, the validator, the experiments and the demo's
torques. Timings (Hz, ms of CPU, "on this machine") stay out: a block masks them.

A command that fails (a traceback, an exit status it should not have) does not fail the
generation: its figures read *pending* with one line saying which command failed and why, so a
document can quote a command that others are still fixing; once the command runs, `make docs`
fills the figures in (and `--check` fails until it has).
"""

from __future__ import annotations

import atexit
import functools
import json
import math
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_SCRATCH = Path(tempfile.mkdtemp(prefix="servodyn-docs-"))
atexit.register(shutil.rmtree, _SCRATCH, ignore_errors=True)
_runs = 0


class CommandFailed(Exception):
    def __init__(self, command: str, why: str):
        super().__init__(f"{command}: {why}")
        self.command, self.why = command, why


@functools.cache
def run(*args: str, ok: tuple[int, ...] = (0,)) -> tuple[str, Path]:
    """`servodyn ARGS` with `--out` in a fresh scratch folder (when the command takes one);
    its standard output and that folder. Raises CommandFailed on a traceback or another exit."""
    global _runs
    _runs += 1
    out = _SCRATCH / f"run{_runs}"
    argv = list(args)
    if args[0] in ("swing", "validate", "experiment", "demo", "size"):
        argv += ["--out", str(out)]
    if args[0] == "retarget":
        argv += ["--report", str(out), "-o", str(out / "motion.csv")]
    if args[0] in ("validate", "size") and "--simulate" not in args:
        proc = _in_process(argv)
    else:
        proc = subprocess.run([sys.executable, "-m", "servodyn.tools.cli", *argv], cwd=_SCRATCH,
                              capture_output=True, text=True)
    shown = "servodyn " + shlex.join(args)
    default = {"swing": "out/swing", "validate": "out/validate", "demo": "out/demo", "size": "out/size"}.get(args[0])
    if args[0] == "experiment":
        default = f"out/{args[1]}"
    if "Traceback" in proc.stderr or proc.returncode not in ok:
        last = (proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
        raise CommandFailed(shown, f"exit {proc.returncode}, {last.strip()}")
    return proc.stdout.replace(str(out), default) if default else proc.stdout, out


def _in_process(argv: list[str]) -> subprocess.CompletedProcess:
    """`servodyn validate` through the command's own entry point in this process, less its two
    figures (their drawing is most of its time, and no document reads them): a dozen runs take
    seconds instead of half a minute. Where the plots have moved, they are simply drawn."""
    import contextlib
    import io
    import os
    import traceback
    from unittest import mock
    from servodyn.tools import cli
    out, err = io.StringIO(), io.StringIO()
    import importlib
    for name in ("servodyn.report.plots", "servodyn.report.validation"):
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    with contextlib.ExitStack() as stack:
        # wherever the two figure functions are bound (the plots module, the command's module)
        for module in [m for name, m in sys.modules.items() if name.startswith("servodyn.") and m is not None]:
            for name in ("envelope_figure", "limits_in_time_figure"):
                if callable(getattr(module, name, None)):
                    stack.enter_context(mock.patch.object(module, name, lambda *a, **k: None))
        cwd = os.getcwd()
        os.chdir(_SCRATCH)
        stack.callback(os.chdir, cwd)
        stack.enter_context(contextlib.redirect_stdout(out))
        stack.enter_context(contextlib.redirect_stderr(err))
        try:
            code = cli.main(argv)
        except BaseException:               # a traceback, as the command would print it
            traceback.print_exc(file=err)
            code = 1
    return subprocess.CompletedProcess(argv, code, out.getvalue(), err.getvalue())


def _json(args: tuple[str, ...], name: str, ok=(0,)) -> dict:
    _, out = run(*args, ok=ok)
    return json.loads((out / name).read_text())


def swing(*args: str) -> dict:
    """`servodyn swing ARGS` (lock-step on the simulated bus): its summary.json."""
    return _json(("swing", *args), "summary.json")


def _as_written(args: tuple) -> tuple:
    """The documents quote a motion as written (time scale 1) unless they name a time scale:
    validate's own default is the configuration's (4 for the replica's forehand)."""
    return args if "--time-scale" in args else (*args, "--time-scale", "1")


def validate(config: str, motion: str = "tennis_forehand", *args: str) -> dict:
    """`servodyn validate CONFIG MOTION ARGS`: its report.json (exit 0 pass or 1 fail)."""
    return _json(("validate", config, motion, *_as_written(args)), "report.json", ok=(0, 1))


def validate_output(config: str, motion: str = "tennis_forehand", *args: str) -> str:
    return run("validate", config, motion, *_as_written(args), ok=(0, 1))[0]


def retarget(clip: str, *args: str) -> dict:
    """`servodyn retarget CLIP ARGS`: its report.json (exit 0, or 1 flagged)."""
    return _json(("retarget", clip, *args), "report.json", ok=(0, 1))


CLIPS = Path("/usr/share/assimp/models/BVH")     # Debian's assimp-testmodels (make test installs it)


def readme_mocap_table() -> None:
    """The three public clips, ten seconds of each from t = 2 s, retargeted onto the replica."""
    rows = ["| clip (10 s from t = 2 s) | elbow axis: twist, residual p95 | captured outside the limits "
            "(dof-frames) | flips avoided | hand error p95 | `validate --fit` on the replica |",
            "|---|---|---|---|---|---|"]
    for name in ("01_01", "01_03", "Boxing_Toes"):
        try:
            r = retarget(str(CLIPS / f"{name}.bvh"), "--config", "replica", "--time", "2:12")
        except CommandFailed as failed:
            rows.append(f"| {name} | *pending: `{failed.command}` fails today ({failed.why})* | | | | |")
            continue
        cal = r["calibration"]
        fit = r["validate"]["fit_time_scale"]
        rows.append(f"| {name} | {abs(cal['twist_deg']):.1f}°, {cal['residual_p95_deg']:.1f}° | "
                    f"{sum(h['frames'] for h in r['limit_hits'].values())} | {r['flips_avoided']} | "
                    f"{r['cartesian_error']['hand']['p95_mm']:.1f} mm | "
                    + (f"×{fit:.2f}" if fit else "none") + " |")
    print("\n".join(rows))


def experiment(name: str) -> dict:
    return _json(("experiment", name), "summary.json")


def experiment_output(name: str) -> str:
    return run("experiment", name)[0]


def demo_output() -> str:
    return run("demo")[0]


@functools.cache
def model_mass(name: str) -> float:
    import servodyn
    return servodyn.load_model(name).total_mass


@functools.cache
def config(name: str):
    from servodyn.hal import load_config
    return load_config(name)


def make_recipe(target: str) -> list[str]:
    """The commands of a Makefile target's recipe, less the echo lines and the venv's path."""
    lines = (ROOT / "Makefile").read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if re.match(rf"{re.escape(target)}\s*:", line))
    recipe = []
    for line in lines[start + 1:]:
        if not line.startswith("\t"):
            break
        command = line.strip().lstrip("@")
        if not command.startswith("echo"):
            recipe.append(command.replace("$(VENV)/bin/", ""))
    return recipe


# ---------------------------------------------------------------------------------- writing

def deg(rad: float) -> float:
    return math.degrees(rad)


class _Pending:
    def __format__(self, spec: str) -> str:
        return "*pending*"

    def __getattr__(self, name):
        return self

    def __getitem__(self, key):
        return self


class _AllPending(dict):
    def __missing__(self, key):
        return _Pending()


def fill(template: str, values, prefix: str = "") -> None:
    """Print `template` (dedented, str.format fields) filled with `values()`, a dict. When a
    command behind it fails, every field reads *pending* and a line says which command and why.
    `prefix` starts every line (a comment's "# " in a TOML file)."""
    note = ""
    try:
        got = values()
    except CommandFailed as failed:
        got = _AllPending()
        note = (f"\n\n*Pending: `{failed.command}` fails today ({failed.why}); `make docs` writes "
                f"these figures once it runs.*")
    text = textwrap.dedent(template).strip("\n").format_map(got) + note
    print("\n".join(prefix + line for line in text.splitlines()))


def code(text: str, lang: str = "") -> None:
    print(f"```{lang}\n{text.rstrip()}\n```")


def mask_timings(text: str) -> str:
    """A command's output with its measured times (ms, us, s of computation) replaced by '…'."""
    text = re.sub(r"in [0-9.]+ ms = [0-9.]+ us per sample", "in … ms = … us per sample", text)
    text = re.sub(r"steps in [0-9.]+ ms", "steps in … ms", text)
    text = re.sub(r"(\d+ plans?), [0-9.]+ s\)", r"\1, … s)", text)
    text = re.sub(r" \([0-9.]+ s\)$", " (… s)", text, flags=re.M)
    return text


def wrap(line: str, width: int = 100, indent: int = 6) -> str:
    return "\n".join(textwrap.wrap(line, width, subsequent_indent=" " * indent, break_on_hyphens=False))


# ---------------------------------------------------------------------------------- the figures
# One function per passage: the values its template names. Keep them thin: the commands compute.

def _joint(report: dict, dof: str) -> dict:
    return report["joints"][dof]


def _limit(report: dict, dof: str, check: str, peak: str) -> float:
    """A joint's limit in a check, from its peak and the peak's ratio (report.json's own figures)."""
    row = _joint(report, dof)
    return row[peak] / row["checks"][check]


def make_demo() -> dict:
    return {"demo": "; ".join(make_recipe("demo"))}


def readme_swing() -> dict:
    ff, pd = swing(), swing("--no-feedforward")
    human = validate("replica", "tennis_forehand", "--fit", "--retime")
    return {**make_demo(), "ff_max": deg(ff["tracking_max_rad"]), "ff_rms": deg(ff["tracking_rms_rad"]),
            "pd_max": deg(pd["tracking_max_rad"]), "ticks": ff["ticks"] + ff["home_ticks"],
            "ff_chatter": 100 * ff["chatter_max"],
            "chatter_dof": max(ff["chatter_by_dof"], key=lambda dof: ff["chatter_by_dof"][dof]["rms_share"]),
            "home_ticks": ff["home_ticks"], "scale": ff["time_scale"],
            "rot_speed": _joint(human, "r_shoulder_rotation")["peak_speed_rad_s"],
            "rot_limit": _limit(human, "r_shoulder_rotation", "speed", "peak_speed_rad_s")}


def readme_can() -> dict:
    can, can_pd, mixed = swing("--config", "replica_can"), swing("--config", "replica_can", "--no-feedforward"), \
        swing("--config", "replica_mixed")
    wire = validate("replica_can")["bus"]
    return {"can_mass": config("replica_can").model.total_mass, "can_scale": can["time_scale"],
            "can_ff": deg(can["tracking_max_rad"]), "can_pd": deg(can_pd["tracking_max_rad"]),
            "mixed_mass": config("replica_mixed").model.total_mass, "mixed_scale": mixed["time_scale"],
            "mixed_ff": deg(mixed["tracking_max_rad"]),
            "can_identified": deg(identified_can()["tracking_max_rad"]),
            "can_wire_ms": max(bus["seconds_per_tick"] for bus in wire) * 1e3,
            "can_period_ms": config("replica_can").control_period * 1e3,
            "can_hz": 1 / config("replica_can").control_period,
            "mixed_period_ms": config("replica_mixed").control_period * 1e3}


def identified_can() -> dict:
    """replica_can's forehand after its motors' friction is identified from one log, as the README's
    identification section tells a user to: excite -> swing -> identify --apply -> swing."""
    folder = _SCRATCH / "identified_can"
    folder.mkdir(exist_ok=True)
    excitation, patched = folder / "excitation.csv", folder / "patched.toml"
    run("excite", "--config", "replica_can", "--duration", "10", "--out", str(excitation))
    _, played = run("swing", "--config", "replica_can", "--motion", str(excitation))
    run("identify", "--config", "replica_can", str(played / "swing_log.csv"), "--out", str(folder / "id"),
        "--apply", "--write", str(patched), "--yes")
    return swing("--config", str(patched))


def readme_demo() -> None:
    """`servodyn demo`'s output, abridged to two rows of its table, its times masked."""
    lines = mask_timings(demo_output()).splitlines()
    header = next(i for i, line in enumerate(lines) if line.lstrip().startswith("t (s)"))
    rows = [line for line in lines[header + 1:] if re.match(r"\s+0\.[46]0 ", line)]
    peak = next(i for i, line in enumerate(lines) if line.lstrip().startswith("peak"))
    code("\n".join(lines[:header + 1] + rows + ["  ..."] + lines[peak:]))


def sci(x: float | None, digits: int = 1) -> str:
    """1.9e-8 style (no exponent padding); plain decimals from 0.1 up; 'inf' for a run that diverged."""
    if x is None or not math.isfinite(x):
        return "inf"
    if x >= 0.1:
        return f"{x:.2f}"
    mantissa, exponent = f"{x:.{digits}e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def readme_experiments() -> dict:
    pend, still, sw = experiment("pendulum"), experiment("still"), experiment("swing")
    ff_only = dict(still["ff_only_drift_by_time"])
    return {"pend_step_ms": pend["small_time_step_s"] * 1e3, "pend_s": pend["duration_s"],
            "pend_drift": sci(pend["energy_drift_rel"]), "pend_com": sci(pend["com_displacement_max_m"]),
            "still_drift": sci(still["max_drift_rad"]), "still_s": still["duration_s"],
            "still_1s": sci(ff_only[1.0], 0), "still_2s": sci(ff_only[2.0], 0) if ff_only[2.0] < 0.1 else f"{ff_only[2.0]:.2f}",
            "still_growth": math.log(ff_only[2.0] / ff_only[1.0]),
            "swing_max": deg(sw["tracking_max_rad"]), "swing_rms": deg(sw["tracking_rms_rad"]),
            "tau_flex": sw["peak_torque_nm"]["r_shoulder_flexion"],
            "tau_abd": sw["peak_torque_nm"]["r_shoulder_abduction"],
            "tau_rot": sw["peak_torque_nm"]["r_shoulder_rotation"]}


def readme_singular_table() -> None:
    def cell(run: dict) -> str:
        return sci(run["energy_drift_rel"]) if run["energy_drift_rel"] is not None \
            else f"div. {run['ran_until_s']:.1f} s"
    try:
        rows = experiment("pendulum")["drift_table"]
    except CommandFailed as failed:
        return print(f"*Pending: `{failed.command}` fails today ({failed.why}); `make docs` writes this table "
                     "once it runs.*")
    print("| step | RK4, ball joints | Euler, ball joints | RK4, hinge chains | Euler, hinge chains |")
    print("|---|---|---|---|---|")
    for row in rows:
        cells = [cell(row[k]) for k in ("rk4_ball", "euler_ball", "rk4_angles", "euler_angles")]
        print(f"| {row['small_time_step_s'] * 1e3:g} ms | " + " | ".join(cells) + " |")


def readme_numbers_tables() -> None:
    numbers = experiment("numbers")
    tracking = numbers["swing_tracking"]
    ratios = list(next(iter(tracking.values())))
    print("| mode | " + " | ".join(f"ratio {r}" for r in ratios) + " |")
    print("|---|" + "---|" * len(ratios))
    for mode, by_ratio in tracking.items():
        print(f"| {mode} | " + " | ".join(f"{deg(by_ratio[r]['tracking_max_rad']):.3f} / "
                                          f"{deg(by_ratio[r]['tracking_rms_rad']):.3f}" for r in ratios) + " |")
    print()
    print("| integrator | swing tracking max (deg) | pendulum drift 10 s, 1 ms | pendulum drift 10 s, 0.25 ms |")
    print("|---|---|---|---|")
    for name, row in numbers["integrators"].items():
        drifts = [row["pendulum_energy_drift_rel_1ms"], row["pendulum_energy_drift_rel_0.25ms"]]
        print(f"| {name} | {deg(row['swing_tracking_max_rad']):.4f} | "
              + " | ".join("inf" if d is None else f"{d:.2e}" for d in drifts) + " |")


def readme_claims() -> dict:
    numbers, pend = experiment("numbers"), experiment("pendulum")
    tracking, integrators = numbers["swing_tracking"], numbers["integrators"]
    finest = min(pend["drift_table"], key=lambda row: row["small_time_step_s"])
    at = lambda mode, ratio: deg(tracking[mode][str(ratio)]["tracking_max_rad"])
    return {"euler_fine": 100 * finest["euler_ball"]["energy_drift_rel"], "fine_ms": finest["small_time_step_s"] * 1e3,
            "rk4_fine": sci(finest["rk4_ball"]["energy_drift_rel"], 0),
            "int_rk4": deg(integrators["rk4"]["swing_tracking_max_rad"]),
            "int_euler": deg(integrators["euler"]["swing_tracking_max_rad"]),
            "pd": at("pd", 10), "ff1": at("feedforward_pd", 1), "ff5": at("feedforward_pd", 5),
            "ff10": at("feedforward_pd", 10), "ff20": at("feedforward_pd", 20),
            "ct1": at("computed_torque", 1), "ct10": at("computed_torque", 10)}


def readme_validate_output() -> None:
    """`servodyn validate replica tennis_forehand --fit --retime`, its times masked, the long
    lines wrapped, without the list of files it wrote."""
    out = mask_timings(validate_output("replica", "tennis_forehand", "--fit", "--retime"))
    lines = [line for line in out.splitlines()[1:] if not line.startswith("wrote ")]
    code("\n".join(wrap(line) if len(line) > 100 and not line.startswith("  ") else line
                   for line in lines if line.strip()))


def _ticks(n: int) -> str:
    if n == 0:
        return "at the predicted time"
    return f"{abs(n)} tick{'' if abs(n) == 1 else 's'} {'after' if n > 0 else 'before'} the predicted time"


def readme_validate_bullets() -> dict:
    human = validate("replica", "tennis_forehand", "--fit", "--retime")
    sim1 = validate("replica", "tennis_forehand", "--simulate")["simulation"]
    sim3 = validate("replica", "tennis_forehand", "--time-scale", "3", "--simulate")["simulation"]
    first = sim1["first"]
    same = first["predicted"]["dof"] == first["saturated"]["dof"]
    saturated_3 = [dof for dof, row in sim3["joints"].items() if row["saturated_s"] is not None]
    return {"fit_08": validate("replica", "tennis_forehand", "--margin", "0.8", "--fit")["fit_time_scale"],
            "scale": swing()["time_scale"],
            "retime_s": human["retime"]["duration_s"], "fit_s": human["fit_time_scale"] * human["duration_s"],
            "first": "the one predicted" if same else
            f"{first['saturated']['dof']} (predicted: {first['predicted']['dof']})",
            "ticks": _ticks(first["ticks_apart"]),
            "at_3": "no servo saturates" if not saturated_3 else "saturated: " + ", ".join(saturated_3),
            "track_3": deg(sim3["tracking_max_rad"])}


# ---------------------------------------------------------------------------------- hal/README.md

GRID = (1, 1.5, 2, 3, 4, 5, 6)          # the time scales of the replica's table
MARGIN = "0.8"                          # 20 % in reserve


def _short(dof: str) -> str:
    return dof.removeprefix("r_").replace("_", " ")


def at_scale(s: float, *args: str) -> dict:
    return validate("replica", "tennis_forehand", "--time-scale", f"{s:g}", "--margin", MARGIN, *args)


def _worst(report: dict, check: str) -> tuple[float, str]:
    return max((row["checks"][check], dof) for dof, row in report["joints"].items())


def chosen_scale() -> float:
    return next(s for s in GRID if at_scale(s)["passed"])


def hal_margin_table() -> None:
    chosen = chosen_scale()
    print("| s | duration (s) | peak current, % of limit | peak speed, % of limit | torque-speed envelope, % "
          f"| `--margin {MARGIN}` |")
    print("|---|---|---|---|---|---|")
    for s in GRID:
        report = at_scale(s)
        cells = [f"{s:g}", f"{report['duration_s']:.1f}"]
        for check in ("current", "speed", "torque_speed"):
            ratio, dof = _worst(report, check)
            cells.append(f"{100 * ratio:.0f} ({_short(dof)})")
        cells.append("PASS" if report["passed"] else "FAIL")
        if s == chosen:
            cells = [f"**{c}**" for c in cells]
        print("| " + " | ".join(cells) + " |")


def hal_joint_table() -> None:
    chosen, cfg = chosen_scale(), config("replica")
    one, slow = at_scale(1), at_scale(chosen)
    print(f"| joint | servo | peak torque (N m) s=1 / s={chosen:g} | stall torque (N m) | peak current (A) s=1 / "
          f"s={chosen:g}, limit | peak speed (rad/s) s=1 / s={chosen:g}, limit |")
    print("|---|---|---|---|---|---|")
    for joint in cfg.joints:
        a, b = one["joints"][joint.dof], slow["joints"][joint.dof]
        print(f"| {joint.dof} | {joint.servo.name} | {a['peak_torque_nm']:.2f} / {b['peak_torque_nm']:.2f} "
              f"| {joint.servo.stall_torque:g} "
              f"| {a['peak_current_a']:.2f} / {b['peak_current_a']:.2f}, "
              f"{_limit(one, joint.dof, 'current', 'peak_current_a'):.1f} "
              f"| {a['peak_speed_rad_s']:.2f} / {b['peak_speed_rad_s']:.2f}, "
              f"{_limit(one, joint.dof, 'speed', 'peak_speed_rad_s'):.2f} |")


def hal_margins() -> dict:
    chosen, one = chosen_scale(), at_scale(1)
    current, current_dof = _worst(one, "current")
    below = max(s for s in GRID if s < chosen)
    before = at_scale(below)
    check_before = max(("speed", "torque_speed", "current"), key=lambda c: _worst(before, c)[0])
    ratio_before, dof_before = _worst(before, check_before)
    finer = (below + chosen) / 2
    fit = validate("replica", "tennis_forehand", "--margin", MARGIN, "--fit")
    slow = [at_scale(s) for s in GRID if s >= below]
    flexion = [r["joints"]["r_shoulder_flexion"]["peak_torque_nm"] for r in slow]
    at_chosen = at_scale(chosen)["joints"]["r_shoulder_flexion"]
    j = lambda dof: one["joints"][dof]["checks"]["speed"]
    return {
        "mass": config("replica").model.total_mass, "human_mass": model_mass("human_arm"),
        "rot_x": j("r_shoulder_rotation"), "flex_x": j("r_shoulder_flexion"),
        "elbow_pct": 100 * j("r_elbow_flexion"), "pron_pct": 100 * j("r_forearm_pronation"),
        "current_sentence": _current_sentence(100 * current, _short(current_dof)),
        "current_t": one["joints"][current_dof]["worst_at_s"]["current"],
        "below": below, "chosen": chosen, "check_before": check_before.replace("_", "-"),
        "dof_before": _short(dof_before), "pct_before": 100 * ratio_before,
        "finer": finer, "finer_pct": 100 * max(_worst(at_scale(finer), c)[0] for c in ("speed", "torque_speed", "current")),
        "flex_lo": min(flexion), "flex_hi": max(flexion), "flex_a": at_chosen["peak_current_a"],
        "flex_limit": _limit(at_scale(chosen), "r_shoulder_flexion", "current", "peak_current_a"),
        "duration": at_scale(chosen)["duration_s"],
        "fit": fit["fit_time_scale"], "fit_s": fit["fit_time_scale"] * fit["duration_s"],
        "fit_148": validate("replica", "tennis_forehand", "--supply-voltage", "14.8", "--margin", MARGIN,
                            "--fit")["fit_time_scale"],
    }


def _current_sentence(pct: float, joint: str) -> str:
    if pct <= 100:
        return f"no joint needs more than {pct:.0f} % of its current"
    return f"the {joint} needs {pct:.0f} % of its current limit"


# ------------------------------------------------------------------- every built-in configuration

CONFIGS = ("replica", "replica_can", "replica_mixed", "replica_pwm")


def configurations_table() -> None:
    """`servodyn validate CONFIG tennis_forehand --time-scale S --fit --retime` and `--simulate`
    on each built-in configuration at its swing's time scale S; a cell whose command fails (or a
    retime that finds no plan, a known fault) reads *pending* and a note below says why."""
    notes = []

    def cell(fn):
        try:
            return fn()
        except CommandFailed as failed:
            notes.append(f"`{failed.command}` fails today ({failed.why})")
            return "*pending*"

    def retime(report):
        info = report["retime"]
        if info["passed"]:
            return f"{info['duration_s']:.2f} s"
        notes.append(f"`--retime` on {report['config']} finds no plan today (“{info['why']}”)")
        return "*pending*"

    print("| configuration | period | S | verdict at S | fit: time scale (duration) | retime (TOPP-RA) | simulated at S: "
          "tracking max |")
    print("|---|---|---|---|---|---|---|")
    for name in CONFIGS:
        cfg = config(name)
        scale = cfg.swing_time_scale or 1.0
        args = (name, "tennis_forehand", "--time-scale", f"{scale:g}")
        checked = cell(lambda: validate(*args, "--fit", "--retime"))
        simulated = cell(lambda: validate(*args, "--simulate")["simulation"])
        if isinstance(checked, dict):
            verdict = "PASS" if checked["passed"] else "FAIL"
            human = checked["duration_s"] / checked["time_scale"]
            fit = (f"{checked['fit_time_scale']:.4f} ({checked['fit_time_scale'] * human:.3f} s)"
                   if checked.get("fit_time_scale") else "none")
            retimed = retime(checked)
        else:
            verdict = fit = retimed = checked
        tracking = (f"{deg(simulated['tracking_max_rad']):.2f}° "
                    f"({'completed' if simulated['completed'] else 'stopped'})"
                    if isinstance(simulated, dict) else simulated)
        print(f"| `{name}` | {cfg.control_period * 1e3:g} ms | {scale:g} | {verdict} | {fit} | {retimed} "
              f"| {tracking} |")
    if notes:
        print("\n*Pending:* " + "; ".join(dict.fromkeys(notes)) + ". `make docs` fills these cells in once "
              "the commands run.")


def near_people_output() -> None:
    """`servodyn validate replica tennis_forehand --time-scale 2 --near-people`: its near-people
    table and verdicts (the servo checks' table above them left out)."""
    lines = validate_output("replica", "tennis_forehand", "--time-scale", "2", "--near-people").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("near people ("))
    code("\n".join(wrap(line) if len(line) > 100 and not line.startswith("  ") else line
                   for line in lines[start:] if line.strip() and not line.startswith(("drawing ", "wrote "))))


def near_people_table() -> None:
    """`servodyn validate CONFIG tennis_forehand --time-scale S --near-people` on each built-in
    configuration at its swing's time scale S: the hand's peak speeds and effective masses, the
    verdict and the fastest passing time scale."""
    print("| configuration | S | hand at S: peak speed, centre of mass / tip | hand's effective mass over the "
          "motion (at the peak) | verdict at S | fastest passing time scale (duration) |")
    print("|---|---|---|---|---|---|")
    for name in CONFIGS:
        scale = config(name).swing_time_scale or 1.0
        try:
            report = validate(name, "tennis_forehand", "--time-scale", f"{scale:g}", "--near-people")
        except CommandFailed as failed:
            print(f"| `{name}` | {scale:g} | *pending: `{failed.command}` fails today ({failed.why})* | | | |")
            continue
        near = report["near_people"]
        links = near["links"]
        hand = list(links.values())[-1]["points"]
        low, high = hand["com"]["effective_mass_range_kg"]
        fastest = report["near_people_time_scale"]
        human = report["duration_s"] / report["time_scale"]
        verdict = "PASS" if near["passed"] else "FAIL: " + ", ".join(
            f"{link} against a {row['limiting_region']} ({row['worst_ratio']:.2f}x)"
            for link, row in links.items() if not row["passed"])
        print(f"| `{name}` | {scale:g} | {hand['com']['peak_speed_m_s']:.2f} / {hand['tip']['peak_speed_m_s']:.2f} m/s "
              f"| {low:.2f}–{high:.2f} kg ({hand['com']['effective_mass_kg']:.2f}) | {verdict} "
              f"| {fastest:.4f} ({fastest * human:.3f} s) |")


def near_people_regions() -> None:
    """The body regions `--near-people` checks, as its report.json gives them."""
    near = validate("replica", "tennis_forehand", "--time-scale", "4", "--near-people")["near_people"]
    print("| body region | transient force F_T (A.2) | spring constant k (A.3) | effective mass m_H (A.3) |")
    print("|---|---|---|---|")
    for name, r in near["regions"].items():
        print(f"| {name} | {r['transient_force_n']:g} N | {r['stiffness_n_per_mm']:g} N/mm | {r['effective_mass_kg']:g} kg |")
    regions = near["no_contact"]["regions"]
    print(f"| {', '.join(regions)} | not permissible | | |")
    print("\n" + textwrap.fill(f"{', '.join(regions).capitalize()}: {near['no_contact']['why']}. No speed makes a "
                               "contact there acceptable: keeping the arm away from the head is the cell's layout "
                               "or a separation monitor, not this check.", 100))


def near_people_figures() -> dict:
    """The hand's effective masses and speeds on the replica and replica_can at their time scales,
    and the hand's permitted speed at each one's largest effective mass (validation.people)."""
    from servodyn.validation.people import REGIONS, permitted_speed
    hand_region = next(r for r in REGIONS if r.name == "hand")

    def hand(config, *args):
        points = list(validate(config, "tennis_forehand", *args, "--near-people")["near_people"]["links"].values())
        return points[-1]["points"]["com"]
    replica, can = hand("replica", "--time-scale", "4"), hand("replica_can", "--time-scale", "2.5")
    low, high = replica["effective_mass_range_kg"]
    return {"arm_kg": config("replica").model.total_mass, "low": low, "high": high,
            "high_can": can["effective_mass_range_kg"][1],
            "cap": float(permitted_speed(high, hand_region)),
            "cap_can": float(permitted_speed(can["effective_mass_range_kg"][1], hand_region)),
            "peak_can": can["peak_speed_m_s"], "at_peak_can": can["effective_mass_kg"]}


SHORTEST_FRAME_BITS = 111               # an 8-byte standard CAN frame with no stuff bit (CAN 2.0A)


def hal_can_wire() -> dict:
    can, mixed = validate("replica_can")["bus"], validate("replica_mixed")["bus"]
    frames, bits = map(int, re.match(r"(\d+) frames x (\d+) bits", can[0]["what"]).groups())
    bitrate = frames * bits / can[0]["seconds_per_tick"]
    shortest = frames * SHORTEST_FRAME_BITS / bitrate
    mixed_can = next(bus for bus in mixed if "frames" in bus["what"])
    return {**readme_can(), "bits": bits, "frames": frames, "short_bits": SHORTEST_FRAME_BITS,
            "short_ms": shortest * 1e3, "can_ms": can[0]["seconds_per_tick"] * 1e3,
            "slow_hz": 1 / can[0]["seconds_per_tick"], "fast_hz": 1 / shortest,
            "mixed_ms": mixed_can["seconds_per_tick"] * 1e3,
            "mixed_motors": int(re.match(r"(\d+) frames", mixed_can["what"]).group(1)) // 2,
            "per_ms": int(1e-3 // (2 * bits / bitrate))}


# ------------------------------------------------------------------ host/model/builtin/README.md

@functools.cache
def model_counts() -> dict:
    """Per built-in model, from `servodyn models`: bodies, dofs and mass (kg, the API's unrounded)."""
    values = {}
    for line in run("models")[0].splitlines()[1:]:
        name, bodies, dofs = line.split()[:3]
        values[f"{name}_bodies"], values[f"{name}_dofs"] = int(bodies), int(dofs)
        values[f"{name}_kg"] = model_mass(name)
    return values


# ------------------------------------------------------------------ README: servodyn size, validate M1 M2 …

SIZE_SCALES = (4, 2, 1)                 # the replica's own time scale, then faster, then human speed


def size(*args: str) -> dict:
    """`servodyn size ARGS`: its size.json (exit 0 a set passes, 1 none does). The documents' sizing
    keeps no reserve (margin 1) unless it names one, as it was written: the command's own default
    keeps 20 %."""
    return _json(("size", *args, *(() if "--margin" in args else ("--margin", "1"))), "size.json", ok=(0, 1))


def replica_size(scale: float) -> dict:
    return size("replica", "--motion", "tennis_forehand", "--time-scale", f"{scale:g}", "--supply-voltage", "12")


def _cell(joint: dict) -> str:
    return f"{joint['servo']} ({joint['worst_check'].replace('_', '-')} {joint['worst_ratio']:.2f})"


def readme_size_table() -> None:
    """The replica's forehand sized at time scales 4, 2, 1 (12 V, Dynamixel): each joint's servo
    and its binding check, the bill's mass; where none passes, the joint and check that rule it out."""
    try:
        reports = {s: replica_size(s) for s in SIZE_SCALES}
    except CommandFailed as failed:
        return print(f"*Pending: `{failed.command}` fails today ({failed.why}); `make docs` writes this table "
                     "once it runs.*")
    own = config("replica")
    print("| joint | the replica's own | " + " | ".join(f"sized, s = {s:g}" for s in SIZE_SCALES) + " |")
    print("|---|---|" + "---|" * len(SIZE_SCALES))
    for joint in own.joints:
        cells = []
        for s in SIZE_SCALES:
            report = reports[s]
            j = report["joints"][joint.dof]
            failure = report.get("failure")
            if j["servo"]:
                cells.append(_cell(j))
            elif failure and failure["dof"] == joint.dof:
                cells.append(f"**none**; nearest: {failure['servo']} at {failure['ratio']:.2f} of its "
                             f"{failure['check'].replace('_', '-')} limit")
            else:
                cells.append("(not reached)")
        print(f"| {joint.dof} | {joint.servo.name} | " + " | ".join(cells) + " |")
    masses = []
    for s in SIZE_SCALES:
        report = reports[s]
        masses.append(f"**{report['servo_mass_kg']:.3f} kg**" if report["passed"] else
                      f"none passes; {report['fit']['time_scale']:.3f}× slower: {report['fit']['servo_mass_kg']:.3f} kg")
    replica_mass = sum(_part_mass(j.servo.name) for j in own.joints)
    print(f"| servos' mass | {replica_mass:.3f} kg | " + " | ".join(masses) + " |")


def _part_mass(name: str) -> float:
    from servodyn.model.modelfile import parts
    return float(parts()[name]["mass"])


def readme_size() -> dict:
    """The figures the size section quotes: the replica's margin to spare at its own time scale,
    human speed in the Dynamixel catalogue (the joint and check that rule it out), any family at
    human speed."""
    own, human = replica_size(4), replica_size(1)
    anyf = size("replica", "--motion", "tennis_forehand", "--family", "any")
    spare = [(dof, j) for dof, j in own["joints"].items() if j.get("original_worst", {}).get("spare_kg", 0) > 0]
    rot = own["joints"]["r_shoulder_rotation"]
    f = human["failure"]
    return {"own_mass": sum(_part_mass(j["original"]) for j in own["joints"].values()),
            "s4_mass": own["servo_mass_kg"], "n_spare": len(spare),
            "rot_orig_ratio": rot["original_worst"]["ratio"], "rot_servo": rot["servo"], "rot_orig": rot["original"],
            "rot_orig_check": rot["original_worst"]["check"].replace("_", "-"),
            "rot_spare_g": rot["original_worst"]["spare_kg"] * 1e3,
            "fail_dof": f["dof"], "fail_check": f["check"].replace("_", "-"), "fail_servo": f["servo"],
            "fail_ratio": f["ratio"], "fit": human["fit"]["time_scale"], "fit_mass": human["fit"]["servo_mass_kg"],
            "any_passed": "passes" if anyf["passed"] else "fails",
            "any_mass": anyf.get("servo_mass_kg", float("nan")), "any_voltage": anyf["supply_voltage"],
            "any_bill": ", ".join(f"{n} × {name}" for name, n in anyf.get("bill", {}).items()),
            "any_binding": "; ".join(f"{_short(dof)} {j['worst_check'].replace('_', '-')} {j['worst_ratio']:.2f}"
                                     for dof, j in anyf["joints"].items() if j.get("worst_ratio", 0) >= 0.9),
            "period_ms": own["control_period_s"] * 1e3}


def readme_validate_many() -> None:
    """`servodyn validate replica tennis_forehand out/validate/retimed.csv`: the forehand as written
    and as TOPP-RA re-timed it, one verdict per motion (the tables left out)."""
    _, first = run("validate", "replica", "tennis_forehand", "--fit", "--retime", "--time-scale", "1", ok=(0, 1))
    retimed = str(first / "retimed.csv")
    out, _ = run("validate", "replica", "tennis_forehand", retimed, "--time-scale", "1", ok=(0, 1))
    lines = [line.replace(retimed, "out/validate/retimed.csv") for line in out.splitlines()
             if line.startswith(("PASS", "FAIL", "ERROR")) or " of " in line and "pass" in line]
    lines = [line.replace(str(_SCRATCH), "out") for line in lines]
    code("\n".join(wrap(line) for line in lines))


def hal_catalogue_table() -> None:
    """Every catalogue servo at its nominal voltage: the figures sizing reads (hal's SERVOS and
    MOTORS, parts.toml's mass and armature), a published model's armature or an estimate's."""
    from servodyn.hal.backend import servo_catalogue
    from servodyn.model.modelfile import parts
    print("| servo | model number | gear | V | stall (peak) torque | stall current | no-load speed | mass "
          "| armature (kg m²) | current control |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for kind in ("dynamixel", "can"):
        for name, s in servo_catalogue(kind).items():
            part = parts()[name]
            estimate = "estimate" in part["source"].lower().split("armature", 1)[-1]
            number = getattr(s, "model_number", None)
            print(f"| {name} | {number if number is not None else 'CAN'} | {s.gear_ratio:g}:1 | {s.nominal_voltage:g} "
                  f"| {s.stall_torque:g} N m | {s.stall_current:.2f} A | {s.no_load_speed_rpm:g} rpm "
                  f"| {part['mass'] * 1e3:g} g | {part['armature']:.3g}{' (est.)' if estimate else ''} "
                  f"| {'yes' if s.current_control else '**no**'} |")


# ------------------------------------------------------------------ README: the five-minute tour

def readme_tour() -> dict:
    """The tour's figures: the demo's swing (readme_swing's runs) and `servodyn validate replica
    tennis_forehand --time-scale 1 --fit` (human speed, as the motion is written)."""
    human = validate("replica", "tennis_forehand", "--time-scale", "1", "--fit")
    first = human["violations"][0] if human["violations"] else None
    failing = sum(not row["passed"] for row in human["joints"].values())
    return {**readme_swing(), "verdict": "passes" if human["passed"] else "fails",
            "failing": failing, "first_dof": first["dof"] if first else "none",
            "first_check": first["check"].replace("_", "-") if first else "none",
            "fit": human["fit_time_scale"], "fit_s": human["fit_time_scale"] * human["duration_s"]}


def pwm_figures() -> dict:
    """replica_pwm (forearm and wrist driven by their torque through PWM): the forehand's fitted time
    scale, the peak duty of its PWM joints there, and its forehand with and without feed-forward."""
    checked = validate("replica_pwm", "tennis_forehand", "--time-scale", "2.65", "--fit")
    cfg = config("replica_pwm")
    pwm = [j.dof for j in cfg.joints if j.options.get("drive") == "pwm"]
    duty = {dof: checked["joints"][dof]["checks"]["current"] for dof in pwm}
    worst = max(duty, key=duty.get)
    fed, pd = swing("--config", "replica_pwm"), swing("--config", "replica_pwm", "--no-feedforward")
    return {"fit": checked["fit_time_scale"], "scale": cfg.swing_time_scale, "servo": cfg.joints[-1].servo.name,
            "duty_pct": 100 * duty[worst], "duty_dof": worst,
            "ff_deg": deg(fed["tracking_max_rad"]), "pd_deg": deg(pd["tracking_max_rad"]),
            "gain": pd["tracking_max_rad"] / fed["tracking_max_rad"]}
