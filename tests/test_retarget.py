"""Retargeting captured arm motion (servodyn.mocap.retarget, `servodyn retarget`, `export-bvh`):
a round trip through BVH over random in-limit poses, orders, units and rest poses; an injected
elbow-axis twist recovered; single-frame glitches removed; the forehand with 0.2° channel noise
within 3 N·m of its torques; the real CMU clip inside the limits and passing validate --fit."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servodyn.control.motion import motion_path
from servodyn.control.trajectory import read_trajectory_csv
from servodyn.hal.config import load_config
from servodyn.mocap import find_arms, guess_axes
from servodyn.mocap.bvh import format_bvh, parse_bvh
from servodyn.mocap.export import ORDERS, arm_clip, euler_channels
from servodyn.mocap.retarget import ArmTarget, retarget
from servodyn.mocap.skeleton import UNITS, segment_rotations
from servodyn.model import load_model
from servodyn.tools.cli import main
from servodyn.tools.mocap import run_retarget
from servodyn.report.validation import validate

from helpers import quiet

CLIPS = Path("/usr/share/assimp/models/BVH")
needs_clips = pytest.mark.skipif(not (CLIPS / "01_01.bvh").exists(),
                                 reason="assimp-testmodels not installed (make test installs it)")
RATE = 120.0
ARM_JOINTS = ("RightArm", "RightForeArm", "RightHand")


@pytest.fixture(scope="module")
def human():
    model = load_model("human_arm")
    return model, ArmTarget.of(model)


def read_back(text):
    clip = parse_bvh(text)
    arms = find_arms(clip)
    axes, _ = guess_axes(clip, arms)
    return clip, arms["right"], axes


def forehand(model):
    return motion_path("tennis_forehand", model).at_scale(1.0, 1.0 / RATE)


@pytest.mark.parametrize("name", ["human_arm", "replica"])
def test_the_target_reads_the_models_own_axes(name):
    """The dof axes at q = 0 found from the model's kinematics are its files' (human_arm.toml and
    replica.toml: -y, -x, z; -y, z; x, y), and the product of exponentials gives the model's
    own body rotations (1e-12) at a random pose."""
    model = load_model(name)
    target = ArmTarget.of(model)
    expected = [[0, -1, 0], [-1, 0, 0], [0, 0, 1], [0, -1, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0]]
    assert np.abs(target.axes - expected).max() < 1e-9, "the files' axes"
    q = np.random.default_rng(1).uniform(model.lower, np.minimum(model.upper, 1.0))
    R, _ = model.user_poses(q)
    R0, _ = model.user_poses(np.zeros(7))
    hand = len(model.bodies) - 1
    assert np.abs(target.rotations(q[None])[2][0] - R[hand] @ R0[hand].T).max() < 1e-12, "POE = the model's kinematics"
    elbow, wrist, _ = target.points(q[None])
    _, p = model.body_poses(q)
    body_of = [i for i, b in enumerate(model.bodies) for _ in b.dofs]
    assert np.abs(elbow[0] - p[body_of[3]]).max() < 1e-12 and np.abs(wrist[0] - p[body_of[5]]).max() < 1e-12


def test_a_model_that_is_no_arm_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "c.bvh").write_text("HIERARCHY\n")
    assert main(["retarget", str(tmp_path / "c.bvh"), "--model", "human15"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err


def in_limit_poses(draw_angles, target, frames):
    lo, hi = target.lower + 0.01, target.upper - 0.01
    q = lo + np.array(draw_angles).reshape(frames, 7) * (hi - lo)
    # the shoulder's lock (abduction ±90°) is a singularity of every 3-angle split: kept 10° away
    near = np.abs(np.abs(q[:, 1]) - math.pi / 2) < math.radians(10)
    q[near, 1] = np.where(q[near, 1] > 0, math.radians(70), math.radians(-30))
    return q


@settings(max_examples=30, deadline=None)
@given(fractions=st.lists(st.floats(0, 1), min_size=8 * 7, max_size=8 * 7),
       orders=st.lists(st.sampled_from(ORDERS), min_size=3, max_size=3),
       unit=st.sampled_from(sorted(UNITS)), rest=st.sampled_from(["hang", "tpose"]))
def test_round_trip_through_bvh_returns_the_angles(human, fractions, orders, unit, rest):
    """Random in-limit poses (8 frames), each arm joint its own rotation order, any unit, either rest
    pose: written at 6 decimals and retargeted back without smoothing, every angle within 1e-5 rad
    (a degree at 6 decimals is 1.7e-8 rad; the split loses no more than that near the limits)."""
    model, target = human
    q = in_limit_poses(fractions, target, 8)
    clip = arm_clip(target, q, 1 / RATE, dict(zip(ARM_JOINTS, orders)), unit, rest)
    back, chain, axes = read_back(format_bvh(clip, 6))
    result = retarget(back, chain, axes, target, slice(None), twist=0.0, smooth=False, with_lead_in=False)
    assert np.abs(result.q_raw - q).max() <= 1e-5, f"orders {orders}, unit {unit}, rest {rest}"


def twisted(clip, chain, psi):
    """The clip as a file whose arm segments' rest frames are turned by psi about the bone (the
    twist BVH does not carry): each segment's rotation relative to the thorax times Rot(bone, psi)."""
    rot = segment_rotations(clip, chain)
    bone = clip.joints[chain.forearm].offset / np.linalg.norm(clip.joints[chain.forearm].offset)
    c, s = math.cos(psi), math.sin(psi)
    K = np.array([[0, -bone[2], bone[1]], [bone[2], 0, -bone[0]], [-bone[1], bone[0], 0]])
    T = np.eye(3) + s * K + (1 - c) * K @ K
    G = {role: rot[role] @ T for role in ("upper_arm", "forearm", "hand")}
    local = {chain.upper_arm: G["upper_arm"], chain.forearm: np.einsum("fji,fjk->fik", G["upper_arm"], G["forearm"]),
             chain.hand: np.einsum("fji,fjk->fik", G["forearm"], G["hand"])}
    motion = clip.motion.copy()
    for i, R in local.items():
        joint = clip.joints[i]
        motion[:, joint.column:joint.column + 3] = euler_channels(R, joint.order)
    return clip.with_motion(motion)


@pytest.mark.parametrize("psi_deg", [25.0, -40.0])
def test_an_injected_elbow_twist_is_recovered(human, psi_deg):
    """The forehand written with its arm's rest frames twisted about the bone: the calibration finds
    the twist to 0.5° (it undoes it: -psi) and the angles come back within 0.5°. Without it the
    elbow leaves its hinge plane by about the twist's size."""
    model, target = human
    clip = arm_clip(target, forehand(model).q, 1 / RATE, "ZYX", "cmu", "tpose")
    clip, chain, axes = read_back(format_bvh(clip, 6))
    clip = twisted(clip, chain, math.radians(psi_deg))
    result = retarget(clip, chain, axes, target, slice(None), smooth=False, with_lead_in=False)
    found = result.report["calibration"]["twist_deg"]
    assert abs(found + psi_deg) <= 0.5, f"twist {psi_deg}° injected, {found:.3f}° found (should undo it)"
    assert result.report["calibration"]["residual_p95_deg"] < 0.5, "the hinge fits after calibration"
    assert np.degrees(np.abs(result.q_raw - forehand(model).q)).max() < 0.5
    raw = retarget(clip, chain, axes, target, slice(None), twist=0.0, smooth=False, with_lead_in=False)
    assert raw.report["elbow_residual_p95_deg"] > abs(psi_deg) / 3, "uncalibrated, the elbow is off its plane"


def test_single_frame_spikes_are_removed(human):
    """Five 15° single-frame spikes on the upper arm's channels: the outlier pass finds them all and
    the written motion stays within 0.5° of the clean clip's; the low-pass alone leaves several
    degrees."""
    model, target = human
    clean = arm_clip(target, forehand(model).q, 1 / RATE, "ZXY", "cm", "hang")
    clean, chain, axes = read_back(format_bvh(clean, 6))
    spiky = clean.motion.copy()
    column = clean.joints[chain.upper_arm].column
    frames = [30, 70, 110, 150, 190]
    spiky[frames, column + 1] += 15.0
    a = retarget(clean, chain, axes, target, slice(None), with_lead_in=False)
    b = retarget(clean.with_motion(spiky), chain, axes, target, slice(None), with_lead_in=False)
    assert sum(b.report["outliers_removed"].values()) >= len(frames), "every spike found"
    assert np.degrees(np.abs(a.q - b.q)).max() < 0.5, "the spikes leave no mark"
    from servodyn.mocap.retarget import low_pass
    assert np.degrees(np.abs(low_pass(b.q_raw, RATE) - a.q)).max() > 2.0, "the low-pass alone would not do"


def test_the_forehand_with_channel_noise_keeps_its_torques(human):
    """The forehand exported at 120 Hz, 0.2° of Gaussian noise on every arm channel, retargeted
    back: the torques (RNEA, the written q, qd, qdd) within 3 N·m of the forehand's own at every
    frame (the note measured 468 N·m unfiltered)."""
    model, target = human
    path = forehand(model)
    clip = arm_clip(target, path.q, 1 / RATE, "ZYX", "cm", "tpose")
    clip, chain, axes = read_back(format_bvh(clip, 6))
    noisy = clip.motion.copy()
    rng = np.random.default_rng(25)
    for name in ARM_JOINTS:
        joint = clip.joints[clip.index(name)]
        noisy[:, joint.column:joint.column + 3] += rng.normal(0, 0.2, (clip.frames, 3))
    result = retarget(clip.with_motion(noisy), chain, axes, target, slice(None), with_lead_in=False)
    traj = result.trajectory
    tau = model.inverse_dynamics(traj.q, traj.qd, traj.qdd)
    truth = model.inverse_dynamics(path.q, path.qd, path.qdd)
    error = np.abs(tau - truth).max()
    assert error <= 3.0, f"torque error {error:.2f} N·m (peak torque {np.abs(truth).max():.1f})"
    unfiltered = retarget(clip.with_motion(noisy), chain, axes, target, slice(None), smooth=False, with_lead_in=False)
    raw = unfiltered.trajectory
    assert np.abs(model.inverse_dynamics(raw.q, raw.qd, raw.qdd) - truth).max() > 30 * error, "the filter is needed"


def test_the_lead_in_starts_at_rest_and_joins_the_motion_c2(human):
    """The written motion starts at rest (q in the soft limits nearest 0, no speed, no acceleration)
    and its q, qd, qdd are continuous where the clip begins (to the spline's own step)."""
    model, target = human
    clip = arm_clip(target, forehand(model).q[60:], 1 / RATE, "ZXY", "cm", "hang")
    clip, chain, axes = read_back(format_bvh(clip, 6))
    result = retarget(clip, chain, axes, target, slice(None))
    traj = result.trajectory
    lo, hi = target.soft_limits()
    assert np.abs(traj.q[0] - np.clip(0, lo, hi)).max() < 1e-12 and np.abs(traj.qd[0]).max() < 1e-12
    assert np.abs(traj.qdd[0]).max() < 1e-9, "from rest"
    k = int(round(result.lead_in_s * RATE))
    dt = 1 / RATE

    def taylor(i):      # how far sample i is from the Taylor step of sample i - 1 (q, qd)
        q_err = traj.q[i] - traj.q[i - 1] - traj.qd[i - 1] * dt - traj.qdd[i - 1] * dt ** 2 / 2
        qd_err = traj.qd[i] - traj.qd[i - 1] - traj.qdd[i - 1] * dt
        return np.abs(q_err).max(), np.abs(qd_err).max()
    join, before, after = taylor(k), taylor(k - 2), taylor(k + 2)
    for n, what in enumerate(("q", "qd")):
        assert join[n] <= 3 * max(before[n], after[n]) + 1e-12, f"{what} steps like its neighbours at the join"
    assert abs(traj.t[k] - result.lead_in_s) < 1e-12, "the clip's first frame follows the lead-in"


@needs_clips
@pytest.mark.slow
def test_the_cmu_clip_retargets_inside_the_limits_and_passes_validate_fit(tmp_path):
    """CMU 01_01 (ten seconds of it) on the replica: the elbow axis 30° off, fitted (residual under
    1°), no frame outside the limits, and validate --fit finds a time scale (at most 10) at which
    the motion passes every check."""
    config = load_config("replica")
    report = run_retarget(str(CLIPS / "01_01.bvh"), config=config, time="2:12", output=tmp_path / "m.csv",
                          report_dir=tmp_path / "r", say=quiet)
    saved = json.loads((tmp_path / "r" / "report.json").read_text())
    assert saved["calibration"]["fitted"] and abs(abs(saved["calibration"]["twist_deg"]) - 30.0) < 1.0
    assert saved["calibration"]["residual_p95_deg"] < 1.0
    assert saved["limit_hits"] == {}, "inside the soft limits as captured"
    traj = read_trajectory_csv(tmp_path / "m.csv", config.model.dof_names)
    assert np.all(traj.q >= config.model.lower) and np.all(traj.q <= config.model.upper), "inside the hard limits"
    scale = report["validate"]["fit_time_scale"]
    assert scale is not None and 1.0 < scale <= 10.0, f"fit {scale}"
    again = validate(config, str(tmp_path / "m.csv"), time_scale=scale * 1.001, say=quiet)
    assert again["passed"], "passes at the fitted time scale"
    assert saved["cartesian_error"]["hand"]["p95_mm"] < 20.0, "the hand follows the captured one"


@needs_clips
def test_retarget_exit_status_flags_the_boxing_clip(tmp_path, capsys):
    """Boxing_Toes onto human_arm: written, but flagged (exit 1): its 3-channel elbow is no hinge
    and its hooks leave the limits."""
    assert main(["retarget", str(CLIPS / "Boxing_Toes.bvh"), "--time", "0:8", "-o", str(tmp_path / "b.csv")]) == 1
    printed = capsys.readouterr()
    assert "the captured elbow is no hinge" in printed.out + printed.err and (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("args, words", [
    (["--frames", "5:2"], "B must come after A"),
    (["--frames", "x:2"], "whole numbers"),
    (["--time", "1:2", "--frames", "1:2"], "not both"),
    (["--frames", "999999:"], "the clip has"),
    (["--map", "/nonexistent.toml"], "no such file"),
])
def test_retarget_bad_options_are_one_line(tmp_path, capsys, args, words, human):
    model, target = human
    path = tmp_path / "f.bvh"
    path.write_text(format_bvh(arm_clip(target, forehand(model).q[:20], 1 / RATE), 6))
    assert main(["retarget", str(path), "-o", str(tmp_path / "m.csv"), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err, err


def test_export_bvh_command_round_trips_the_forehand(tmp_path, capsys, human):
    """export-bvh then retarget: the written motion (filtered) within 1° of the forehand."""
    model, target = human
    out = tmp_path / "f.bvh"
    assert main(["export-bvh", "tennis_forehand", "--order", "YZX", "--unit", "m", "-o", str(out)]) == 0
    assert main(["retarget", str(out), "-o", str(tmp_path / "m.csv")]) == 0
    traj = read_trajectory_csv(tmp_path / "m.csv", model.dof_names)
    q = forehand(model).q
    late = len(q) - int(0.25 * RATE)          # the frames after the eased start, as recorded
    assert np.degrees(np.abs(traj.q[-late:] - q[-late:])).max() < 1.5
    assert main(["export-bvh", "tennis_forehand", "--order", "XXY", "-o", str(tmp_path / "bad.bvh")]) == 2
    assert "--order XXY" in capsys.readouterr().err


@needs_clips
def test_ik_keeps_the_boxing_hooks_inside_the_limits_nearer_the_captured_hand(tmp_path):
    """Boxing_Toes, 3 s: its 3-channel elbow is no hinge and its hooks leave the limits, so the
    angles method clamps (the hand p95 tens of mm off); IK on the captured hand with the limits as
    bounds stays inside them and puts the hand nearer the captured one."""
    model = load_model("human_arm")
    angles = run_retarget(str(CLIPS / "Boxing_Toes.bvh"), model=model, time="0:3", output=tmp_path / "a.csv",
                          say=quiet)
    solved = run_retarget(str(CLIPS / "Boxing_Toes.bvh"), model=model, time="0:3", method="ik",
                          output=tmp_path / "i.csv", say=quiet)
    traj = read_trajectory_csv(tmp_path / "i.csv", model.dof_names)
    assert np.all(traj.q >= model.lower - 1e-12) and np.all(traj.q <= model.upper + 1e-12), "inside the limits"
    a, i = angles["cartesian_error"]["hand"]["p95_mm"], solved["cartesian_error"]["hand"]["p95_mm"]
    assert i < 0.8 * a, f"IK's hand {i:.1f} mm (p95) against the angles' {a:.1f} mm"
    assert sum(solved["ik"].values()) == solved["frames"]["count"], "every frame solved one way or another"


def test_the_view_overlays_the_captured_arm_on_the_retargeted_one(tmp_path):
    """view --motion retargeted.csv --source CLIP.bvh: at each time the captured arm (orange) is
    where the retargeted arm is, within the filter's few millimetres, and hidden during the lead-in;
    a clip the motion did not come from is one line."""
    from servodyn.tools.view import ViewError, open_view
    model = load_model("human_arm")
    bvh, csv = tmp_path / "f.bvh", tmp_path / "f.csv"
    assert main(["export-bvh", "tennis_forehand", "-o", str(bvh)]) == 0
    assert main(["retarget", str(bvh), "-o", str(csv)]) == 0
    v = open_view("human_arm", motion=str(csv), source=str(bvh), port=0, say=quiet)
    try:
        lead = v.source.t[0]
        v.seek(0.5 * lead)
        assert not v.source.handle.visible, "no captured arm before the clip starts"
        for j in (60, 132, 180):          # frames of the swing, the fastest (contact) among them
            t = float(v.source.t[j])
            v.seek(t)
            k = v.timeline.index(t)
            elbow, wrist, _ = ArmTarget.of(model).points(v.timeline.planned[k][None])
            drawn = v.source.handle.points          # (3 segments, 2 ends, 3)
            assert v.source.handle.visible
            assert np.linalg.norm(drawn[0, 1] - elbow[0]) < 0.01, "the captured elbow on the arm's"
            assert np.linalg.norm(drawn[1, 1] - wrist[0]) < 0.01, "the captured wrist on the arm's"
    finally:
        v.close()
    other = tmp_path / "other.bvh"
    clip = parse_bvh(bvh.read_text())
    other.write_text(format_bvh(clip.with_motion(clip.motion[:100]), 6))         # a shorter clip
    with pytest.raises(ViewError, match="--source overlays"):
        open_view("human_arm", motion=str(csv), source=str(other), port=0,
                  say=quiet)


def test_export_bvh_asks_before_replacing_a_file(tmp_path, monkeypatch, capsys):
    """An existing OUT.bvh (perhaps a capture) is replaced only on a yes: 'n' keeps it (exit 1),
    --yes replaces it."""
    import io
    out = tmp_path / "clip.bvh"
    out.write_text("a capture\n")
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["export-bvh", "tennis_forehand", "-o", str(out)]) == 1
    assert out.read_text() == "a capture\n" and "kept as it was" in capsys.readouterr().err
    assert main(["export-bvh", "tennis_forehand", "-o", str(out), "--yes"]) == 0
    assert out.read_text().startswith("HIERARCHY"), "replaced on --yes"


@needs_clips
def test_the_left_arm_is_mirrored_onto_the_right_arm(tmp_path):
    """CMU 01_01's left arm onto human_arm (a right arm): mirrored, so its hinge is found as the
    right arm's is (30° off, residual under 1°) and no frame leaves the limits."""
    model = load_model("human_arm")
    report = run_retarget(str(CLIPS / "01_01.bvh"), model=model, arm="left", time="2:6", output=tmp_path / "l.csv",
                          say=quiet)
    assert abs(abs(report["calibration"]["twist_deg"]) - 30.0) < 1.0 and report["calibration"]["residual_p95_deg"] < 1
    assert report["limit_hits"] == {} and report["chain"]["upper_arm"] == "LeftArm"
    assert report["cartesian_error"]["hand"]["p95_mm"] < 20.0
