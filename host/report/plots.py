"""Figures a reader compares with the paper's: stick-figure postures (Figs. 5, 7), weights and
joint torques (Fig. 6), torque curves (Fig. 8). matplotlib, off-screen."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

VIEWS = {"side": (0, 2, "x forward (m)", "z up (m)"), "top": (0, 1, "x forward (m)", "y left (m)"),
         "front": (1, 2, "y left (m)", "z up (m)")}


TITLE_CHARS = 100        # a title or label longer than this is cut: matplotlib lays out every glyph, and
                         # a 100 000-character configuration name took half a minute to draw


def short(text: str, limit: int = TITLE_CHARS) -> str:
    """`text` cut to `limit` characters, an ellipsis marking the cut."""
    text = str(text)
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: Path, dpi: int, tight: bool = True) -> None:
    """Lay the figure out (unless `tight` is False), write it to `path` and free it."""
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    _pyplot().close(fig)


def skeleton(model, q) -> list[np.ndarray]:
    """Line segments (2 x 3 world points) of a stick figure: parent origin to child origin, and
    for a body without children its origin to twice its centre of mass (the segment's end)."""
    _, origins = model.body_poses(q)
    coms = model.com_positions(q)
    has_child = {b.parent for b in model.bodies}
    segments = []
    for i, body in enumerate(model.bodies):
        if body.parent >= 0:
            segments.append(np.array([origins[body.parent], origins[i]]))
        if i not in has_child:
            segments.append(np.array([origins[i], origins[i] + 2 * (coms[i] - origins[i])]))
    return segments


def draw_posture(ax, model, q, view: str = "side", color="k", alpha=1.0, lw=2.0) -> None:
    a, b, xlabel, ylabel = VIEWS[view]
    for seg in skeleton(model, q):
        ax.plot(seg[:, a], seg[:, b], "-", color=color, alpha=alpha, lw=lw, solid_capstyle="round")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_aspect("equal", adjustable="box")


def posture_series(path: Path, model, qs, times, views=("side", "top"), title: str = "") -> None:
    """Postures overlaid, early ones light and late ones dark, one panel per view (paper Fig. 7)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(views), figsize=(5.5 * len(views), 5.5))
    axes = np.atleast_1d(axes)
    cmap = plt.get_cmap("viridis")
    for ax, view in zip(axes, views):
        for k, q in enumerate(qs):
            draw_posture(ax, model, q, view, color=cmap(k / max(1, len(qs) - 1)), alpha=0.85, lw=1.4)
        ax.set_title(f"{view} view")
        ax.grid(alpha=0.3)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(times[0], times[-1]))
    fig.colorbar(sm, ax=axes.tolist(), label="time (s)", shrink=0.8)
    if title:
        fig.suptitle(short(title))
    _save(fig, path, 110, tight=False)


def snapshots(path: Path, model, qs, times, view: str = "front", title: str = "") -> None:
    """One small panel per posture (paper Fig. 5)."""
    plt = _pyplot()
    n = len(qs)
    cols = min(n, 6)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 3.2 * rows), squeeze=False)
    everything = np.concatenate([np.concatenate(skeleton(model, q)) for q in qs])
    a, b, _, _ = VIEWS[view]
    lo, hi = everything.min(axis=0) - 0.1, everything.max(axis=0) + 0.1
    for ax in axes.flat[n:]:
        ax.axis("off")
    for ax, q, t in zip(axes.flat, qs, times):
        draw_posture(ax, model, q, view, lw=2.2)
        ax.set_xlim(lo[a], hi[a])
        ax.set_ylim(lo[b], hi[b])
        ax.set_title(f"t = {t:.1f} s", fontsize=9)
        ax.set_xlabel("")
        ax.set_ylabel("")
        ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(short(title))
    _save(fig, path, 110)


def curves(path: Path, t, series: dict[str, np.ndarray], ylabel: str, title: str = "",
           marks: dict[str, float] | None = None) -> None:
    """Time curves, one line per name (paper Fig. 8), with optional vertical event marks."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, values in series.items():
        ax.plot(t, values, label=short(name, 40))
    for label, when in (marks or {}).items():
        ax.axvline(when, color="0.5", ls=":", lw=1)
        ax.text(when, ax.get_ylim()[1], label, rotation=90, va="top", ha="right", fontsize=8, color="0.4")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(short(title))
    _save(fig, path, 110)


def weights_and_torques(path: Path, model, q, tau, title: str = "") -> None:
    """Each solid's weight (N) and each joint's torque (N m) holding the posture (paper Fig. 6)."""
    plt = _pyplot()
    fig, (ax0, ax1, ax2) = plt.subplots(1, 3, figsize=(15, 5.5), width_ratios=[1.1, 1, 1.6])
    draw_posture(ax0, model, q, "front", lw=2.5)
    coms = model.com_positions(q)
    weights = np.array([b.mass for b in model.bodies]) * np.linalg.norm(model.gravity)
    for c, w in zip(coms, weights):
        ax0.annotate("", xy=(c[1], c[2] - 0.004 * w), xytext=(c[1], c[2]),
                     arrowprops=dict(arrowstyle="->", color="tab:red", lw=1.2))
    ax0.set_title("posture (front) and weights G")
    ax1.barh(model.body_names, weights, color="tab:red")
    ax1.set_xlabel("weight G (N)")
    ax1.invert_yaxis()
    names = list(model.dof_names)
    ax2.barh(names, tau, color="tab:blue")
    ax2.set_xlabel("joint torque (N m)")
    ax2.invert_yaxis()
    ax2.tick_params(labelsize=7)
    for ax in (ax0, ax1, ax2):
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(short(title))
    _save(fig, path, 110)


ERROR_SMOOTHING = 0.05    # s: the tracking error's moving average in the swing's figure


def _moving_mean(x: np.ndarray, width: int) -> np.ndarray:
    """The mean of `width` samples centred on each one (fewer at the ends), per column."""
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    k = np.arange(len(x))
    lo, hi = np.clip(k - width // 2, 0, len(x)), np.clip(k - width // 2 + width, 0, len(x))
    return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))


def tracking_figure(path: Path, t, q_d, q, tau, names, title: str, torque_limits=None, encoder_steps=None) -> None:
    """A run at a glance: the angles (desired dotted); each joint's tracking error in a panel of its
    own, the raw error faint under its ERROR_SMOOTHING moving average, one encoder count at the joint
    (`encoder_steps`, rad) shaded; and the commanded torques as a share of each joint's torque limit
    (`torque_limits`, N m; without them in N m), the limit drawn at ±100 %."""
    plt = _pyplot()
    n = len(names)
    cols = min(4, n)
    rows = -(-n // cols)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    color = [colors[k % len(colors)] for k in range(n)]
    fig = plt.figure(figsize=(12, 3.2 + 1.9 * rows + 3.2), layout="constrained")
    grid = fig.add_gridspec(2 + rows, cols, height_ratios=[1.7] + [1.0] * rows + [1.7])
    angles = fig.add_subplot(grid[0, :])
    torques = fig.add_subplot(grid[-1, :], sharex=angles)
    error = np.degrees(q_d - q)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1e-3
    smooth = _moving_mean(error, max(1, int(round(ERROR_SMOOTHING / dt)))) if len(t) else error
    first = None
    for k, name in enumerate(names):
        angles.plot(t, np.degrees(q[:, k]), color=color[k], lw=1.2, label=short(name, 40))
        angles.plot(t, np.degrees(q_d[:, k]), ":", color=color[k], lw=1.2)
        ax = fig.add_subplot(grid[1 + k // cols, k % cols], sharex=angles, sharey=first)
        first = first or ax
        if encoder_steps is not None and encoder_steps[k]:
            step = math.degrees(encoder_steps[k])
            ax.axhspan(-step, step, color="0.88", lw=0, label="±1 encoder count")
        ax.plot(t, error[:, k], color=color[k], lw=0.5, alpha=0.35, label="error")
        ax.plot(t, smooth[:, k], color=color[k], lw=1.4, label=f"{ERROR_SMOOTHING * 1e3:g} ms mean")
        rms = float(np.sqrt(np.mean(error[:, k] ** 2))) if len(t) else 0.0
        peak = float(np.abs(error[:, k]).max()) if len(t) else 0.0
        ax.set_title(f"{short(name, 28)}: rms {rms:.3f}°, max {peak:.3f}°", fontsize=8, color=color[k])
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        if k % cols == 0:
            ax.set_ylabel("error (deg)", fontsize=8)
        if k == 0:
            ax.legend(fontsize=6, loc="upper right")
    if torque_limits is not None:
        for k, name in enumerate(names):
            torques.plot(t, 100 * tau[:, k] / torque_limits[k], color=color[k], lw=1,
                         label=f"{short(name, 28)} (limit {torque_limits[k]:.2f} N m)")
        for sign in (1, -1):
            torques.axhline(100 * sign, color="tab:red", ls="--", lw=1.2,
                            label="torque limit (current limit × torque constant × gear)" if sign > 0 else None)
        torques.set_ylabel("commanded torque (% of limit)")
    else:
        for k, name in enumerate(names):
            torques.plot(t, tau[:, k], color=color[k], lw=1, label=short(name, 28))
        torques.set_ylabel("commanded torque (N m)")
    angles.set_ylabel("angle (deg), dotted: desired")
    torques.set_xlabel("time (s)")
    angles.legend(fontsize=7, ncol=4, loc="best")
    torques.legend(fontsize=7, ncol=2, loc="best")
    for ax in (angles, torques):
        ax.grid(alpha=0.3)
    fig.suptitle(short(title))
    _save(fig, path, 100, tight=False)


def envelope_figure(file: Path, result, limits, dof_names, title: str) -> None:
    """Per joint, the torque–speed plane as a motor data sheet draws it: the motion's path over
    the envelope at the supply voltage (driving: the line from stall torque to no-load speed;
    braking: widening with the back-EMF), the current limit and the velocity limit."""
    plt = _pyplot()
    n = len(dof_names)
    cols = min(4, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.2 * rows), squeeze=False)
    for j, dof in enumerate(dof_names):
        ax = axes[j // cols][j % cols]
        g, ts, w0 = limits.gear[j], limits.stall_torque[j] * limits.gear[j], limits.no_load_speed[j] / limits.gear[j]
        w = np.linspace(-w0, w0, 201)
        upper = np.where(w >= 0, ts * (1 - w / w0), ts * (1 - w / w0))    # driving right, braking left
        current = (limits.current[j] - limits.no_load_current[j]) * limits.torque_constant[j] * g
        ax.fill_between(w, np.minimum(upper, current), -np.minimum(upper[::-1], current), color="tab:green",
                        alpha=0.12, label="envelope")
        ax.plot(w, np.minimum(upper, current), color="tab:green", lw=1)
        ax.plot(w, -np.minimum(upper[::-1], current), color="tab:green", lw=1)
        ax.axvline(limits.speed[j], color="0.5", ls=":", lw=1)
        ax.axvline(-limits.speed[j], color="0.5", ls=":", lw=1, label="velocity limit")
        bad = result.ratios["torque_speed"][:, j] > result.allowed("torque_speed")
        ax.plot(result.qd[:, j], result.tau[:, j], color="tab:blue", lw=1, label="motion")
        if bad.any():
            ax.plot(result.qd[bad, j], result.tau[bad, j], ".", color="tab:red", ms=2, label="outside")
        ax.set_title(short(dof, 40), fontsize=9)
        ax.set_xlabel("speed (rad/s)", fontsize=8)
        ax.set_ylabel("torque (N m)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(short(title))
    _save(fig, file, 100)


def limits_in_time_figure(file: Path, result, limits, dof_names, title: str) -> None:
    """Current and winding temperature of each joint against time, with their limits."""
    plt = _pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for j, dof in enumerate(dof_names):
        line, = top.plot(result.t, result.current[:, j], lw=1, label=short(dof, 40))
        top.axhline(limits.current[j], color=line.get_color(), ls=":", lw=1)
        bottom.plot(result.t, result.temperature[:, j], lw=1, color=line.get_color(), label=short(dof, 40))
    for limit in sorted(set(limits.temperature)):
        bottom.axhline(limit, color="tab:red", ls=":", lw=1)
    top.set_ylabel("current (A), dotted: limit")
    bottom.set_ylabel("winding (°C), dotted: limit")
    bottom.set_xlabel("time (s)")
    top.legend(fontsize=7, ncol=2)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    top.set_title(short(title))
    _save(fig, file, 100)
