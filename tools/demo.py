"""`servodyn demo`: the torque profile of a sample reach of the built-in arm, and a check that
the direct dynamics driven by those torques retrace the motion (paper Fig. 4, open loop)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..control.timing import BANDWIDTH, SMALL_TIME_STEP
from ..control.trajectory import write_columns_csv
from ..model import load_model

# a forward reach and back: arm raised forward and out, elbow bent, forearm pronated, wrist cocked
REACH = {
    "r_shoulder_flexion": 1.4,
    "r_shoulder_abduction": 0.3,
    "r_shoulder_rotation": 0.4,
    "r_elbow_flexion": 1.2,
    "r_forearm_pronation": 0.6,
    "r_wrist_flexion": -0.4,
    "r_wrist_deviation": 0.2,
}
DURATION = 2.0        # s: out and back


def reach_motion(model, duration: float = DURATION, dt: float = SMALL_TIME_STEP):
    """q, qd, qdd of the out-and-back reach q = target sin⁴(π t / duration), sampled every dt:
    smooth, at rest with zero acceleration at both ends."""
    target = np.array([REACH.get(name, 0.5) for name in model.dof_names])
    target = np.clip(target, model.lower, model.upper)
    t = np.arange(0.0, duration + dt / 2, dt)
    w = np.pi / duration
    s, c = np.sin(w * t), np.cos(w * t)
    q = np.outer(s**4, target)
    qd = np.outer(4 * w * s**3 * c, target)
    qdd = np.outer(w**2 * (12 * s**2 * c**2 - 4 * s**4), target)
    return t, q, qd, qdd


def replay(model, t, q, qd, tau, bandwidth: float) -> np.ndarray:
    """Drive the direct dynamics with tau (held over each step) plus a PD whose gains give each
    joint the given bandwidth on its own inertia; the largest joint deviation at every sample."""
    inertia = np.diag(model.mass_matrix(q[0]))
    kp, kd = inertia * bandwidth**2, 2.0 * inertia * bandwidth
    qs, qds = q[0].copy(), qd[0].copy()
    drift = np.zeros(len(t))
    for k in range(len(t) - 1):
        command = tau[k] + kp * (q[k] - qs) + kd * (qd[k] - qds)
        qs, qds = model.step(qs, qds, command, t[k + 1] - t[k], "rk4")
        drift[k + 1] = np.abs(qs - q[k + 1]).max()
    return drift


def _abbreviate(name: str) -> str:
    name = name.removeprefix("r_")
    for long, brief in (("shoulder", "sh"), ("flexion", "flex"),
                        ("abduction", "abd"), ("rotation", "rot"), ("forearm_", ""),
                        ("pronation", "pron"), ("deviation", "dev")):
        name = name.replace(long, brief)
    return name[:10]


def run_demo(model_name: str, out: Path) -> None:
    model = load_model(model_name)
    t, q, qd, qdd = reach_motion(model)
    print(f"servodyn demo: model '{model.name}', {model.nbody} bodies, {model.nq} dofs, "
          f"{model.total_mass:.2f} kg; a {DURATION:.1f} s reach sampled every {SMALL_TIME_STEP * 1e3:g} ms")

    # inverse dynamics of every sample in one batched call
    start = time.perf_counter()
    tau = model.inverse_dynamics(q, qd, qdd)
    elapsed = time.perf_counter() - start
    print(f"inverse dynamics (recursive Newton-Euler, C core): {len(t)} samples in {elapsed * 1e3:.2f} ms "
          f"= {elapsed / len(t) * 1e6:.2f} us per sample\n")

    # the torque profile, a row every 0.2 s
    short = [_abbreviate(name) for name in model.dof_names]
    print("  t (s) " + " ".join(f"{s:>10}" for s in short) + "   [N·m]")
    for k in range(0, len(t), int(round(0.2 / SMALL_TIME_STEP))):
        print(f"  {t[k]:5.2f} " + " ".join(f"{v:10.3f}" for v in tau[k]))
    peak = np.abs(tau).max(axis=0)
    print("  peak  " + " ".join(f"{v:10.3f}" for v in peak))

    # replay by direct dynamics: feed-forward alone, and feed-forward with a light joint PD
    start = time.perf_counter()
    drift_ff = replay(model, t, q, qd, tau, bandwidth=0.0)
    drift_pd = replay(model, t, q, qd, tau, bandwidth=BANDWIDTH)
    elapsed = time.perf_counter() - start
    print(f"\nreplay by direct dynamics (Armstrong-Green + RK4 at {SMALL_TIME_STEP * 1e3:g} ms, "
          f"2 x {len(t) - 1} steps in {elapsed * 1e3:.0f} ms), largest joint deviation from the plan:")
    beyond = np.flatnonzero(drift_ff > np.radians(1.0))
    when = f"past 1 deg at t = {t[beyond[0]]:.2f} s" if len(beyond) else "never past 1 deg"
    print(f"  feed-forward only          {np.degrees(drift_ff.max()):10.4f} deg "
          f"({when}: open loop, the raised arm is unstable and step errors grow)")
    print(f"  feed-forward + PD {BANDWIDTH:g} rad/s {np.degrees(drift_pd.max()):10.4f} deg")

    out.mkdir(parents=True, exist_ok=True)
    write_columns_csv(out / "torques.csv", t, "tau", model.dof_names, tau)
    write_columns_csv(out / "motion.csv", t, "q", model.dof_names, q)
    _plot(out / "torques.png", t, q, tau, model.dof_names, drift_pd)
    print(f"wrote {out / 'torques.csv'}, {out / 'motion.csv'}, {out / 'torques.png'}")


def _plot(path: Path, t, q, tau, names, drift) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True, height_ratios=[2, 2, 1])
    for k, name in enumerate(names):
        axes[0].plot(t, np.degrees(q[:, k]), label=name)
        axes[1].plot(t, tau[:, k], label=name)
    axes[0].set_ylabel("joint angle (deg)")
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].set_ylabel("feed-forward torque (N·m)")
    axes[2].semilogy(t[1:], np.degrees(np.maximum(drift[1:], 1e-12)))
    axes[2].set_ylabel("replay deviation,\nFF + PD (deg)")
    axes[2].set_xlabel("time (s)")
    axes[0].set_title("servodyn demo: inverse dynamics of a reach, replayed by direct dynamics")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
