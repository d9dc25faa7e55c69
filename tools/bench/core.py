"""`make bench`: servodyn's C core timed beside Pinocchio (C++) and MuJoCo (C) in one run, on the
same models and states, then the same calls through Python. Prints the table and writes
out/bench/{results.json,table.md,per_dof.png}.

The implementations are timed interleaved: each repetition times every one of them once, one
after the other, so a busy neighbour slows them alike; and in CPU time of the timing thread, so
the milliseconds the scheduler gives a neighbour's build are charged to no one. Absolute times
drift on shared machines; the figures to read are the ratios, taken within each repetition and
reported as their median with the interquartile range.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

import servodyn
from servodyn.control.contact import DEFAULT_GAIN, DEFAULT_LOWPASS
from servodyn.model import MomentumObserver
from servodyn.model.samples import random_model, serial_chain

ROOT = Path(__file__).resolve().parents[2]
BUILD = ROOT / "build" / "bench"
SOURCES = [ROOT / "tools" / "bench" / "native" / "bench.cpp", ROOT / "tools" / "bench" / "native" / "build.sh",
           *sorted((ROOT / "firmware" / "core").rglob("*.[ch]"))]
GOALS = {"rnea": 0.6, "forward": 0.8, "rk4": 0.8}
# the momentum observer's tick (issue 31): at most 3 RNEA calls' time, and 5 µs, on the host
OBSERVER_GOAL_RNEA = 3.0
OBSERVER_GOAL_US = 5.0
# the ratio each goal is judged on: contest, library servodyn is timed against, label
GOAL_RATIOS = (("rnea", "pin", "inverse dynamics vs Pinocchio RNEA"),
               ("forward", "pin", "direct dynamics vs Pinocchio ABA"),
               ("rk4", "mj", "RK4 step vs MuJoCo mj_step RK4"))


def models() -> list[tuple[str, servodyn.Model]]:
    out = [("human_arm", servodyn.load_model("human_arm")), ("human15", servodyn.load_model("human15"))]
    out += [(f"chain{n}", serial_chain(n)) for n in (7, 14, 28, 56, 88)]
    out.append(("tree88", random_model(np.random.default_rng(88), 88, name="tree88")))
    return out


def states(model: servodyn.Model, n: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(1)
    lo, hi = np.maximum(model.lower, -2.5), np.minimum(model.upper, 2.5)
    q = rng.uniform(lo, hi, size=(n, model.nq))
    qd = rng.normal(size=(n, model.nq))
    qdd = rng.normal(size=(n, model.nq))
    tau = model.inverse_dynamics(q, qd, qdd)
    return q, qd, qdd, tau


def build_binary() -> Path:
    binary = BUILD / "bench"
    newest = max(p.stat().st_mtime for p in SOURCES)
    if not binary.exists() or binary.stat().st_mtime < newest:
        print("building the C++ benchmark (Pinocchio headers take about two minutes) ...", flush=True)
        BUILD.mkdir(parents=True, exist_ok=True)
        res = subprocess.run(["bash", str(ROOT / "tools" / "bench" / "native" / "build.sh"), sys.executable, str(BUILD)],
                             capture_output=True, text=True)
        if res.returncode != 0:
            sys.exit(f"bench: the C++ benchmark did not build:\n{res.stderr.strip()}")
    return binary


def run_native(binary: Path, name: str, model, data, reps: int) -> dict:
    q, qd, qdd, tau = data
    (BUILD / f"{name}.bin").write_bytes(model.core.model_bytes())
    with open(BUILD / f"{name}.states", "wb") as f:
        np.array([len(q), model.nq], dtype=np.int32).tofile(f)
        for arr in (q, qd, qdd, tau):
            np.ascontiguousarray(arr, dtype=np.float64).tofile(f)
    res = subprocess.run([str(binary), "--reps", str(reps), "--mjcf", str(BUILD / f"{name}.xml"),
                          str(BUILD / f"{name}.bin"), str(BUILD / f"{name}.states")],
                         capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"bench: {name}: {res.stderr.strip()}")
    if res.stderr.strip():
        print(f"  {name}: {res.stderr.strip()}", file=sys.stderr)
    return json.loads(res.stdout)


def summary(sample: np.ndarray) -> dict:
    """Median, quartiles and range of a sample (bench.cpp reports its ratios the same way)."""
    q1, median, q3 = np.percentile(sample, [25, 50, 75])
    return {"median": float(median), "q1": float(q1), "q3": float(q3),
            "min": float(np.min(sample)), "max": float(np.max(sample))}


def time_interleaved(contests: dict[str, dict[str, tuple[Callable[[], object], int]]],
                     reps: int) -> tuple[dict[str, np.ndarray], float]:
    """µs of CPU time per state of every pass in every repetition, and the share of passes during
    which the thread waited for a core. A pass is (fn, count): fn() evaluates count states. In
    each repetition, every contest runs its passes one after the other, in an order rotated from
    one repetition to the next, so a busy neighbour slows them alike (as bench.cpp does)."""
    passes = [p for contest in contests.values() for p in contest.values()]
    for fn, _ in passes:
        fn()   # warm-up
    us = {name: np.empty(reps) for contest in contests.values() for name in contest}
    descheduled = 0
    for r in range(reps):
        for contest in contests.values():
            names = list(contest)
            for k in range(len(names)):
                name = names[(k + r) % len(names)]
                fn, count = contest[name]
                wall, cpu = time.perf_counter(), time.thread_time()
                fn()
                cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
                descheduled += wall > 1.05 * cpu + 1e-5
                us[name][r] = cpu / count * 1e6
    return us, descheduled / (reps * len(passes))


def each_state(fn: Callable[[int], object], count: int) -> tuple[Callable[[], None], int]:
    """A pass of one call per state."""
    def run():
        for i in range(count):
            fn(i)
    return run, count


def run_python(name: str, model, data, reps: int) -> dict:
    import mujoco
    import pinocchio as pin
    q, qd, qdd, tau = data
    n = min(len(q), 300)
    model.to_urdf(BUILD / f"{name}.urdf")
    pm = pin.buildModelFromUrdf(str(BUILD / f"{name}.urdf"))
    pm.gravity.linear = model.gravity
    pd = pm.createData()
    mm = mujoco.MjModel.from_xml_path(str(BUILD / f"{name}.xml"))
    md = mujoco.MjData(mm)

    def mj_inverse(i):
        md.qpos[:], md.qvel[:], md.qacc[:] = q[i], qd[i], qdd[i]
        mujoco.mj_inverse(mm, md)

    def mj_forward(i):
        md.qpos[:], md.qvel[:], md.qfrc_applied[:] = q[i], qd[i], tau[i]
        mujoco.mj_forward(mm, md)

    us, descheduled = time_interleaved({
        "rnea": {"sd_rnea": each_state(lambda i: model.inverse_dynamics(q[i], qd[i], qdd[i]), n),
                 "sd_rnea_batch": (lambda: model.inverse_dynamics(q, qd, qdd), len(q)),
                 "pin_rnea": each_state(lambda i: pin.rnea(pm, pd, q[i], qd[i], qdd[i]), n),
                 "mj_inverse": each_state(mj_inverse, n)},
        "forward": {"sd_forward": each_state(lambda i: model.forward_dynamics(q[i], qd[i], tau[i]), n),
                    "sd_forward_batch": (lambda: model.forward_dynamics(q, qd, tau), len(q)),
                    "pin_aba": each_state(lambda i: pin.aba(pm, pd, q[i], qd[i], tau[i]), n),
                    "mj_forward": each_state(mj_forward, n)},
    }, reps)
    ratio = {key: {"pin": summary(us[f"sd_{key}"] / us[pin_key]), "mj": summary(us[f"sd_{key}"] / us[mj_key])}
             for key, pin_key, mj_key in (("rnea", "pin_rnea", "mj_inverse"), ("forward", "pin_aba", "mj_forward"))}
    return {"us": {k: float(np.median(v)) for k, v in us.items()},
            "us_per_rep": {k: v.tolist() for k, v in us.items()}, "ratio": ratio, "descheduled": descheduled}


def run_observer(model, data, reps: int) -> dict:
    """The observer's tick (sd_observer_step: one sd_momentum and the filter) and sd_momentum alone,
    timed against sd_rnea, each over the states in one C loop (one call from Python: the same row
    loading for all three), interleaved: µs per state and the ratios to one RNEA."""
    q, qd, qdd, tau = data
    observer = MomentumObserver(model, 1e-3, DEFAULT_GAIN, lowpass=DEFAULT_LOWPASS)
    us, _ = time_interleaved({"observer": {
        "sd_rnea_batch": (lambda: model.inverse_dynamics(q, qd, qdd), len(q)),
        "sd_momentum_batch": (lambda: model.momentum(q, qd), len(q)),
        "sd_observer_run": (lambda: observer.run(q, qd, tau), len(q))}}, reps)
    return {"us": {k: float(np.median(v)) for k, v in us.items()},
            "ratio": {"observer": summary(us["sd_observer_run"] / us["sd_rnea_batch"]),
                      "momentum": summary(us["sd_momentum_batch"] / us["sd_rnea_batch"])}}


def observer_lines(results: list[dict]) -> list[str]:
    """The observer's cost per model and its goal (judged on the models of up to 7 dofs, an arm's)."""
    lines = ["The momentum observer's tick (sd_observer_step) and sd_momentum, per state, in RNEA calls "
             "(median, interquartile range) and µs:", ""]
    for r in results:
        o = r["observer"]
        lines.append(f"  {r['name']:<10} {r['ndof']:>3} dofs: observer {ratio_text(o['ratio']['observer'])} RNEA, "
                     f"{o['us']['sd_observer_run']:.2f} µs; momentum {ratio_text(o['ratio']['momentum'])} RNEA")
    arms = [r for r in results if r["ndof"] <= 7]
    worst = max(arms, key=lambda r: r["observer"]["ratio"]["observer"]["median"])
    ratio, us = worst["observer"]["ratio"]["observer"]["median"], worst["observer"]["us"]["sd_observer_run"]
    met = ratio <= OBSERVER_GOAL_RNEA and us <= OBSERVER_GOAL_US
    lines.append(f"goal observer tick <= {OBSERVER_GOAL_RNEA:g} RNEA and <= {OBSERVER_GOAL_US:g} µs on an arm: "
                 f"{'met' if met else 'NOT met'} ({ratio:.2f} RNEA, {us:.2f} µs on {worst['name']})")
    return lines


def ratio_text(s: dict, bold: bool = False) -> str:
    """A ratio's median with its interquartile range: 0.47 (0.46–0.48)."""
    median = f"**{s['median']:.2f}**" if bold else f"{s['median']:.2f}"
    return f"{median} ({s['q1']:.2f}–{s['q3']:.2f})"


def quiet_text(result: dict, key: str, ref: str) -> str:
    """The median ratio over the quiet repetitions (bench.cpp's quiet_repetitions)."""
    return f"quiet {result['native']['ratio_quiet'][key][ref]['median']:.2f}"


def table(results: list[dict]) -> str:
    lines = ["| model | dof | RNEA servodyn / Pinocchio / MuJoCo (µs) | ratio to Pinocchio (IQR) "
             "| direct dynamics servodyn / Pinocchio ABA / MuJoCo (µs) | ratio to Pinocchio (IQR) "
             "| RK4 step servodyn / Pinocchio / MuJoCo (µs) | ratio to MuJoCo (IQR) "
             "| servodyn ns per dof (RNEA / ABA) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        us, ratio, n = r["native"]["us"], r["native"]["ratio"], r["ndof"]
        lines.append(
            f"| {r['name']} | {n} | {us['sd_rnea']:.2f} / {us['pin_rnea']:.2f} / {us['mj_inverse']:.2f} "
            f"| {ratio_text(ratio['rnea']['pin'], bold=True)}, {quiet_text(r, 'rnea', 'pin')} "
            f"| {us['sd_forward']:.2f} / {us['pin_aba']:.2f} / {us['mj_forward']:.2f} "
            f"| {ratio_text(ratio['forward']['pin'], bold=True)}, {quiet_text(r, 'forward', 'pin')} "
            f"| {us['sd_rk4']:.2f} / {us['pin_rk4']:.2f} / {us['mj_step_rk4']:.2f} "
            f"| {ratio_text(ratio['rk4']['mj'], bold=True)}, {quiet_text(r, 'rk4', 'mj')} "
            f"| {us['sd_rnea'] / n * 1e3:.0f} / {us['sd_forward'] / n * 1e3:.0f} |")
    return "\n".join(lines)


def python_table(results: list[dict]) -> str:
    lines = ["| model | dof | RNEA servodyn / batch / Pinocchio / MuJoCo (µs per call) | ratio to Pinocchio (IQR) "
             "| direct servodyn / batch / Pinocchio / MuJoCo (µs per call) | ratio to Pinocchio (IQR) |",
             "|---|---|---|---|---|---|"]
    for r in results:
        p, ratio = r["python"]["us"], r["python"]["ratio"]
        lines.append(f"| {r['name']} | {r['ndof']} | {p['sd_rnea']:.2f} / {p['sd_rnea_batch']:.2f} / "
                     f"{p['pin_rnea']:.2f} / {p['mj_inverse']:.2f} | {ratio_text(ratio['rnea']['pin'])} "
                     f"| {p['sd_forward']:.2f} / {p['sd_forward_batch']:.2f} / {p['pin_aba']:.2f} / "
                     f"{p['mj_forward']:.2f} | {ratio_text(ratio['forward']['pin'])} |")
    return "\n".join(lines)


def verdict(results: list[dict]) -> list[str]:
    lines = []
    for key, ref, label in GOAL_RATIOS:
        ratios = {r["name"]: r["native"]["ratio"][key][ref] for r in results}
        worst = max(ratios, key=lambda name: ratios[name]["median"])
        status = "met" if ratios[worst]["median"] <= GOALS[key] else "NOT met"
        lines.append(f"goal {label} <= {GOALS[key]}: {status} (worst {ratio_text(ratios[worst])} on {worst})")
    quiet = []
    for key, ref, label in GOAL_RATIOS:
        ratios = {r["name"]: r["native"]["ratio_quiet"][key][ref]["median"] for r in results}
        worst = max(ratios, key=ratios.get)
        quiet.append(f"{label.split(' vs ')[0]} {ratios[worst]:.2f} on {worst}")
    reps = [r["native"]["quiet_reps"] for r in results]
    lines.append(f"over the quiet repetitions only ({min(reps)}-{max(reps)} per model), the worst are: "
                 + "; ".join(quiet))
    spreads = {(r["name"], label): (s["q3"] - s["q1"]) / s["median"] for r in results
               for key, ref, label in GOAL_RATIOS for s in [r["native"]["ratio"][key][ref]]}
    name, label = max(spreads, key=spreads.get)
    lines.append(f"widest interquartile range of these ratios: {spreads[name, label] * 100:.1f} % of the median "
                 f"({label.split(' vs ')[0]} on {name})")
    waited = [r["native"]["descheduled"] * 100 for r in results]
    lines.append(f"timed passes during which the thread waited for a core: {min(waited):.0f}-{max(waited):.0f} % "
                 "per model (CPU time leaves the wait out)")
    chains = [r for r in results if r["name"].startswith("chain")]
    per_dof = [r["native"]["us"]["sd_rnea"] / r["ndof"] for r in chains]
    lines.append(f"RNEA time per dof on chains 7..88: {min(per_dof) * 1e3:.0f}-{max(per_dof) * 1e3:.0f} ns "
                 f"(spread {max(per_dof) / min(per_dof):.2f}x)")
    return lines


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    chains = [r for r in results if r["name"].startswith("chain")]
    n = [r["ndof"] for r in chains]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, label, style in (("sd_rnea", "servodyn RNEA", "-o"), ("pin_rnea", "Pinocchio RNEA", "--o"),
                              ("sd_forward", "servodyn direct", "-s"), ("pin_aba", "Pinocchio ABA", "--s"),
                              ("mj_forward", "MuJoCo mj_forward", ":^")):
        ax.plot(n, [r["native"]["us"][key] / r["ndof"] * 1e3 for r in chains], style, label=label)
    ax.set_xlabel("dofs of the serial chain")
    ax.set_ylabel("ns per dof")
    ax.set_title("time per dof (flat = O(n))")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.core", description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=1000, help="states per model (default 1000)")
    parser.add_argument("--reps", type=int, default=31,
                        help="interleaved timed repetitions, in C++ and in Python (default 31)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    binary = build_binary()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    print(f"timing {args.reps} interleaved repetitions per model; servodyn's time over the others', "
          "median (interquartile range):", flush=True)
    for name, model in models():
        print(f"  {name:<10} {model.nq:>3} dofs ...", end="", flush=True)
        data = states(model, args.states)
        native = run_native(binary, name, model, data, args.reps)
        ok = "ok" if native["agreement"]["ok"] else "NOT ok"
        ratio = native["ratio"]
        print(f" agreement {ok}; RNEA/Pinocchio {ratio_text(ratio['rnea']['pin'])}, "
              f"direct/ABA {ratio_text(ratio['forward']['pin'])}, RK4/MuJoCo {ratio_text(ratio['rk4']['mj'])} "
              f"({native['quiet_reps']} quiet); Python ...", end="", flush=True)
        python = run_python(name, model, data, args.reps)
        observer = run_observer(model, data, args.reps)
        results.append({"name": name, "ndof": model.nq, "nbody": model.nbody, "native": native, "python": python,
                        "observer": observer})
        print(f" done; {native['descheduled'] * 100:.0f} % of passes waited for a core", flush=True)
    text = "\n".join([
        f"servodyn benchmark, {os.cpu_count()} cpus, {args.states} states per model, {args.reps} interleaved "
        "repetitions: CPU times are medians, ratios the medians of the per-repetition ratios "
        "(interquartile range), and over the quiet repetitions only (total time within 10 % of the fastest)",
        "", "C/C++ in one process (servodyn core, Pinocchio headers, MuJoCo library):", "", table(results),
        "", "Through Python, per call (servodyn batch: N states in one call, per state):", "", python_table(results),
        "", *verdict(results), "", *observer_lines(results)])
    print("\n" + text)
    (out / "table.md").write_text(text + "\n")
    (out / "results.json").write_text(json.dumps(results, indent=1))
    plot(results, out / "per_dof.png")
    print(f"\nwrote {out / 'table.md'}, {out / 'results.json'}, {out / 'per_dof.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
