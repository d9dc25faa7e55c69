"""`make bench`: servodyn's C core timed beside Pinocchio (C++) and MuJoCo (C) in one run, on the
same models and states, then the same calls through Python. Prints the table and writes
out/bench/{results.json,table.md,per_dof.png}.

Absolute times drift on shared machines; the ratios within one run are the figures to read.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import servodyn
from servodyn.model.samples import random_model, serial_chain

ROOT = Path(__file__).resolve().parents[1]
BUILD = ROOT / "build" / "bench"
SOURCES = [ROOT / "tools" / "bench_native" / "bench.cpp", ROOT / "tools" / "bench_native" / "build.sh",
           *sorted((ROOT / "firmware" / "core").rglob("*.[ch]"))]
GOALS = {"rnea": 0.6, "forward": 0.8, "rk4": 0.8}


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
        res = subprocess.run(["bash", str(ROOT / "tools" / "bench_native" / "build.sh"), sys.executable, str(BUILD)],
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


def per_call(fn, count: int, reps: int = 7) -> float:
    """Median over reps of the mean time per call of fn(i) for i < count, in microseconds."""
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        for i in range(count):
            fn(i)
        times.append((time.perf_counter() - start) / count * 1e6)
    return float(np.median(times))


def run_python(name: str, model, data) -> dict:
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

    out = {
        "sd_rnea": per_call(lambda i: model.inverse_dynamics(q[i], qd[i], qdd[i]), n),
        "sd_rnea_batch": _batch_time(lambda: model.inverse_dynamics(q, qd, qdd), len(q)),
        "pin_rnea": per_call(lambda i: pin.rnea(pm, pd, q[i], qd[i], qdd[i]), n),
        "mj_inverse": per_call(mj_inverse, n),
        "sd_forward": per_call(lambda i: model.forward_dynamics(q[i], qd[i], tau[i]), n),
        "sd_forward_batch": _batch_time(lambda: model.forward_dynamics(q, qd, tau), len(q)),
        "pin_aba": per_call(lambda i: pin.aba(pm, pd, q[i], qd[i], tau[i]), n),
        "mj_forward": per_call(mj_forward, n),
    }
    return out


def _batch_time(fn, count: int) -> float:
    times = []
    for _ in range(7):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) / count * 1e6)
    return float(np.median(times))


def table(results: list[dict]) -> str:
    lines = ["| model | dof | RNEA servodyn / Pinocchio / MuJoCo (µs) | ratio to Pinocchio "
             "| direct dynamics servodyn / Pinocchio ABA / MuJoCo (µs) | ratio to Pinocchio "
             "| RK4 step servodyn / Pinocchio / MuJoCo (µs) | ratio to MuJoCo | servodyn ns per dof (RNEA / ABA) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        us, n = r["native"]["us"], r["ndof"]
        lines.append(
            f"| {r['name']} | {n} | {us['sd_rnea']:.2f} / {us['pin_rnea']:.2f} / {us['mj_inverse']:.2f} "
            f"| **{us['sd_rnea'] / us['pin_rnea']:.2f}** "
            f"| {us['sd_forward']:.2f} / {us['pin_aba']:.2f} / {us['mj_forward']:.2f} "
            f"| **{us['sd_forward'] / us['pin_aba']:.2f}** "
            f"| {us['sd_rk4']:.2f} / {us['pin_rk4']:.2f} / {us['mj_step_rk4']:.2f} "
            f"| **{us['sd_rk4'] / us['mj_step_rk4']:.2f}** "
            f"| {us['sd_rnea'] / n * 1e3:.0f} / {us['sd_forward'] / n * 1e3:.0f} |")
    return "\n".join(lines)


def python_table(results: list[dict]) -> str:
    lines = ["| model | dof | RNEA servodyn / batch / Pinocchio / MuJoCo (µs per call) "
             "| direct servodyn / batch / Pinocchio / MuJoCo (µs per call) |", "|---|---|---|---|"]
    for r in results:
        p = r["python"]
        lines.append(f"| {r['name']} | {r['ndof']} | {p['sd_rnea']:.2f} / {p['sd_rnea_batch']:.2f} / "
                     f"{p['pin_rnea']:.2f} / {p['mj_inverse']:.2f} | {p['sd_forward']:.2f} / "
                     f"{p['sd_forward_batch']:.2f} / {p['pin_aba']:.2f} / {p['mj_forward']:.2f} |")
    return "\n".join(lines)


def verdict(results: list[dict]) -> list[str]:
    lines = []
    for key, ref, label in (("rnea", "pin_rnea", "inverse dynamics vs Pinocchio RNEA"),
                            ("forward", "pin_aba", "direct dynamics vs Pinocchio ABA"),
                            ("rk4", "mj_step_rk4", "RK4 step vs MuJoCo mj_step RK4")):
        ratios = {r["name"]: r["native"]["us"][f"sd_{key}"] / r["native"]["us"][ref] for r in results}
        worst = max(ratios, key=ratios.get)
        status = "met" if ratios[worst] <= GOALS[key] else "NOT met"
        lines.append(f"goal {label} <= {GOALS[key]}: {status} (worst {ratios[worst]:.2f} on {worst})")
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
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=1000, help="states per model (default 1000)")
    parser.add_argument("--reps", type=int, default=21, help="timed repetitions (default 21)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    binary = build_binary()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for name, model in models():
        print(f"  {name:<10} {model.nq:>3} dofs ...", end="", flush=True)
        data = states(model, args.states)
        native = run_native(binary, name, model, data, args.reps)
        python = run_python(name, model, data)
        results.append({"name": name, "ndof": model.nq, "nbody": model.nbody, "native": native, "python": python})
        print(f" agreement ok={native['agreement']['ok']}")
    text = "\n".join([
        f"servodyn benchmark, {os.cpu_count()} cpus, {args.states} states per model, median of {args.reps} runs",
        "", "C/C++ in one process (servodyn core, Pinocchio headers, MuJoCo library):", "", table(results),
        "", "Through Python, per call (servodyn batch: N states in one call, per state):", "", python_table(results),
        "", *verdict(results)])
    print("\n" + text)
    (out / "table.md").write_text(text + "\n")
    (out / "results.json").write_text(json.dumps(results, indent=1))
    plot(results, out / "per_dof.png")
    print(f"\nwrote {out / 'table.md'}, {out / 'results.json'}, {out / 'per_dof.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
