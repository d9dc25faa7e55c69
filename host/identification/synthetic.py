"""A log made with the core's direct dynamics on a plant whose numbers are known, as the real arm's
are not: for the tests and the benchmark of identification.

The plant is the model with a payload (a point mass at a body's centre of mass), friction per joint
(Coulomb, smoothed over SMOOTH_SPEED so that RK4 meets no step, and viscous), its armature and a
torque-constant scale s (the servo gives s times the torque the configuration's constant says). A
computed-torque PD on the nominal model tracks the motion from the quantised sensors (encoder
4096 counts per turn, velocity 0.229 rpm); the logged current is the command's, quantised to
2.69 mA (Dynamixel X's units)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

ENCODER_STEP = 2 * math.pi / 4096     # rad
VELOCITY_STEP = 0.229 * 2 * math.pi / 60     # rad/s
CURRENT_STEP = 2.69e-3                # A
SMOOTH_SPEED = 1e-3                   # rad/s: the Coulomb friction's tanh width in the plant
TRACKING_HZ = 4.0                     # the PD's bandwidth


@dataclass
class Plant:
    """What the plant has beyond the model (per dof arrays, model dof order)."""
    payload_kg: float = 0.0
    payload_body: str | None = None
    coulomb: np.ndarray = field(default_factory=lambda: np.zeros(0))
    viscous: np.ndarray = field(default_factory=lambda: np.zeros(0))
    armature: np.ndarray | None = None           # default: the model's
    torque_scale: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _quantised(x, step):
    return np.round(np.asarray(x) / step) * step


def simulate_log(model, joints, motion, duration: float, plant: Plant, dt: float = 1e-3,
                 quantise: bool = True) -> dict:
    """t, q, qd, current (and the true torque) of the plant tracking motion(t) -> (q, qd, qdd)."""
    n = model.nv
    truth = model.with_payload(plant.payload_kg, plant.payload_body) if plant.payload_kg else model
    if plant.armature is not None:
        truth = truth.with_armature(dict(zip(model.dof_names, plant.armature)))
    coulomb = plant.coulomb if len(plant.coulomb) else np.zeros(n)
    viscous = plant.viscous if len(plant.viscous) else np.zeros(n)
    scale = plant.torque_scale if len(plant.torque_scale) else np.ones(n)
    per_amp = np.array([j.torque_constant * j.gear_ratio for j in joints])
    steps = int(round(duration / dt))
    t = np.arange(steps + 1) * dt
    q_d, qd_d, qdd_d = motion(t)
    feed = model.inverse_dynamics(q_d, qd_d, qdd_d)
    inertia = np.diag(model.mass_matrix(q_d[0]))
    w = 2 * math.pi * TRACKING_HZ
    kp, kd = inertia * w**2, inertia * 2 * w
    q, qd = q_d[0].copy(), qd_d[0].copy()
    log_q, log_qd, log_i, log_tau = (np.empty((steps + 1, n)) for _ in range(4))
    for k in range(steps + 1):
        qm = _quantised(q, ENCODER_STEP) if quantise else q
        qdm = _quantised(qd, VELOCITY_STEP) if quantise else qd
        command = feed[k] + kp * (q_d[k] - qm) + kd * (qd_d[k] - qdm)
        current = command / per_amp
        current = _quantised(current, CURRENT_STEP) if quantise else current
        tau = scale * current * per_amp
        log_q[k], log_qd[k], log_i[k], log_tau[k] = qm, qdm, current, tau
        if k < steps:
            applied = tau - coulomb * np.tanh(qd / SMOOTH_SPEED) - viscous * qd
            q, qd = truth.step(q, qd, applied, dt)
    return {"t": t, "q": log_q, "qd": log_qd, "current": log_i, "tau_true": log_tau}
