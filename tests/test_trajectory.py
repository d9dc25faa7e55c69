"""Keyframe motions (firmware/core/trajectory.c through host/control/motion.py): C2 continuity, rest at
the ends, the built-in forehand, and clear errors for bad keyframe files and trajectories."""

import textwrap

import numpy as np
import pytest

import servodyn
from servodyn.control.motion import Motion, check_limits, load_motion
from servodyn.control.trajectory import TrajectoryError

ARM = servodyn.load_model("human_arm")


def test_forehand_is_c2_at_every_keyframe():
    """Left and right limits of q, qd, qdd agree at every keyframe (1e-9 s either side, against
    the scale of each derivative), and the samples match finite differences inside segments."""
    motion = load_motion("tennis_forehand", ARM)
    assert motion.duration == pytest.approx(1.8), "the forehand's keyframes span 1.8 s"
    h = 1e-9
    for t in motion.t[1:-1] - motion.t[0]:
        left, right = motion.at(t - h), motion.at(t + h)
        for k, (a, b) in enumerate(zip(left, right)):
            scale = np.abs(motion.at(np.linspace(0, motion.duration, 1801))[k]).max()
            assert np.abs(a - b).max() <= 1e-6 * scale, f"derivative {k} jumps at t = {t:.3f}"
    t = np.linspace(0.01, 1.79, 300)
    q, qd, qdd = motion.at(t)
    d = 1e-6
    assert np.allclose(qd, (motion.at(t + d)[0] - motion.at(t - d)[0]) / (2 * d), atol=1e-6), \
        "qd is not the central difference of q"
    assert np.allclose(qdd, (motion.at(t + d)[1] - motion.at(t - d)[1]) / (2 * d), atol=1e-4), \
        "qdd is not the central difference of qd"


def test_forehand_starts_and_ends_at_rest_inside_the_limits():
    traj = load_motion("tennis_forehand", ARM).sample(1e-3)
    for k in (0, -1):
        assert np.abs(traj.qd[k]).max() == 0 and np.abs(traj.qdd[k]).max() == 0, \
            f"sample {k}: not at rest (zero velocity and acceleration) at the swing's end"
    assert np.all(traj.q >= ARM.lower) and np.all(traj.q <= ARM.upper), "a sample outside human_arm's joint limits"
    abduction = traj.q[:, ARM.dof_names.index("r_shoulder_abduction")]
    assert np.abs(abduction).max() <= np.radians(75), "the swing keeps away from the shoulder's lock"


def test_time_scaling():
    motion = load_motion("tennis_forehand", ARM)
    slow = motion.sample(1e-3, time_scale=2.0)
    fast = motion.sample(1e-3)
    assert slow.t[-1] == pytest.approx(3.6), "twice the 1.8 s forehand"
    assert np.allclose(slow.q[::2], fast.q, atol=1e-12), "the same poses at twice the time"
    assert np.allclose(slow.qd[::2], fast.qd / 2, atol=1e-12), "twice as slow: half the velocity"
    assert np.allclose(slow.qdd[::2], fast.qdd / 4, atol=1e-12), "twice as slow: a quarter of the acceleration"


def frames(body: str) -> str:
    names = ARM.dof_names
    zero = ", ".join(f"{n} = 0.0" for n in names)
    return "name = 'x'\nmodel = 'human_arm'\n" + textwrap.dedent(body).replace("ZERO", zero)


@pytest.mark.parametrize("body,message", [
    ("[[keyframe]]\nt = 0.0\nq = { ZERO }\n", "at least two"),
    ("[[keyframe]]\nt = 0.0\nq = { ZERO }\n[[keyframe]]\nt = 0.0\nq = { ZERO }\n", "keyframe 2: time must increase"),
    ("[[keyframe]]\nt = 0.0\nq = { ZERO }\n[[keyframe]]\nt = 1.0\nq = { r_elbow_flexion = 1.0 }\n", "keyframe 2: missing dof 'r_shoulder_flexion'"),
    ("[[keyframe]]\nt = 0.0\nq = { ZERO, r_knee = 1.0 }\n[[keyframe]]\nt = 1.0\nq = { ZERO }\n", "unknown dof 'r_knee'"),
    ("[[keyframe]]\nt = 0.0\nq = { ZERO }\n[[keyframe]]\nt = 'soon'\nq = { ZERO }\n", "keyframe 2: 't' must be a finite number"),
    ("[[keyframe]]\nt = 0.0\nq = { ZERO }\n[[keyframe]]\nt = 1.0\nq = { ZERO }\n[[keyframe]]\nt = 2.0\nq = { ZERO }\n[keyframe.q]\n", "not valid TOML"),
    ("keyframe = [0, 1]\n", "at least two \\[\\[keyframe\\]\\] entries"),   # not tables: an AttributeError before
])
def test_bad_keyframe_files(tmp_path, body, message):
    path = tmp_path / "bad.toml"
    path.write_text(frames(body))
    with pytest.raises(TrajectoryError, match=message) as err:
        load_motion(path, ARM)
    assert "\n" not in str(err.value)


def test_keyframes_beyond_a_joint_limit_name_the_dof_and_time(tmp_path):
    body = "[[keyframe]]\nt = 0.0\nq = { ZERO }\n[[keyframe]]\nt = 1.0\nq = { ZERO }\n"
    text = frames(body).replace("r_elbow_flexion = 0.0", "r_elbow_flexion = 3.0", 1)
    path = tmp_path / "far.toml"
    path.write_text(text)
    with pytest.raises(TrajectoryError, match=r"t = 0.000 s \(sample 1\), dof 'r_elbow_flexion': position 3 rad beyond the limit 2.618"):
        load_motion(path, ARM)


def test_velocity_and_acceleration_limits():
    traj = load_motion("tennis_forehand", ARM).sample(1e-3)
    check_limits(traj, ARM, velocity=9.0, acceleration=400.0)
    with pytest.raises(TrajectoryError, match="dof 'r_shoulder_rotation': speed 7.*rad/s beyond the limit 7 rad/s"):
        check_limits(traj, ARM, velocity=7.0)
    with pytest.raises(TrajectoryError, match="acceleration"):
        check_limits(traj, ARM, acceleration=10.0)


def test_bad_knots_from_the_core():
    with pytest.raises(TrajectoryError, match="strictly increasing"):
        Motion(name="m", model="human_arm", t=np.array([0.0, 1.0, 1.0]), q=np.zeros((3, 7)),
               dof_names=ARM.dof_names)


def test_keyframes_and_csv_round_trip(tmp_path):
    """save_motion then load_motion gives the same keyframes bit for bit; a sampled trajectory
    written as CSV reads back exactly, qd and qdd from the file (not re-derived)."""
    from servodyn.control.motion import save_motion
    from servodyn.control.trajectory import read_trajectory_csv, write_trajectory_csv
    motion = load_motion("tennis_forehand", ARM)
    save_motion(motion, tmp_path / "again.toml")
    again = load_motion(tmp_path / "again.toml", ARM)
    assert np.array_equal(again.t, motion.t) and np.array_equal(again.q, motion.q)
    assert again.phases == motion.phases, "each keyframe's phase name saved and read back"
    traj = motion.sample(1e-3)
    write_trajectory_csv(tmp_path / "swing.csv", traj, ARM.dof_names)
    back = read_trajectory_csv(tmp_path / "swing.csv", ARM.dof_names)
    assert not back.derived, "qd and qdd read from the CSV, not derived from a spline of q"
    for a, b in ((back.t, traj.t), (back.q, traj.q), (back.qd, traj.qd), (back.qdd, traj.qdd)):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("make,words", [
    (lambda p: p.write_bytes(bytes(range(256)) * 4), ["swing.toml", "not a text file"]),
    (lambda p: p.mkdir(), ["swing.toml", "is a folder"]),
])
def test_unreadable_keyframe_files_are_one_trajectory_error(tmp_path, make, words):
    make(tmp_path / "swing.toml")
    with pytest.raises(TrajectoryError) as err:
        load_motion(tmp_path / "swing.toml", ARM)
    assert "\n" not in str(err.value), str(err.value)
    for word in words:
        assert word in str(err.value), f"{word!r} not in: {err.value}"


@pytest.mark.parametrize("limit", [float("nan"), -1.0, 0.0])
def test_a_limit_that_is_not_positive_is_refused_not_ignored(limit):
    """NaN compares false, so a NaN limit used to switch the check off; -1 refused everything
    with a message about the trajectory rather than the limit."""
    traj = load_motion("tennis_forehand", ARM).sample(1e-2)
    for key in ("velocity", "acceleration"):
        with pytest.raises(TrajectoryError, match=r"limit must be a positive number of rad/s.*, got"):
            check_limits(traj, ARM, **{key: limit})
