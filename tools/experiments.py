"""The paper's three experiments (§4, Figs. 5-8) and the numbers behind the method.

    servodyn experiment pendulum --out DIR   # Fig. 5: free limbs under gravity and a support
    servodyn experiment still --out DIR      # Fig. 6: the upper body held still
    servodyn experiment swing --out DIR      # Figs. 7, 8: the tennis swing under closed-form control
    servodyn experiment numbers --out DIR    # tracking and energy against mode, step ratio, integrator

Each writes CSV, PNG figures and DIR/summary.json, and prints what it measured.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..control import ControlConfig, Controller
from ..control.motion import DEFAULT_MOTION, load_motion
from ..control.timing import SMALL_TIME_STEP, TIME_STEP
from ..control.trajectory import Trajectory, write_columns_csv
from ..model import load_model
from ..report import plots



def _json_safe(value):
    """JSON has no infinity: a diverged run's drift is written as null (its ran_until_s tells)."""
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def _write_summary(out: Path, summary: dict) -> None:
    (out / "summary.json").write_text(json.dumps(_json_safe(summary), indent=2, allow_nan=False) + "\n")
    print(f"wrote {out / 'summary.json'}")


def _say(text: str) -> None:
    print(text, flush=True)


# ---------------------------------------------------------------- pendulum (Fig. 5)

# the start pose: limbs lifted mostly in the sagittal plane, away from the 3-dof joints' locks
# (shoulder and hip abduction +-90 deg)
PENDULUM_POSE = {
    "r_shoulder_flexion": 1.2, "r_shoulder_abduction": 0.2, "r_elbow_flexion": 0.8,
    "l_shoulder_flexion": -0.6, "l_shoulder_abduction": 0.3, "l_elbow_flexion": 0.4,
    "r_hip_flexion": 0.7, "r_knee_flexion": 0.6, "l_hip_flexion": -0.3, "l_hip_abduction": 0.1,
    "r_wrist_flexion": 0.3, "l_ankle_dorsiflexion": 0.2,
}
# the paper frees the limbs ("the motion of arms and legs is like a pendulum because we set all
# the DOF of them free"); the trunk and head are one rigid body on the support
HELD_TRUNK = ("up_torso", "head_and_neck")



def pendulum_setup(ball: bool = True):
    """human15 with a free root and the trunk held rigid, the start pose, and the support: a
    base-frame force equal and opposite to the whole body's weight, applied at the point of the
    trunk where the centre of mass is at the start (paper: "acts on the center of gravity of the
    whole body located at the abdomen"). With ball, the shoulders' and hips' 3-dof joints are
    ball joints: the same physics without the gimbal lock that the limbs otherwise reach."""
    angles = load_model("human15").with_locked(list(HELD_TRUNK)).with_free_root()
    q_angles = angles.neutral_q()
    for name, value in PENDULUM_POSE.items():
        q_angles[angles.q_names.index(name)] = value
    model = angles.with_ball_joints() if ball else angles
    q0 = model.q_from(angles, q_angles)
    masses = np.array([b.mass for b in model.bodies])
    com = masses @ model.com_positions(q0) / masses.sum()
    R, p = model.body_poses(q0)
    point = R[0].T @ (com - p[0])
    force = -masses.sum() * model.gravity
    model.core.set_root_force(force, point)
    return model, q0, masses, force, point


class PendulumEnergy:
    """Kinetic, gravitational and support energy: the support is a constant force at a point
    fixed in the trunk, so it has the potential -F . x_point and E is conserved exactly."""

    def __init__(self, model, masses, force, point):
        self.model, self.masses, self.force, self.point = model, masses, force, point

    def __call__(self, q, qd):
        kinetic, gravity = self.model.energy(q, qd)
        R, p = self.model.body_poses(q)
        support = -float(self.force @ (p[0] + R[0] @ self.point))
        return kinetic, gravity + support

    def com(self, q):
        return self.masses @ self.model.com_positions(q) / self.masses.sum()


def run_pendulum(dt: float, duration: float, integrator: str = "rk4", sample: float = 0.01,
                 ball: bool = True):
    """(times, q samples, energy drift relative to the largest kinetic energy, largest centre of
    mass displacement, the singular-joint events the core counted, the model). A run that
    diverges stops there with an infinite drift."""
    model, q, masses, force, point = pendulum_setup(ball)
    energy = PendulumEnergy(model, masses, force, point)
    qd = np.zeros(model.nv)
    tau = np.zeros(model.nv)
    kin0, pot0 = energy(q, qd)
    e0, com0 = kin0 + pot0, energy.com(q)
    per_sample = int(round(sample / dt))
    times, qs, drift, kinetic_max, com_max = [0.0], [q.copy()], 0.0, 0.0, 0.0
    singular0 = model.core.warnings["singular"]
    for k in range(1, int(round(duration / sample)) + 1):
        try:
            q, qd = model.step(q, qd, tau, dt, integrator, nsteps=per_sample)
        except FloatingPointError:
            drift = float("inf")
            break
        with np.errstate(over="ignore", invalid="ignore"):
            kinetic, potential = energy(q, qd)
        if not np.isfinite(kinetic + potential):
            drift = float("inf")
            break
        drift = max(drift, abs(kinetic + potential - e0))
        kinetic_max = max(kinetic_max, kinetic)
        com_max = max(com_max, float(np.linalg.norm(energy.com(q) - com0)))
        times.append(k * sample)
        qs.append(q.copy())
        if drift > 10 * kinetic_max:      # diverging: stop before the numbers overflow
            drift = float("inf")
            break
    return (np.array(times), np.array(qs), drift / max(kinetic_max, 1e-300), com_max,
            model.core.warnings["singular"] - singular0, model)


def experiment_pendulum(out: Path, small_time_step: float = 1.25e-4, duration: float = 10.0,
                        table: bool = True) -> dict:
    _say(f"pendulum: human15 with a free root, gravity and a support at the centre of mass, limbs "
         f"free (shoulders and hips as ball joints); RK4 at {small_time_step * 1e3:g} ms for {duration:g} s")
    start = time.perf_counter()
    times, qs, drift, com_max, singular, model = run_pendulum(small_time_step, duration)
    _say(f"  energy drift {drift:.2e} of the largest kinetic energy, centre of mass moved "
         f"{com_max:.2e} m ({time.perf_counter() - start:.1f} s)")

    # drift against step size, integrator and the 3-dof joints' coordinates, over the same run
    rows = []
    if table:
        _say("  energy drift over the run, relative to the largest kinetic energy ('div. t': the state")
        _say("  became non-finite at t); 'angles' keeps the 3-dof joints as chains of hinges:")
        _say(f"  {'step (ms)':>10} {'RK4, ball':>12} {'Euler, ball':>12} {'RK4, angles':>12} {'Euler, angles':>14}")
        for dt in (1e-3, 5e-4, 2.5e-4, 1.25e-4):
            row = {"small_time_step_s": dt}
            for ball in (True, False):
                for integrator in ("rk4", "euler"):
                    t_end, _, d, c, s, _ = run_pendulum(dt, duration, integrator, ball=ball)
                    row[f"{integrator}_{'ball' if ball else 'angles'}"] = {
                        "energy_drift_rel": d, "com_displacement_max_m": c, "singular_events": s,
                        "ran_until_s": float(t_end[-1])}
            rows.append(row)
            cells = [_drift_cell(row[k]) for k in ("rk4_ball", "euler_ball", "rk4_angles", "euler_angles")]
            _say(f"  {dt * 1e3:>10g} {cells[0]:>12} {cells[1]:>12} {cells[2]:>12} {cells[3]:>14}")

    out.mkdir(parents=True, exist_ok=True)
    write_columns_csv(out / "pendulum_q.csv", times, "q", model.q_names, qs)
    picks = [int(round(t / 0.01)) for t in np.linspace(0, times[-1], 12)]
    plots.snapshots(out / "pendulum_snapshots.png", model, qs[picks], times[picks], view="front",
                    title="human15 under gravity and a support at the centre of mass (paper Fig. 5)")
    summary = {
        "experiment": "pendulum",
        "model": "human15, free root (down_torso); spine and neck held; every limb dof free, "
                 "shoulders and hips as ball joints",
        "small_time_step_s": small_time_step,
        "duration_s": duration,
        "integrator": "rk4",
        "energy_drift_rel": drift,
        "energy_reference": "largest kinetic energy of the run; E = kinetic + gravity + support potential",
        "com_displacement_max_m": com_max,
        "drift_table": rows,
        "start_pose_rad": PENDULUM_POSE,
        "near_singular_configurations": (
            "With the shoulders and hips as chains of three hinges (the paper's DOF frames) the "
            "tumbling limbs reach abduction near +-90 deg, where the flexion and rotation axes "
            "align: the hinge rates grow without bound as the middle angle nears 90 deg, and "
            "fixed-step RK4 loses the energy or the state there (see the 'angles' columns). As ball "
            "joints (unit quaternions) the same bodies have no such configuration."),
    }
    _write_summary(out, summary)
    return summary


def _drift_cell(entry: dict) -> str:
    if not np.isfinite(entry["energy_drift_rel"]):
        return f"div. {entry['ran_until_s']:.1f}s"
    return f"{entry['energy_drift_rel']:.1e}"


# ---------------------------------------------------------------- still (Fig. 6)

STILL_POSE = {
    "neck_flexion": 0.15, "r_shoulder_flexion": 0.6, "r_shoulder_abduction": 0.3,
    "r_elbow_flexion": 0.9, "l_shoulder_flexion": 0.4, "l_shoulder_abduction": 0.5,
    "l_elbow_flexion": 0.5, "r_wrist_flexion": 0.2, "l_wrist_flexion": -0.2,
}


def run_still(mode: str, duration: float, small_time_step: float = SMALL_TIME_STEP,
              time_step: float = TIME_STEP):
    """The upper body (human15 from up_torso, the thorax held) told to hold STILL_POSE."""
    model = load_model("human15").subtree("up_torso")
    q = model.neutral_q()
    for name, value in STILL_POSE.items():
        q[model.q_names.index(name)] = value
    n = int(round(duration / small_time_step))
    t = np.arange(n + 1) * small_time_step
    hold = Trajectory(t=t, q=np.tile(q, (n + 1, 1)), qd=np.zeros((n + 1, model.nv)),
                      qdd=np.zeros((n + 1, model.nv)), derived=False)
    controller = Controller(model, ControlConfig(mode=mode, small_time_step=small_time_step,
                                                 time_step=time_step), q_start=q)
    return model, q, controller.run(model, hold)


def experiment_still(out: Path, duration: float = 5.0) -> dict:
    _say(f"still: the upper body held at the thorax by closed-form control for {duration:g} s")
    model, q, run = run_still("feedforward_pd", duration)
    drift = float(np.abs(run.error).max())
    _, _, ff = run_still("feedforward", duration)
    ff_error = np.abs(ff.error).max(axis=1)
    ff_drift = float(ff_error.max()) if ff.completed else float("inf")
    tau = model.inverse_dynamics(q, np.zeros(model.nv), np.zeros(model.nv))
    _say(f"  feed-forward + PD: largest drift {drift:.2e} rad; feed-forward alone: {ff_drift:.2e} rad")
    growth = [(float(t), float(e)) for t, e in zip(ff.t[::500], ff_error[::500])]
    for t, e in growth:
        _say(f"    feed-forward alone, t = {t:4.1f} s: drift {e:.2e} rad")
    out.mkdir(parents=True, exist_ok=True)
    plots.weights_and_torques(out / "still_weights_torques.png", model, q, tau,
                              title="upper body held still: weights and joint torques (paper Fig. 6)")
    _drift_plot(out / "still_drift.png", ff.t, ff_error, np.abs(run.error).max(axis=1))
    write_columns_csv(out / "still_torques.csv", np.zeros(1), "tau", model.dof_names, tau[None, :])
    summary = {
        "experiment": "still",
        "model": "human15 from up_torso down, up_torso held",
        "mode": "feedforward_pd",
        "small_time_step_s": SMALL_TIME_STEP,
        "time_step_s": TIME_STEP,
        "duration_s": duration,
        "max_drift_rad": drift,
        "max_drift_ff_only_rad": ff_drift,
        "ff_only_drift_by_time": growth,
        "torques_nm": dict(zip(model.dof_names, map(float, tau))),
        "weights_n": {b.name: b.mass * float(np.linalg.norm(model.gravity)) for b in model.bodies},
        "pose_rad": STILL_POSE,
    }
    _write_summary(out, summary)
    return summary


def _drift_plot(path: Path, t, ff_error, pd_error) -> None:
    plt = plots._pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.semilogy(t, np.maximum(ff_error, 1e-18), label="feed-forward alone")
    ax.semilogy(t, np.maximum(pd_error, 1e-18), label="feed-forward + PD (default)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("largest joint drift (rad)")
    ax.set_title("holding the upper body still: an upright head is an inverted pendulum")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------- swing (Figs. 7, 8)

def run_swing(mode: str = "feedforward_pd", ratio: int = 10, integrator: str = "rk4",
              small_time_step: float = SMALL_TIME_STEP):
    model = load_model("human_arm")
    motion = load_motion(DEFAULT_MOTION, model)
    traj = motion.sample(small_time_step)
    config = ControlConfig(mode=mode, small_time_step=small_time_step,
                           time_step=ratio * small_time_step)
    controller = Controller(model, config, q_start=traj.q[0])
    return model, motion, traj, controller.run(model, traj, integrator=integrator)


def experiment_swing(out: Path) -> dict:
    _say("swing: the tennis forehand on human_arm, closed-form control (feed-forward + PD, "
         f"inverse dynamics every {TIME_STEP * 1e3:g} ms, RK4 at {SMALL_TIME_STEP * 1e3:g} ms)")
    model, motion, traj, run = run_swing()
    rms, worst = run.tracking_rms(), run.tracking_max()
    peak = np.abs(run.tau).max(axis=0)
    _say(f"  {'dof':<24} {'rms (deg)':>10} {'max (deg)':>10} {'peak |tau| (N m)':>17}")
    for name, r, w, p in zip(model.dof_names, rms, worst, peak):
        _say(f"  {name:<24} {np.degrees(r):>10.4f} {np.degrees(w):>10.4f} {p:>17.3f}")
    out.mkdir(parents=True, exist_ok=True)
    write_columns_csv(out / "swing_q_desired.csv", run.t, "q", model.dof_names, run.q_d)
    write_columns_csv(out / "swing_q_measured.csv", run.t, "q", model.dof_names, run.q)
    write_columns_csv(out / "swing_tau.csv", run.t, "tau", model.dof_names, run.tau)
    every = int(round(0.04 / SMALL_TIME_STEP))
    plots.posture_series(out / "swing_postures.png", model, run.q[::every], run.t[::every],
                         title="tennis forehand every 0.04 s (paper Fig. 7)")
    keyframe_marks = {phase: float(t) for phase, t in zip(motion.phases, motion.t) if phase == "contact"}
    shoulder = {n: run.tau[:, k] for k, n in enumerate(model.dof_names) if "shoulder" in n}
    plots.curves(out / "swing_shoulder_torques.png", run.t, shoulder, "torque (N m)",
                 "shoulder torques from inverse dynamics (paper Fig. 8)", keyframe_marks)
    plots.curves(out / "swing_tracking_error.png", run.t,
                 {n: np.degrees(run.error[:, k]) for k, n in enumerate(model.dof_names)},
                 "desired - measured (deg)", "tracking error", keyframe_marks)
    summary = {
        "experiment": "swing",
        "model": "human_arm",
        "motion": motion.name,
        "mode": "feedforward_pd",
        "small_time_step_s": SMALL_TIME_STEP,
        "time_step_s": TIME_STEP,
        "duration_s": motion.duration,
        "tracking_rms_rad": float(np.sqrt(np.mean(run.error**2))),
        "tracking_max_rad": float(np.abs(run.error).max()),
        "tracking_rms_by_dof_rad": dict(zip(model.dof_names, map(float, rms))),
        "tracking_max_by_dof_rad": dict(zip(model.dof_names, map(float, worst))),
        "peak_torque_nm": dict(zip(model.dof_names, map(float, peak))),
        "completed": run.completed,
    }
    _write_summary(out, summary)
    return summary


# ---------------------------------------------------------------- the numbers behind the method

def experiment_numbers(out: Path) -> dict:
    """Swing tracking against control mode and time_step / small_time_step, and RK4 against
    Euler: the paper's two claims as numbers."""
    _say("numbers: the swing's largest tracking error (deg) by mode and time_step / small_time_step")
    modes = ("pd", "feedforward_pd", "computed_torque")
    ratios = (1, 5, 10, 20)
    grid = {}
    _say(f"  {'mode':<16}" + "".join(f"{r:>10}" for r in ratios))
    for mode in modes:
        grid[mode] = {}
        for ratio in ratios:
            *_, run = run_swing(mode, ratio)
            grid[mode][ratio] = {"tracking_max_rad": float(np.abs(run.error).max()),
                                 "tracking_rms_rad": float(np.sqrt(np.mean(run.error**2))),
                                 "completed": run.completed}
        _say(f"  {mode:<16}" + "".join(f"{np.degrees(grid[mode][r]['tracking_max_rad']):>10.3f}" for r in ratios))
    integrators = {}
    for integrator in ("rk4", "euler"):
        *_, run = run_swing("feedforward_pd", 10, integrator)
        _, _, drift, _, _, _ = run_pendulum(1e-3, 10.0, integrator)
        _, _, drift_fine, _, _, _ = run_pendulum(2.5e-4, 10.0, integrator)
        integrators[integrator] = {"swing_tracking_max_rad": float(np.abs(run.error).max()),
                                   "pendulum_energy_drift_rel_1ms": drift,
                                   "pendulum_energy_drift_rel_0.25ms": drift_fine}
    _say("  integrator: swing tracking (max, deg), pendulum energy drift over 10 s at 1 ms and 0.25 ms")
    for name, row in integrators.items():
        _say(f"  {name:<6} {np.degrees(row['swing_tracking_max_rad']):>10.4f} "
             f"{row['pendulum_energy_drift_rel_1ms']:>12.2e} {row['pendulum_energy_drift_rel_0.25ms']:>12.2e}")
    out.mkdir(parents=True, exist_ok=True)
    lines = ["| mode | " + " | ".join(f"ratio {r}" for r in ratios) + " |",
             "|---|" + "---|" * len(ratios)]
    for mode in modes:
        lines.append(f"| {mode} | " + " | ".join(
            f"{np.degrees(grid[mode][r]['tracking_max_rad']):.3f} / {np.degrees(grid[mode][r]['tracking_rms_rad']):.3f}"
            for r in ratios) + " |")
    lines += ["", "| integrator | swing tracking max (deg) | pendulum drift 10 s, 1 ms | pendulum drift 10 s, 0.25 ms |",
              "|---|---|---|---|"]
    for name, row in integrators.items():
        lines.append(f"| {name} | {np.degrees(row['swing_tracking_max_rad']):.4f} | "
                     f"{row['pendulum_energy_drift_rel_1ms']:.2e} | {row['pendulum_energy_drift_rel_0.25ms']:.2e} |")
    (out / "numbers.md").write_text("\n".join(lines) + "\n")
    summary = {"experiment": "numbers", "swing_tracking": grid, "integrators": integrators}
    _write_summary(out, summary)
    print(f"wrote {out / 'numbers.md'}")
    return summary


EXPERIMENTS = {"pendulum": experiment_pendulum, "still": experiment_still, "swing": experiment_swing,
               "numbers": experiment_numbers}
