"""Least squares on the observation matrix of one or more logs: friction, armature, a payload (or
the arm's base parameters) and a torque-constant scale per joint.

Per sample k and joint j (rows where the joint moves faster than STILL_SPEED, so that the sign of
its Coulomb friction is known; notes/identification.md):

    s_j·τ_meas,j = Y_j·(π_model + δπ) + [known payload]·Y_j,b·π_known + I_a,j·q̈_j + F_c,j·sign(q̇_j) + F_v,j·q̇_j

- τ_meas = current × torque_constant × gear_ratio, the configuration's numbers (`measured_torque`);
- δπ: the payload's 10 parameters at body b (default), or with `arm=True` every body's π itself
  (π_model then drops out) — reduced to base parameters: the inertial columns that the friction and
  armature columns leave independent, by QR with column pivoting on the regressor at random states
  (Gautier 1991), the others regrouped into them;
- s_j, the torque-constant scale, only when one log (`loaded`, by default the last) carries a known
  payload π_known (a point mass at body b's own centre of mass, where `validate --payload` puts it):
  current and inertia alone leave that scale free (Gautier & Briot 2011). The scale comes from the
  difference between the logs with and without it, so the same samples given twice are refused, and
  so are roles that make the scales negative (the mass put on a log that carried less);
- ordinary least squares, then each joint's rows weighted by 1/σ_j, σ_j from its OLS residual;
  Cov = σ̂²(AᵀWA)⁻¹. A parameter whose standard error exceeds REL_SIGMA_MAX of its value is reported
  as not determined, with the figures, never as a number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ..errors import ServodynError
from .signals import Prepared

REL_SIGMA_MAX = 0.3        # a parameter with a larger relative standard error is "not determined"
STILL_SPEED = 0.1          # rad/s, about four of a Dynamixel's velocity quanta (0.024 rad/s): rows of
                           # slower joints are left out, the sign of their friction being unknown
STILL_RANGE = 0.01         # rad: a joint whose filtered q spans less never moved
EACH_WAY_S = 1.0          # s a joint must move each way, faster than STILL_SPEED, for its friction: one
                           # way only, a Coulomb friction is a constant that gravity's columns absorb
MOVING_S = 2.0            # s a joint must move in all for its armature and torque-constant scale (a
                           # heating run's one move of a second or two identified armatures 30 % off
                           # with standard errors of 6 %: few, smooth, correlated samples)
BASE_TOL = 1e-6            # |R_ii| / |R_00| under which a column depends on the ones before it
STRUCTURE_SAMPLES = 200    # random states for the structural rank (Gautier's numeric base parameters)
INERTIAL = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_yy", "I_xz", "I_yz", "I_zz")
JOINT_KEYS = ("friction_coulomb_nm", "friction_viscous_nm_s", "armature_kg_m2", "torque_constant_scale")


class IdentificationError(ServodynError, ValueError):
    """Logs that identify nothing (no joint moves, no current); the message is one line."""


@dataclass
class Parameter:
    """An estimate and its standard error; value None when the data cannot determine it (`note` says why);
    `bound` the worst case of errors that are not noise (a temperature's whole degrees), where known."""
    value: float | None
    std: float | None
    note: str = ""
    bound: float | None = None

    @property
    def determined(self) -> bool:
        return self.value is not None

    def as_json(self) -> dict:
        out = {"value": self.value, "std": self.std}
        if self.note:
            out["note"] = self.note
        if self.bound is not None:
            out["bound"] = self.bound
        return out


def _judged(value: float, std: float, unit: str, physical: bool = False) -> Parameter:
    """The estimate, or not determined when its standard error is above REL_SIGMA_MAX of it, or
    (`physical`: a friction, an armature, a torque constant) when it comes out negative: no joint has
    one, so the model misses something there and the number is not the joint's."""
    if not (math.isfinite(value) and math.isfinite(std)):
        return Parameter(None, None, "not determined: the data leave it free")
    if physical and value < 0:
        return Parameter(None, None, f"not determined: fitted {value:.4g} ± {std:.2g} {unit}, negative, which no "
                                     f"joint has: the model misses something at this joint (its torque constant? "
                                     f"a second log with --known-payload identifies it)")
    if std > REL_SIGMA_MAX * abs(value):
        return Parameter(None, None, f"not determined: {value:.4g} ± {std:.2g} {unit}, a standard error above "
                                     f"{REL_SIGMA_MAX:.0%} of the value")
    return Parameter(float(value), float(std))


@dataclass
class Estimate:
    """What the logs determine, and how well the model then fits them."""
    dof_names: tuple
    joints: dict                      # dof -> {key of JOINT_KEYS: Parameter}
    payload: dict | None              # body, mass_kg, com_m (Parameters; com in the body's user frame)
    base: list                        # (name, Parameter) of the inertial base parameters (arm=True)
    residual_rms_nm: dict             # dof -> N m over the rows used
    condition_number: float           # of the column-scaled, weighted observation matrix
    rows: int                         # equations used
    notes: list = field(default_factory=list)     # one line each: what the logs could not identify
    fits: list = field(default_factory=list)      # per log: (t, measured τ, predicted τ), for the plot


def measured_torque(current, joints) -> np.ndarray:
    """Joint torque (N m) of a logged motor current: current × torque_constant × gear_ratio, as the
    HAL converts (the log's current is already signed as the joint: positive = positive torque)."""
    per_amp = np.array([j.torque_constant * j.gear_ratio for j in joints])
    return np.asarray(current, dtype=float) * per_amp


def _point_mass(mass: float, c: np.ndarray) -> np.ndarray:
    """The 10 parameters of a point mass at c: m, m c, m(|c|² 1 − c c') about the origin."""
    I = mass * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([mass, *(mass * c), I[0, 0], I[0, 1], I[1, 1], I[0, 2], I[1, 2], I[2, 2]])


def _gram_condition(A: np.ndarray) -> float:
    """cond(A) from the eigenvalues of A'A: a small symmetric problem however tall A is (a
    threaded LAPACK on a tall matrix is slow on a busy machine)."""
    eig = np.linalg.eigvalsh(A.T @ A)
    return float(np.sqrt(eig[-1] / eig[0])) if eig[0] > 0 else math.inf


def _solve(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares by the normal equations, for columns already scaled to unit norm (their
    condition, squared, stays far from double precision's limit here)."""
    return np.linalg.pinv(A.T @ A, hermitian=True) @ (A.T @ y)


def _base_columns(model, inertial: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which inertial columns are base parameters once each joint's armature and friction columns
    are in, and the regrouping K (β = π_base + K·π_rest), from the regressor at random states."""
    n = model.nv
    lo, hi = np.maximum(model.lower, -np.pi), np.minimum(model.upper, np.pi)
    q = rng.uniform(lo, hi, size=(STRUCTURE_SAMPLES, n))
    qd, qdd = rng.normal(size=(2, STRUCTURE_SAMPLES, n))
    Y = model.regressor(q, qd, qdd)[:, :, inertial].reshape(-1, len(inertial))
    eye = np.eye(n)
    joint = np.concatenate([(qdd[:, :, None] * eye).reshape(-1, n), (qd[:, :, None] * eye).reshape(-1, n),
                            (np.sign(qd)[:, :, None] * eye).reshape(-1, n)], axis=1)
    # the inertial columns with what the joint columns explain taken out, scaled to unit norm
    rest = Y - joint @ _solve(joint, Y)
    scale = np.linalg.norm(Y, axis=0)
    scale[scale == 0] = 1.0
    rest = rest / scale
    # QR with column pivoting of any B with B'B = rest'rest gives rest's own R and pivots: B
    # the Gram matrix's square root, small and square
    G = rest.T @ rest
    eig, V = np.linalg.eigh(G)
    B = (V * np.sqrt(np.maximum(eig, 0))) @ V.T
    _, R, piv = scipy.linalg.qr(B, mode="economic", pivoting=True)
    diag = np.abs(np.diag(R))
    rank = int(np.sum(diag > BASE_TOL * max(diag[0], 1e-300))) if len(diag) else 0
    base, dropped = np.sort(piv[:rank]), np.sort(piv[rank:])
    # regrouping: the dropped columns as combinations of the base ones, rest_d = rest_b K
    K = np.linalg.solve(G[np.ix_(base, base)], G[np.ix_(base, dropped)]) if len(dropped) else np.zeros((rank, 0))
    # back to the parameters' own units
    K = K * scale[dropped][None, :] / scale[base][:, None]
    return base, dropped, K


def identify(model, joints, logs: list[Prepared], payload_body: str | None = None, known_payload: float = 0.0,
             arm: bool = False, names: list[str] | None = None, seed: int = 0, loaded: int | None = None) -> Estimate:
    """Estimate friction, armature, the payload at `payload_body` (default the last body) or with
    `arm` the arm's base parameters, and, when `known_payload` kg rode on that body's centre of mass
    in log `loaded` (an index into `logs`; default the last), a torque-constant scale per joint.
    `joints`: the configuration's JointConfigs in model dof order (the torque columns' meaning);
    logs already `prepare`d."""
    n, nb = model.nv, model.nbody
    names = names or [f"log {k + 1}" for k in range(len(logs))]
    for k, later in ((k, m) for m in range(len(logs)) for k in range(m)):
        if _same_samples(logs[k], logs[later]):
            raise IdentificationError(f"{names[k]} and {names[later]} hold the same samples: one log given twice "
                                      "adds no information (and with a known payload nothing tells the log that "
                                      "carried it from the one without it)")
    body_name = payload_body or model.body_names[-1]
    if body_name not in model.body_names:
        raise IdentificationError(f"no body '{body_name}' in model '{model.name}' ({', '.join(model.body_names)})")
    b = model.body_names.index(body_name)
    if not (math.isfinite(known_payload) and known_payload >= 0):
        raise IdentificationError(f"a known payload must be a finite mass >= 0 kg, got {known_payload:g}")
    scaled = known_payload > 0
    if scaled and len(logs) < 2:
        raise IdentificationError("a known payload needs two logs or more: the last one with the known mass, "
                                  "the others without it")
    loaded = len(logs) - 1 if loaded is None else loaded
    if not 0 <= loaded < len(logs):
        raise IdentificationError(f"the log carrying the known payload is number {loaded + 1}, of {len(logs)} logs")
    notes = []
    if not scaled:
        notes.append("torque constants taken as configured (no --known-payload log): where one is off, that "
                     "joint's friction and armature and the payload absorb it; a second log with a known mass "
                     "added identifies each joint's scale")

    # joints that never move in any log: their columns are left out, their numbers not determined
    moving = np.zeros(n, dtype=bool)
    for log in logs:
        moving |= np.ptp(log.q, axis=0) > STILL_RANGE
    if not moving.any():
        raise IdentificationError("no joint moves in the logs: nothing to identify (play an excitation: "
                                  "servodyn excite, then servodyn swing --motion)")
    for j in np.flatnonzero(~moving):
        notes.append(f"joint {model.dof_names[j]} never moves in the logs: its friction, armature and torque "
                     "constant are not determined")

    inertial = np.arange(10 * nb) if arm else np.arange(10 * b, 10 * b + 10)
    base, dropped, K = _base_columns(model, inertial, np.random.default_rng(seed))
    pi_model = model.inertial_parameters()
    pi_known = _point_mass(known_payload, pi_model[10 * b + 1:10 * b + 4] / pi_model[10 * b]) if scaled else None

    # the observation matrix: per log, rows (sample, joint) where the joint moves
    live = np.flatnonzero(moving)
    cols = ([("armature_kg_m2", j) for j in live] + [("friction_viscous_nm_s", j) for j in live]
            + [("friction_coulomb_nm", j) for j in live] + ([("torque_constant_scale", j) for j in live] if scaled else [])
            + [("inertial", int(inertial[c])) for c in base])
    blocks, targets, row_joint, fits_in = [], [], [], []
    forward, backward = np.zeros(n), np.zeros(n)      # s each joint moves each way, in the rows used
    for k, log in enumerate(logs):
        m = len(log.t)
        Y = model.regressor(log.q, log.qd, log.qdd)
        known = Y[:, :, 10 * b:10 * b + 10] @ pi_known if scaled and k == loaded else np.zeros((m, n))
        fixed = np.zeros((m, n)) if arm else Y @ pi_model
        A = np.zeros((m, n, len(cols)))
        for c, (what, j) in enumerate(cols):
            if what == "armature_kg_m2":
                A[:, j, c] = log.qdd[:, j]
            elif what == "friction_viscous_nm_s":
                A[:, j, c] = log.qd[:, j]
            elif what == "friction_coulomb_nm":
                A[:, j, c] = log.sign[:, j]
            elif what == "torque_constant_scale":
                A[:, j, c] = -log.tau[:, j]
            else:
                A[:, :, c] = Y[:, :, j]
        # with a scale the measured torque is a column; without, it is the target
        y = -(fixed + known) if scaled else log.tau - fixed - known
        use = (np.abs(log.qd) > STILL_SPEED) & moving
        dt = float(np.median(np.diff(log.t))) if m > 1 else 0.0
        forward += dt * np.sum(use & (log.qd > 0), axis=0)
        backward += dt * np.sum(use & (log.qd < 0), axis=0)
        blocks.append(A[use])
        targets.append(y[use])
        row_joint.append(np.nonzero(use)[1])
        fits_in.append((log, A, y, fixed + known))
    A, y, row_joint = np.concatenate(blocks), np.concatenate(targets), np.concatenate(row_joint)
    if len(y) <= len(cols):
        raise IdentificationError(f"{len(y)} usable samples for {len(cols)} unknowns: the logs are too short or "
                                  f"too slow (joints faster than {STILL_SPEED} rad/s count)")

    # ordinary, then weighted least squares on scaled columns
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    x = _solve(As, y)
    res = y - As @ x
    sigma = np.ones(n)
    for j in live:
        r = res[row_joint == j]
        sigma[j] = max(float(np.sqrt(np.mean(r**2))), 1e-12)
    w = 1.0 / sigma[row_joint]
    Aw = As * w[:, None]
    x = _solve(Aw, y * w)
    resw = (y - As @ x) * w
    s2 = float(resw @ resw) / max(len(y) - len(cols), 1)
    cov = s2 * np.linalg.pinv(Aw.T @ Aw, hermitian=True)
    theta, std = x / scale, np.sqrt(np.maximum(np.diag(cov), 0)) / scale
    condition = _gram_condition(Aw)

    # per joint numbers
    got = {col: (theta[c], std[c]) for c, col in enumerate(cols)}
    if scaled:
        _check_roles(got, live, forward, backward, known_payload, names[loaded])
    units = {"armature_kg_m2": "kg m²", "friction_viscous_nm_s": "N m s", "friction_coulomb_nm": "N m",
             "torque_constant_scale": ""}
    out_joints = {}
    for j, dof in enumerate(model.dof_names):
        entry = {}
        for key in JOINT_KEYS:
            short = _too_little_motion(key, forward[j], backward[j])
            if (key, j) in got and short:
                entry[key] = Parameter(None, None, short)
            elif (key, j) in got:
                entry[key] = _judged(*got[(key, j)], units[key], physical=True)
            elif key == "torque_constant_scale" and moving[j]:
                entry[key] = Parameter(None, None, "not determined: needs a second log with a known payload "
                                                   "(--known-payload)")
            else:
                entry[key] = Parameter(None, None, "not determined: the joint never moves")
        out_joints[dof] = entry

    # the inertial part: δπ on the columns, regrouped base parameters
    delta = np.zeros(10 * nb)
    d_std = np.full(10 * nb, np.nan)
    for c, (what, i) in enumerate(cols):
        if what == "inertial":
            delta[i], d_std[i] = theta[c], std[c]
    payload, base_out = None, []
    if arm:
        for c_local in base:
            i = int(inertial[c_local])
            grouped = [f"{K[list(base).index(c_local), r]:+.3g}·{_label(model, int(inertial[d]))}"
                       for r, d in enumerate(dropped) if abs(K[list(base).index(c_local), r]) > 1e-9]
            name = _label(model, i) + (" " + " ".join(grouped) if grouped else "")
            base_out.append((name, _judged(delta[i], d_std[i], "")))
    else:
        payload = _payload(model, b, base, dropped, K, delta, d_std, inertial, cov, cols, scale)

    # residuals (in measured torque) and the fits for the plot
    residual = {}
    fits = []
    s = np.ones(n)
    if scaled:
        for j in live:
            s[j] = theta[cols.index(("torque_constant_scale", j))]
    sums, counts = np.zeros(n), np.zeros(n)
    x_model = theta.copy()
    for c, (what, j) in enumerate(cols):
        if what == "torque_constant_scale":
            x_model[c] = 0.0
    for (log, A_full, _, offset), name in zip(fits_in, names):
        # the predicted true torque, then as the current would read it: / s
        model_tau = (offset + A_full @ x_model) if scaled else (offset + A_full @ theta)
        predicted = model_tau / s
        use = (np.abs(log.qd) > STILL_SPEED) & moving
        err = np.where(use, log.tau - predicted, 0.0)
        sums += np.sum(err**2, axis=0)
        counts += np.sum(use, axis=0)
        fits.append((name, log.t, log.tau, predicted))
    for j, dof in enumerate(model.dof_names):
        residual[dof] = float(np.sqrt(sums[j] / counts[j])) if counts[j] else None
    return Estimate(tuple(model.dof_names), out_joints, payload, base_out, residual, condition, len(y), notes, fits)


def _same_samples(a: Prepared, b: Prepared) -> bool:
    return a.q.shape == b.q.shape and np.array_equal(a.q, b.q) and np.array_equal(a.tau, b.tau)


def _check_roles(got: dict, live, forward, backward, known_payload: float, name: str) -> None:
    """IdentificationError when the torque-constant scales come out negative on most joints that
    moved enough for one: the measured torque then says the log given the known payload carried less
    than the others, not more (s·(τ_with − τ_without) = the payload's torque fits with s < 0)."""
    scales = [got[("torque_constant_scale", j)][0] for j in live
              if not _too_little_motion("torque_constant_scale", forward[j], backward[j])]
    negative = [s for s in scales if s < 0]
    if scales and 2 * len(negative) > len(scales):
        raise IdentificationError(f"with the known {known_payload:g} kg on {name} the torque-constant scales come "
                                  f"out negative on {len(negative)} of {len(scales)} joints ({min(negative):.2f} to "
                                  f"{max(negative):.2f}), as if that log carried less than the others, not more: "
                                  "which log carried the payload?")


def _too_little_motion(key: str, forward: float, backward: float) -> str:
    """Why a joint moved too little in the logs for `key`, or "" when it moved enough."""
    moved = f"the joint moves {forward:.1f} s one way and {backward:.1f} s the other faster than {STILL_SPEED:g} rad/s"
    if key in ("friction_coulomb_nm", "friction_viscous_nm_s") and min(forward, backward) < EACH_WAY_S:
        return f"not determined: {moved}; friction needs {EACH_WAY_S:g} s each way (servodyn excite)"
    if key in ("armature_kg_m2", "torque_constant_scale") and forward + backward < MOVING_S:
        return f"not determined: {moved}; needs {MOVING_S:g} s in all (servodyn excite)"
    return ""


def _label(model, i: int) -> str:
    return f"{INERTIAL[i % 10]}[{model.body_names[i // 10]}]"


def _payload(model, b, base, dropped, K, delta, d_std, inertial, cov, cols, scale) -> dict:
    """Mass and centre of mass (the body's user frame) of δπ at body b, when m and m·c are base
    parameters of their own (nothing regrouped into them) and the data determine them."""
    name = model.body_names[b]
    local = {int(inertial[c]) - 10 * b: k for k, c in enumerate(base)}
    free = [p for p in range(4) if p not in local or (len(dropped) and np.any(np.abs(K[local[p]]) > 1e-9))]
    if free:
        why = f"not determined: {', '.join(INERTIAL[p] for p in free)} of {name} regroup with other parameters"
        return {"body": name, "mass_kg": Parameter(None, None, why), "com_m": [Parameter(None, None, why)] * 3}
    m, m_std = delta[10 * b], d_std[10 * b]
    mass = _judged(m, m_std, "kg")
    if mass.determined and m < 0:
        mass = Parameter(None, None, f"not determined: fitted {m:.4g} ± {m_std:.2g} kg, a mass below zero, which no "
                                     f"payload has (is the model's {name} heavier than the arm's? --arm fits every "
                                     "body)")
    if not mass.determined:
        return {"body": name, "mass_kg": mass,
                "com_m": [Parameter(None, None, "not determined: the payload's mass is not")] * 3}
    # c = h / m in the core frame, its covariance by first order, then turned to the user frame
    index = [cols.index(("inertial", 10 * b + p)) for p in range(4)]
    C = cov[np.ix_(index, index)] / np.outer(scale[index], scale[index])
    h = delta[10 * b + 1:10 * b + 4]
    J = np.zeros((3, 4))
    J[:, 0] = -h / m**2
    J[:, 1:] = np.eye(3) / m
    F = model.frame_rot[b]
    com = F @ (h / m)
    com_cov = F @ J @ C @ J.T @ F.T
    com_std = np.sqrt(np.maximum(np.diag(com_cov), 0))
    # a coordinate near zero has a large relative error yet is known: judged on the distance's scale
    reach = max(float(np.linalg.norm(com)), 1e-6)
    coords = [Parameter(float(v), float(e)) if e <= REL_SIGMA_MAX * reach else
              Parameter(None, None, f"not determined: {v:.4g} ± {e:.2g} m") for v, e in zip(com, com_std)]
    return {"body": name, "mass_kg": mass, "com_m": coords}
