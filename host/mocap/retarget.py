"""Captured arm motion onto a model's arm: segment orientations, split along the model's own axes.

The captured arm is read as the orientation of each segment relative to the thorax, never as raw
channels (which wrap and whose order and rest differ from file to file):

    F_S = A · (R_thoraxᵀ R_S) · Aᵀ · F_rest,S

A turns the file's axes into servodyn's (skeleton.guess_axes); F_rest,S is the smallest rotation
from the model's segment at q = 0 (the hanging arm) to the file's rest bone (the child's OFFSET),
then a twist about the bone that BVH does not carry: the elbow-axis calibration fits it from the
motion (`calibrate`). The arm must be spherical-revolute-spherical as the built-in arms are: three
dofs at the shoulder, elbow flexion and pronation at the elbow (pronation along the forearm), two
at the wrist (`ArmTarget`). Then, with the model's dof axes at q = 0 (w1..w7, world frame):

- shoulder: F_upper = Rot(w1,q1) Rot(w2,q2) Rot(w3,q3), split exactly (angles.split3); of its two
  branches each frame takes the one with fewer limit hits, then the one nearest the frame before;
- elbow: the forearm direction u in the upper arm gives q4 (its part off the hinge plane is the
  elbow residual, which the calibration drives to zero);
- pronation and wrist: Rot(w4,q4)ᵀ F_upperᵀ F_hand = Rot(w5,q5) Rot(w6,q6) Rot(w7,q7), split the
  same way, whichever segment of the file stores the forearm's twist.

Then (`smooth`): outliers out (a Hampel-style pass on the residual from a local quadratic),
soft limits SOFT_MARGIN inside the hard ones, a zero-phase Butterworth low-pass at CUTOFF_HZ,
one C2 spline for q, qd, qdd; then the clip's first EASE_IN s played from stillness (slower,
the same path) and a C2 lead-in from rest to its first pose (arriving at the clip's own speed
instead can swing a joint past its limit). Noise in the angles is amplified twice by differentiation: 0.2° of channel noise is some
470 N·m of torque error through q̈ unfiltered, 2.5 N·m after this on the forehand
(tests/test_retarget.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..control.trajectory import Trajectory, spline_derivatives
from ..errors import ServodynError
from ..model import ik
from ..model.rotations import axis_angle, unit
from .angles import angle_about, smallest_rotation, split3
from .bvh import Clip
from .smoothing import CUTOFF_HZ, FILTER_ORDER, ease_in, lead_in, low_pass, remove_outliers
from .skeleton import ArmChain, Axes, rest_frame, segment_rotations

SOFT_MARGIN = math.radians(2.0)     # clamping exactly at a limit fails the validator's dense check
CALIBRATION_FLEXION = math.radians(30.0)   # frames with the elbow bent this far fit its hinge
CALIBRATION_FRAMES = 10
EASE_IN = 0.25                      # s of the clip's start played from stillness, in twice the time
FLIP = math.radians(30.0)           # a step this large between frames is a flip, not motion


class RetargetError(ServodynError, ValueError):
    """A model or clip the retargeting cannot use: one line."""


@dataclass
class ArmTarget:
    """A model's arm as the retargeting sees it: the dofs' world axes at q = 0 (the product of
    exponentials: R(q) = Rot(w1,q1)···Rot(wk,qk) R(0) for the body after dof k), its joint
    centres and the hand's centre of mass at q = 0, and its limits."""
    model: object
    axes: np.ndarray                # (7, 3)
    shoulder: np.ndarray
    elbow: np.ndarray
    wrist: np.ndarray
    hand: np.ndarray                # the last body's centre of mass
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def of(cls, model) -> "ArmTarget":
        if model.free_root or any(b.ball for b in model.bodies):
            raise RetargetError(f"model '{model.name}': retargeting needs a fixed base and 1-dof axes (no free root "
                                "or ball joints)")
        q0 = np.zeros(model.nq)
        R0, p0 = model.body_poses(q0)
        body_of = [i for i, b in enumerate(model.bodies) for _ in b.dofs]
        groups: list[list[int]] = []
        for k, i in enumerate(body_of):
            if groups and np.allclose(p0[body_of[groups[-1][0]]], p0[i], atol=1e-9):
                groups[-1].append(k)
            else:
                groups.append([k])
        sizes = [len(g) for g in groups]
        if sizes != [3, 2, 2]:
            raise RetargetError(f"model '{model.name}': retargeting needs a spherical-revolute-spherical arm: 3 dofs "
                                f"at the shoulder, 2 at the elbow (flexion, pronation), 2 at the wrist; its dofs "
                                f"meet in groups of {sizes}")
        axes = np.zeros((7, 3))
        eps = 1e-6
        for k in range(7):
            dq = np.zeros(model.nq)
            dq[k] = eps
            Rp, Rm = model.body_poses(dq)[0][body_of[k]], model.body_poses(-dq)[0][body_of[k]]
            W = (Rp - Rm) @ R0[body_of[k]].T / (2 * eps)
            axes[k] = unit([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])
        shoulder, elbow, wrist = (p0[body_of[g[0]]] for g in groups)
        hand = model.com_positions(q0)[body_of[6]]
        target = cls(model, axes, shoulder, elbow, wrist, hand, model.lower.copy(), model.upper.copy())
        if abs(axes[4] @ target.fore_dir) < 1 - 1e-6:
            raise RetargetError(f"model '{model.name}': its fifth dof ({model.dof_names[4]}) must turn about the "
                                "forearm (pronation)")
        if abs(axes[3] @ target.fore_dir) > 1e-6:
            raise RetargetError(f"model '{model.name}': its elbow axis ({model.dof_names[3]}) must be across the "
                                "forearm")
        return target

    @property
    def upper_dir(self) -> np.ndarray:
        return unit(self.elbow - self.shoulder)

    @property
    def fore_dir(self) -> np.ndarray:
        return unit(self.wrist - self.elbow)

    @property
    def lengths(self) -> tuple[float, float]:
        return float(np.linalg.norm(self.elbow - self.shoulder)), float(np.linalg.norm(self.wrist - self.elbow))

    def rotations(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(F, 3, 3) world rotations of the upper arm, forearm and hand relative to q = 0."""
        P = axis_angle(self.axes[0], q[:, 0])
        out = []
        for k in range(1, 7):
            P = P @ axis_angle(self.axes[k], q[:, k])
            if k in (2, 4, 6):
                out.append(P)
        return tuple(out)

    def points(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(F, 3) positions of the elbow, the wrist and the hand's centre of mass."""
        F_upper, F_fore, F_hand = self.rotations(q)
        elbow = self.shoulder + F_upper @ (self.elbow - self.shoulder)
        wrist = elbow + F_fore @ (self.wrist - self.elbow)
        return elbow, wrist, wrist + F_hand @ (self.hand - self.wrist)

    def soft_limits(self) -> tuple[np.ndarray, np.ndarray]:
        margin = np.minimum(SOFT_MARGIN, (self.upper - self.lower) / 4)
        return self.lower + margin, self.upper - margin


@dataclass
class Capture:
    """The captured arm on servodyn's axes: segment rotations relative to the model's rest."""
    t: np.ndarray                   # (F,) s, from the first frame used
    F_upper: np.ndarray             # (F, 3, 3)
    F_hand: np.ndarray
    forearm: np.ndarray             # (F, 3) unit forearm direction
    twist: float                    # rad, the calibrated twist about the upper arm
    calibration: dict = field(default_factory=dict)


def _conjugate(A, R):
    return np.einsum("ij,fjk,lk->fil", A, R, A)


def capture(clip: Clip, chain: ArmChain, axes: Axes, target: ArmTarget, frames: slice = slice(None),
            twist: float | None = None) -> Capture:
    """The arm's segments relative to the thorax for `frames`, with the elbow axis calibrated (or
    the given twist, rad); a left arm mirrored (the built-in arms are right arms)."""
    rot = segment_rotations(clip, chain, frames)
    # a left arm is mirrored onto the model's (right) arm: left and right swapped, y -> -y
    A = axes.A if chain.side == "right" else np.diag([1.0, -1.0, 1.0]) @ axes.A
    for role, child in (("upper_arm", chain.forearm), ("forearm", chain.hand)):
        if np.linalg.norm(clip.joints[child].offset) < 1e-12:
            raise RetargetError(f"{clip.source}: joint '{clip.joints[child].name}' sits on its parent "
                                f"('{clip.joints[getattr(chain, role)].name}' has no length to point along)")
    o_upper = A @ unit(clip.joints[chain.forearm].offset)
    o_fore = A @ unit(clip.joints[chain.hand].offset)
    S_upper = smallest_rotation(target.upper_dir, o_upper)
    S_fore = smallest_rotation(target.fore_dir, o_fore)
    M_upper, M_hand = _conjugate(A, rot["upper_arm"]), _conjugate(A, rot["hand"])
    u = np.einsum("fij,j->fi", _conjugate(A, rot["forearm"]), o_fore)
    G = M_upper @ S_upper
    u_local = np.einsum("fji,fj->fi", G, u)
    calibration = calibrate(u_local, target) if twist is None else {"twist_deg": math.degrees(twist),
                                                                    "fitted": False, "why": "given"}
    psi = math.radians(calibration["twist_deg"])
    F_upper = G @ axis_angle(target.upper_dir, psi)
    F_hand = M_hand @ S_fore @ axis_angle(target.fore_dir, psi)
    t = np.arange(len(u)) * clip.frame_time
    return Capture(t, F_upper, F_hand, u, psi, calibration)


def captured_points(cap: Capture, target: ArmTarget) -> np.ndarray:
    """(F, 4, 3) the captured arm with the model's segment lengths: shoulder, elbow, wrist and the
    hand's centre of mass, in the model's base frame."""
    elbow = target.shoulder + cap.F_upper @ (target.elbow - target.shoulder)
    wrist = elbow + target.lengths[1] * cap.forearm
    hand = wrist + cap.F_hand @ (target.hand - target.wrist)
    return np.stack([np.broadcast_to(target.shoulder, elbow.shape), elbow, wrist, hand], axis=1)


def _hinge_frame(target: ArmTarget) -> tuple[np.ndarray, np.ndarray]:
    """(f, h): where elbow flexion moves the forearm from rest, and the hinge axis."""
    h = target.axes[3]
    return unit(np.cross(h, target.fore_dir)), h


def calibrate(u_local: np.ndarray, target: ArmTarget) -> dict:
    """The twist about the upper arm that puts the captured elbow's hinge on the model's: over the
    frames with the elbow flexed past CALIBRATION_FLEXION, the forearm direction in the upper arm
    sweeps a plane through the bone; its normal is the hinge (the smallest direction of the
    scatter of u across the bone)."""
    f, h = _hinge_frame(target)
    flexion = np.arccos(np.clip(u_local @ target.fore_dir, -1, 1))
    bent = flexion > CALIBRATION_FLEXION
    if bent.sum() < CALIBRATION_FRAMES:
        return {"twist_deg": 0.0, "fitted": False, "frames": int(bent.sum()),
                "why": f"the elbow bends past {math.degrees(CALIBRATION_FLEXION):.0f}° in {int(bent.sum())} frames "
                       f"(fewer than {CALIBRATION_FRAMES}): not calibrated"}
    xy = np.stack([u_local[bent] @ f, u_local[bent] @ h], axis=1)
    _, vectors = np.linalg.eigh(xy.T @ xy)
    m = vectors[:, 1]                                 # the direction the forearm sweeps
    if (xy @ m).mean() < 0:
        m = -m
    psi = math.atan2(m[1], m[0])                      # from f towards h, about the bone
    before = np.degrees(np.arcsin(np.clip(xy[:, 1] / np.linalg.norm(xy, axis=1), -1, 1)))
    c, s = math.cos(psi), math.sin(psi)
    after = np.degrees(np.arcsin(np.clip((-s * xy[:, 0] + c * xy[:, 1]) / np.linalg.norm(xy, axis=1), -1, 1)))
    return {"twist_deg": math.degrees(psi), "fitted": True, "frames": int(bent.sum()),
            "residual_p95_deg_before": float(np.percentile(np.abs(before), 95)),
            "residual_p95_deg": float(np.percentile(np.abs(after), 95)),
            "residual_max_deg": float(np.abs(after).max())}


def _wrap_into(angles: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Each angle moved by whole turns to the middle of its limits' turn."""
    mid = np.where(np.isfinite(lo + hi), (lo + hi) / 2, 0.0)
    return angles + 2 * np.pi * np.round((mid - angles) / (2 * np.pi))


def _choose(sets: tuple[np.ndarray, np.ndarray], lo, hi) -> tuple[np.ndarray, int]:
    """Per frame the branch with fewer limit hits, then the one nearest the frame before;
    (F, 3) angles and how many frames the naive principal branch would have flipped."""
    a, b = (_wrap_into(s, lo, hi) for s in sets)
    hits = [((s < lo) | (s > hi)).sum(axis=1) for s in (a, b)]
    out = np.empty_like(a)
    previous = None
    for i in range(len(a)):
        if hits[0][i] != hits[1][i]:
            pick = a[i] if hits[0][i] < hits[1][i] else b[i]
        elif previous is None:
            pick = a[i] if np.abs(a[i]).sum() <= np.abs(b[i]).sum() else b[i]
        else:
            pick = a[i] if np.abs(a[i] - previous).sum() <= np.abs(b[i] - previous).sum() else b[i]
        out[i] = previous = pick
    naive = np.where((np.abs(sets[0][:, 1]) <= np.abs(sets[1][:, 1]))[:, None], sets[0], sets[1])
    return out, _flips(naive) - _flips(out)


def _flips(q: np.ndarray) -> int:
    return int((np.abs(np.diff(q, axis=0)).max(axis=1, initial=0.0) > FLIP).sum()) if len(q) > 1 else 0


def decompose(cap: Capture, target: ArmTarget) -> tuple[np.ndarray, dict]:
    """The model's angles (F, 7) that put its segments on the captured ones, exactly where the
    captured elbow is a hinge, and what it took."""
    w = target.axes
    lo, hi = target.lower, target.upper
    shoulder, flips_shoulder = _choose(split3(cap.F_upper, w[0], w[1], w[2]), lo[:3], hi[:3])
    v = np.einsum("fji,fj->fi", cap.F_upper, cap.forearm)
    elbow = angle_about(w[3], np.broadcast_to(target.fore_dir, v.shape), v)
    elbow = _wrap_into(elbow[:, None], lo[3:4], hi[3:4])[:, 0]
    off_hinge = np.degrees(np.arcsin(np.clip(v @ w[3], -1, 1)))
    N = np.einsum("fji,fjk->fik", axis_angle(w[3], elbow), np.einsum("fji,fjk->fik", cap.F_upper, cap.F_hand))
    wrist, flips_wrist = _choose(split3(N, w[4], w[5], w[6]), lo[4:], hi[4:])
    q = np.concatenate([shoulder, elbow[:, None], wrist], axis=1)
    return q, {"flips_avoided": max(0, flips_shoulder) + max(0, flips_wrist),
               "elbow_residual_p95_deg": float(np.percentile(np.abs(off_hinge), 95)),
               "elbow_residual_max_deg": float(np.abs(off_hinge).max())}


def solve_ik(cap: Capture, target: ArmTarget, q_angles: np.ndarray, progress=None) -> tuple[np.ndarray, dict]:
    """The model's angles by inverse kinematics on the captured hand (servodyn.model.ik): per frame
    the wrist at the captured forearm's end and the hand's frame as captured, the elbow's swivel
    the captured elbow's (from the angles' split, which is exact before any limit), the limits as
    bounds, from the previous frame's pose. Where no pose at that swivel is inside the limits, the
    in-limit swivel nearest the previous frame's; where none reaches the hand's frame, the bounded
    least-squares pose nearest it. (F, 7) angles and what it took; progress(i, F) after each frame."""
    model = target.model
    arm = ik.Arm.of(model)
    R0 = model.user_poses(np.zeros(model.nq))[0][arm.end]
    wrist = captured_points(cap, target)[:, 2]
    rotations = cap.F_hand @ R0
    lo, hi = target.lower, target.upper
    q = np.empty_like(q_angles)
    previous = np.clip(q_angles[0], lo, hi)
    counts = {"at_captured_swivel": 0, "nearest_swivel": 0, "least_squares": 0}
    for i in range(len(q)):
        swivel = arm.swivel_of(q_angles[i][arm.q_index])
        try:
            r = ik.solve(model, wrist[i], rotations[i], q_prev=previous, swivel=swivel)
            counts["at_captured_swivel"] += 1
        except ik.IkError:
            try:
                r = ik.solve(model, wrist[i], rotations[i], q_prev=previous)
                counts["nearest_swivel"] += 1
            except ik.IkError:
                r = None
        if r is not None:
            previous = r.q
        else:
            x, _, _ = arm.solve_dls(previous[arm.q_index], wrist[i], rotations[i])
            previous = previous.copy()
            previous[arm.q_index] = np.clip(x, arm.lower, arm.upper)
            counts["least_squares"] += 1
        q[i] = previous
        if progress is not None:
            progress(i + 1, len(q))
    return q, {"ik": counts, "flips_avoided": max(0, _flips(q_angles) - _flips(q))}


@dataclass
class Retargeted:
    trajectory: Trajectory          # the motion to play: lead-in, then the clip
    lead_in_s: float
    frame_times: np.ndarray         # (F,) s, when each of the clip's frames is played in `trajectory`
    q_raw: np.ndarray               # (F, 7) the decomposition, before any smoothing
    q: np.ndarray                   # (F, 7) smoothed, at the clip's frames
    capture: Capture
    report: dict


METHODS = ("angles", "ik")


def retarget(clip: Clip, chain: ArmChain, axes: Axes, target: ArmTarget, frames: slice | None = None,
             twist: float | None = None, smooth: bool = True, with_lead_in: bool = True,
             method: str = "angles", progress=None) -> Retargeted:
    """The clip's arm on the model: the decomposition (method "angles") or inverse kinematics on
    the hand ("ik", `solve_ik`), then (smooth) outliers, soft limits, low-pass and spline, then
    (with_lead_in) the lead-in from rest. `frames` None takes the whole clip without its rest
    frame (frame 0 when it is a T-pose)."""
    if method not in METHODS:
        raise RetargetError(f"method '{method}': expected one of {', '.join(METHODS)}")
    dropped = False
    if frames is None:
        dropped = rest_frame(clip, chain)[0]
        frames = slice(1 if dropped else 0, None)
    cap = capture(clip, chain, axes, target, frames, twist)
    if len(cap.t) < 2:
        raise RetargetError(f"{clip.source}: {len(cap.t)} frame{'s' if len(cap.t) != 1 else ''} selected: a "
                            "motion needs at least two")
    q_raw, info = decompose(cap, target)
    soft_lo, soft_hi = target.soft_limits()
    outside = (q_raw < soft_lo) | (q_raw > soft_hi)       # the captured pose, split: where it leaves the limits
    worst = np.maximum(np.maximum(soft_lo - q_raw, q_raw - soft_hi), 0.0).max(axis=0)
    if method == "ik":
        q_angles = q_raw
        q_raw, solved = solve_ik(cap, target, q_angles, progress)
        info.update(solved)
    names = target.model.dof_names
    replaced = np.zeros(q_raw.shape, dtype=bool)
    q = q_raw
    if smooth:
        q, replaced = remove_outliers(q_raw)
        q = np.clip(q, soft_lo, soft_hi)
        q = np.clip(low_pass(q, clip.rate), soft_lo, soft_hi)
    qd, qdd = spline_derivatives(cap.t, q)
    t, Q, QD, QDD, lead, eased, shown = cap.t, q, qd, qdd, 0.0, 0.0, cap.t
    if with_lead_in:
        eased = min(EASE_IN, float(cap.t[-1]) / 4) if len(cap.t) > 3 else 0.0
        te, qe, qde, qdde, shown = ease_in(cap.t, q, eased)
        rest = np.clip(np.zeros(7), soft_lo, soft_hi)
        tl, ql, qdl, qddl = lead_in(rest, qe[0], clip.frame_time)
        lead = float(len(tl) * clip.frame_time)
        t, shown = np.concatenate([tl, te + lead]), shown + lead
        Q, QD, QDD = (np.concatenate(pair) for pair in ((ql, qe), (qdl, qde), (qddl, qdde)))
    _, elbow_c, _, hand_c = captured_points(cap, target).transpose(1, 0, 2)
    elbow_m, _, hand_m = target.points(q)
    errors = {}
    for what, a, b in (("elbow", elbow_c, elbow_m), ("hand", hand_c, hand_m)):
        d = np.linalg.norm(a - b, axis=1) * 1e3
        errors[what] = {"p95_mm": float(np.percentile(d, 95)), "max_mm": float(d.max()),
                        "rms_mm": float(np.sqrt(np.mean(d ** 2)))}
    first = frames.start or 0
    report = {
        "frames": {"first": int(first), "count": int(len(cap.t)), "rest_frame_dropped": dropped,
                   "rate_hz": clip.rate, "duration_s": float(cap.t[-1])},
        "calibration": cap.calibration,
        "lead_in_s": lead,
        "eased_in_s": eased,      # the clip's first seconds played slower from stillness (twice as long)
        "method": method,
        "flips_avoided": info["flips_avoided"],
        **({"ik": info["ik"]} if "ik" in info else {}),
        "elbow_residual_p95_deg": info["elbow_residual_p95_deg"],
        "elbow_residual_max_deg": info["elbow_residual_max_deg"],
        "limit_hits": {d: {"frames": int(outside[:, j].sum()), "worst_deg": float(np.degrees(worst[j]))}
                       for j, d in enumerate(names) if outside[:, j].any()},
        "soft_limit_margin_deg": math.degrees(SOFT_MARGIN),
        "outliers_removed": {d: int(replaced[:, j].sum()) for j, d in enumerate(names) if replaced[:, j].any()},
        "filter": {"cutoff_hz": CUTOFF_HZ, "order": FILTER_ORDER, "zero_phase": True} if smooth else None,
        "cartesian_error": errors,
    }
    return Retargeted(Trajectory(t=t, q=Q, qd=QD, qdd=QDD, derived=False), lead, shown, q_raw, q, cap, report)



def source_arm(clip: Clip, model, duration: float, arms: dict[str, ArmChain], axes: Axes,
               arm: str = "right") -> tuple[np.ndarray, np.ndarray]:
    """The captured arm of a clip as `retarget` (whole clip) reads it, on the clock of the motion it
    writes (lead-in included): times (F,) and points (F, 4, 3), `captured_points`. RetargetError
    when a motion of `duration` s is not that clip's whole retarget."""
    if arm not in arms:
        raise RetargetError(f"{clip.source}: no {arm} arm found (found: {', '.join(arms) or 'none'})")
    target = ArmTarget.of(model)
    result = retarget(clip, arms[arm], axes, target)
    t = result.frame_times
    if abs(t[-1] - duration) > 2 * clip.frame_time:
        raise RetargetError(f"{clip.source}: retargeted as a whole it lasts {t[-1]:.3f} s, the motion "
                            f"{duration:.3f} s: --source overlays a motion that `servodyn retarget` wrote from "
                            "the whole clip")
    return t, captured_points(result.capture, target)
