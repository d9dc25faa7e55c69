"""`make bench`, inverse kinematics: the time per drag event of the hand, and from a drag event to
the arm redrawn in `servodyn view`.

- IK per drag event: a drag is a chain of small hand steps (2 mm, along a circle through the
  workspace), each solved from the previous pose (servodyn.model.ik.solve, the closed form), with
  and without the hand's orientation; cold solves (no previous pose) beside them. The reference in
  the same run: pink (Pinocchio's differential IK, a QP per step with daqp) stepped to the same
  target from the same previous pose until it is within 1e-9 m.
- Drag event to redrawn arm: the view's own handler (HandGizmo.solve_to) on the replica's
  forehand, timed in-process from the event to the arm posed (IK and the scene's frames), and to
  the verdict (keyframe, torques, validator, plots). The reference: the same keyframe changed by a
  typed angle (MotionEditor.set_keyframe), which does the same work less the IK and the posing.

Goals (issue 25): IK per drag event ≤ 1 ms median; drag event to redrawn arm ≤ 16 ms (a frame at
60 Hz). Writes out/bench/ik.json and out/bench/ik.md.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .loop import ROOT, publish
from ...model import ik, load_model
from ...view import open_view

GOAL_IK_MS = 1.0
GOAL_REDRAW_MS = 16.0


def drag_targets(arm, q0, steps: int, step_m: float = 0.002):
    """Hand frames along a circle of 2 mm steps through the hand at q0 (the drag of a person)."""
    R0, p0 = arm.hand(q0)
    radius = steps * step_m / (2 * np.pi)
    angles = np.arange(1, steps + 1) * step_m / radius
    offsets = radius * np.stack([np.cos(angles) - 1, np.sin(angles), 0.3 * np.sin(angles)], axis=1)
    return [(R0, p0 + d) for d in offsets]


def time_ik(name: str, steps: int) -> dict:
    model = load_model(name)
    arm = ik.Arm.of(model)
    q0 = np.radians([40.0, 15.0, 10.0, 70.0, 10.0, 5.0, 0.0])
    targets = drag_targets(arm, q0, steps)
    rows = {}
    for label, with_rotation in (("position", False), ("position + orientation", True)):
        q, times, worst = q0, [], 0.0
        for R, p in targets:
            start = time.perf_counter()
            r = ik.solve(model, p, R if with_rotation else None, q_prev=q)
            times.append(time.perf_counter() - start)
            q, worst = r.q, max(worst, r.position_error)
        rows[label] = {"median_ms": 1e3 * float(np.median(times)), "p95_ms": 1e3 * float(np.percentile(times, 95)),
                       "worst_error_m": worst}
    rng = np.random.default_rng(0)
    times = []
    for _ in range(max(steps // 4, 20)):
        R, p = arm.hand(rng.uniform(arm.lower, arm.upper))
        start = time.perf_counter()
        ik.solve(model, p, R)
        times.append(time.perf_counter() - start)
    rows["cold, position + orientation"] = {"median_ms": 1e3 * float(np.median(times)),
                                           "p95_ms": 1e3 * float(np.percentile(times, 95)), "worst_error_m": None}
    rows["pink to 1e-9 m (reference)"] = time_pink(model, arm, q0, targets)
    return rows


def time_pink(model, arm, q0, targets) -> dict:
    try:
        import pink
        import pinocchio as pin
        from pink.tasks import FrameTask
    except ImportError as err:
        return {"median_ms": None, "p95_ms": None, "worst_error_m": None, "skipped": str(err)}
    with tempfile.TemporaryDirectory() as tmp:
        model.to_urdf(Path(tmp) / "arm.urdf")
        pm = pin.buildModelFromUrdf(str(Path(tmp) / "arm.urdf"))
    task = FrameTask(model.body_names[arm.end], position_cost=1.0, orientation_cost=0.0, lm_damping=1e-6)
    q, times, worst = q0.copy(), [], 0.0
    for R, p in targets:
        start = time.perf_counter()
        conf = pink.Configuration(pm, pm.createData(), q)
        task.set_target(pin.SE3(R, p))
        for _ in range(50):
            conf.integrate_inplace(pink.solve_ik(conf, [task], 0.01, solver="daqp"), 0.01)
            if np.linalg.norm(task.compute_error(conf)[:3]) < 1e-9:
                break
        times.append(time.perf_counter() - start)
        q = conf.q.copy()
        worst = max(worst, float(np.linalg.norm(arm.hand(q)[1] - p)))
    return {"median_ms": 1e3 * float(np.median(times)), "p95_ms": 1e3 * float(np.percentile(times, 95)),
            "worst_error_m": worst}


def time_view(events: int) -> dict:
    viewer = open_view("replica", http_port=0, say=lambda *a, **k: None)
    try:
        ed, hand = viewer.editor, viewer.editor.hand
        ed.key.value = 4
        q0 = ed.motion.q[ed.k].copy()
        targets = drag_targets(hand.arm, q0, events)
        for R, p in targets:
            hand.gizmo.position = tuple(p)
            hand._on_drag(SimpleNamespace(phase="update"))
        typed = []
        elbow = viewer.model.dof_names.index("r_elbow_flexion")
        for i in range(events):
            q = ed.motion.q[ed.k].copy()
            q[elbow] += 0.002 * (1 if i % 2 else -1)
            start = time.perf_counter()
            ed.set_keyframe(ed.k, float(ed.motion.t[ed.k]), q)
            typed.append(time.perf_counter() - start)
        return {"events": events, "solves": hand.solves, "refusals": hand.refusals,
                "to_arm_median_ms": 1e3 * float(np.median(hand.arm_s)),
                "to_arm_p95_ms": 1e3 * float(np.percentile(hand.arm_s, 95)),
                "to_verdict_median_ms": 1e3 * float(np.median(hand.handler_s)),
                "to_verdict_p95_ms": 1e3 * float(np.percentile(hand.handler_s, 95)),
                "typed_angle_median_ms": 1e3 * float(np.median(typed))}
    finally:
        viewer.close()


def table(ik_rows: dict, view: dict) -> str:
    def ms(v):
        return "—" if v is None else f"{v:.3f}"
    lines = ["| IK per drag event (ms) | model | median | p95 | worst hand error (m) |", "|---|---|---:|---:|---:|"]
    for name, rows in ik_rows.items():
        for label, r in rows.items():
            err = "—" if r.get("worst_error_m") is None else f"{r['worst_error_m']:.1e}"
            lines.append(f"| {label} | {name} | {ms(r['median_ms'])} | {ms(r['p95_ms'])} | {err} |")
    for name, rows in ik_rows.items():
        ours, ref = rows["position"]["median_ms"], rows["pink to 1e-9 m (reference)"]["median_ms"]
        if ref:
            lines.append(f"\n{name}: pink's time / the closed form's, per drag event (position): {ref / ours:.1f}")
    lines += ["", f"IK goal ≤ {GOAL_IK_MS:g} ms median: "
              + ", ".join(f"{n} {'met' if r['position + orientation']['median_ms'] <= GOAL_IK_MS else 'MISSED'}"
                          for n, r in ik_rows.items()),
              "", "| servodyn view, replica's forehand (ms) | median | p95 |", "|---|---:|---:|",
              f"| drag event → arm redrawn (IK + pose) | {view['to_arm_median_ms']:.2f} | {view['to_arm_p95_ms']:.2f} |",
              f"| drag event → torques and verdict shown | {view['to_verdict_median_ms']:.2f} | "
              f"{view['to_verdict_p95_ms']:.2f} |",
              f"| typed angle → torques and verdict (reference) | {view['typed_angle_median_ms']:.2f} | — |",
              "", f"{view['events']} drag events, {view['solves']} solved, {view['refusals']} refused; "
              f"redraw goal ≤ {GOAL_REDRAW_MS:g} ms: {'met' if view['to_arm_median_ms'] <= GOAL_REDRAW_MS else 'MISSED'}"
              f"; the verdict's share over the typed angle's: "
              f"{view['to_verdict_median_ms'] / view['typed_angle_median_ms']:.2f}"]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m servodyn.tools.bench.ik", description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=400, help="drag events per case (default 400)")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench"), help="output folder")
    args = parser.parse_args(argv)
    print(f"servodyn inverse kinematics: {args.steps} drag events per case, {os.cpu_count()} cpus", flush=True)
    ik_rows = {name: time_ik(name, args.steps) for name in ("human_arm", "replica")}
    view = time_view(max(args.steps // 4, 20))
    publish(Path(args.out), "ik", table(ik_rows, view), {"ik": ik_rows, "view": view})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
