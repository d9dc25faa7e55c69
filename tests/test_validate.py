"""The offline validator (host/report/validation.py): torques against Pinocchio, one motion per check
built to break exactly that check, the margin, the fit, and one line with exit 2 for bad input."""

import copy
import csv
import dataclasses
import json
import tomllib

import numpy as np
import pytest

from servodyn.hal.config import CONFIGS_DIR, config_from_dict, load_config
from servodyn.hal.dynamixel.control_table import XM540_W270
from servodyn.control.motion import motion_path
from servodyn.report.validation import validate
from servodyn.validation import CHECKS, Limits, check

from helpers import quiet, run_cli

with open(CONFIGS_DIR / "replica.toml", "rb") as f:
    REPLICA = tomllib.load(f)
ABDUCTED = [0.0, 1.4, 0.0, 0.0, 0.0, 0.0, 0.0]     # the arm held out sideways: the shoulder carries it


def config(mutate=None):
    data = copy.deepcopy(REPLICA)
    if mutate is not None:
        mutate(data)
    return config_from_dict(data, origin="test.toml", base=CONFIGS_DIR)


def write_csv(path, names, t, q, qd, qdd):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t"] + [f"{p}_{n}" for p in ("q", "qd", "qdd") for n in names])
        w.writerows(np.hstack([t[:, None], q, qd, qdd]).tolist())
    return str(path)


def hold(path, names, pose, seconds=1.0):
    t = np.arange(int(round(seconds / 1e-3)) + 1) * 1e-3
    q = np.tile(pose, (len(t), 1))
    return write_csv(path, names, t, q, 0 * q, 0 * q)


def ramp(path, names, joint, speed, accel=0.0, seconds=0.5, start=None):
    """Joint `joint` at constant acceleration from `speed` (constant speed when accel is 0)."""
    t = np.arange(int(round(seconds / 1e-3)) + 1) * 1e-3
    q = np.tile(np.zeros(len(names)) if start is None else start, (len(t), 1))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    q[:, joint] += speed * t + accel * t**2 / 2
    qd[:, joint] = speed + accel * t
    qdd[:, joint] = accel
    return write_csv(path, names, t, q, qd, qdd)


def failing(report):
    return {v["check"] for v in report["violations"]}


def test_peak_torques_are_pinocchios(twin, tmp_path):
    """The report's peak torques are the RNEA of every sample: Pinocchio's on the exported URDF,
    within 1e-9 relative, for the swing and with a 0.5 kg payload at the hand (added to
    Pinocchio's own inertia of the hand at its centre of mass)."""
    cfg = load_config("replica")
    traj = motion_path("tennis_forehand", cfg.model).at_scale(1.0)
    pin = twin(cfg.model)
    expected = np.abs([pin.rnea(q, qd, qdd) for q, qd, qdd in zip(traj.q, traj.qd, traj.qdd)]).max(axis=0)
    report = validate(cfg, "tennis_forehand", time_scale=1.0, say=quiet)
    peaks = np.array([report["joints"][d]["peak_torque_nm"] for d in cfg.model.dof_names])
    assert np.abs(peaks - expected).max() <= 1e-9 * np.abs(expected).max(), f"{peaks} vs Pinocchio {expected}"

    hand = pin.model.getJointId(cfg.model.bodies[-1].dofs[-1].name)
    inertia = pin.model.inertias[hand]
    pin.model.inertias[hand] = inertia + pin.pin.Inertia(0.5, inertia.lever, np.zeros((3, 3)))
    pin.data = pin.model.createData()
    expected = np.abs([pin.rnea(q, qd, qdd) for q, qd, qdd in zip(traj.q, traj.qd, traj.qdd)]).max(axis=0)
    report = validate(cfg, "tennis_forehand", time_scale=1.0, payload=0.5, say=quiet)
    peaks = np.array([report["joints"][d]["peak_torque_nm"] for d in cfg.model.dof_names])
    assert np.abs(peaks - expected).max() <= 1e-9 * np.abs(expected).max(), "the payload as Pinocchio carries it"
    assert report["payload"]["body"] == "r_hand"


def test_the_replica_swing_at_human_speed_and_slower():
    """At human speed the replica's servos cannot swing (the shoulder rotation needs 8 rad/s, an
    XM540-W270 turns 3.1); at 3x everything is within the limits; with 20 % in reserve 3x fails on
    the shoulder rotation's speed and 4x (the configuration's time scale) passes."""
    cfg = load_config("replica")
    human = validate(cfg, "tennis_forehand", time_scale=1.0, say=quiet)
    assert not human["passed"] and {"speed", "torque_speed"} <= failing(human), failing(human)
    rotation = human["joints"]["r_shoulder_rotation"]
    assert rotation["peak_speed_rad_s"] > 2.5 * XM540_W270.no_load_speed, "the swing's 8 rad/s"
    assert validate(cfg, "tennis_forehand", time_scale=3.0, say=quiet)["passed"]
    reserve = validate(cfg, "tennis_forehand", time_scale=3.0, margin=0.8, say=quiet)
    assert not reserve["passed"] and reserve["joints"]["r_shoulder_rotation"]["worst_check"] in ("speed", "torque_speed")
    assert validate(cfg, "tennis_forehand", time_scale=4.0, margin=0.8, say=quiet)["passed"]


def test_fit_finds_the_smallest_passing_time_scale():
    """The fitted scale passes and 0.2 % faster fails (the bisection stops at 0.1 %)."""
    cfg = load_config("replica")
    report = validate(cfg, "tennis_forehand", time_scale=1.0, margin=0.8, fit=True, say=quiet)
    scale = report["fit_time_scale"]
    assert 3.0 < scale < 4.0, f"between the 3x that fails and the 4x that passes with 20 % reserve: {scale}"
    assert validate(cfg, "tennis_forehand", time_scale=scale, margin=0.8, say=quiet)["passed"]
    assert not validate(cfg, "tennis_forehand", time_scale=scale * 0.998, margin=0.8, say=quiet)["passed"]


# --- one motion per check, each breaking that check alone --------------------------------------

def test_position(tmp_path):
    """The wrist configured to 0.5 rad of flexion, held at 0.6 (inside the model's 1.40)."""
    def narrow(data):
        data["joint"][5]["position_limits"] = [-0.5, 0.5]
    cfg = config(narrow)
    pose = np.zeros(7)
    pose[5] = 0.6
    report = validate(cfg, hold(tmp_path / "m.csv", cfg.model.dof_names, pose), say=quiet)
    assert failing(report) == {"position"}, report["violations"]
    v = report["violations"][0]
    assert (v["dof"], v["value"], v["limit"]) == ("r_wrist_flexion", pytest.approx(0.6), 0.5)


def test_speed_and_within_one_percent(tmp_path):
    """The wrist's velocity limit set to 1 rad/s: 1.01 rad/s fails on speed alone, 0.99 passes."""
    def slow(data):
        data["joint"][5]["velocity_limit"] = 1.0
    cfg = config(slow)
    names = cfg.model.dof_names
    over = validate(cfg, ramp(tmp_path / "over.csv", names, 5, 1.01), say=quiet)
    assert failing(over) == {"speed"}, over["violations"]
    assert over["violations"][0]["t_s"] == 0.0, "from the first sample"
    assert validate(cfg, ramp(tmp_path / "under.csv", names, 5, 0.99), say=quiet)["passed"], "1 % under the limit"


def test_torque_speed(tmp_path):
    """The elbow accelerated near its no-load speed: within its speed and current limits, but
    torque and speed together leave the envelope (driving quadrant). At 20 rad/s², 2 N m (0.9 N m of
    it the XM430-W350's rotor, armature 0.045 kg m²); at the 50 rad/s² this used before the
    rotor was modelled, 4 N m pass the current limit too."""
    cfg = config()
    names = cfg.model.dof_names
    report = validate(cfg, ramp(tmp_path / "m.csv", names, 3, 3.8, accel=20.0, seconds=0.004,
                                start=np.array([0, 0, 0, 1.0, 0, 0, 0])), say=quiet)
    assert failing(report) == {"torque_speed"}, report["violations"]
    row = report["joints"]["r_elbow_flexion"]
    assert row["checks"]["speed"] < 1 and row["checks"]["current"] < 1, row["checks"]


def test_current(tmp_path):
    """The shoulder abduction holding the arm out, its current limit set between the motor current
    the torque needs and that plus the no-load current: only the current check fails."""
    cfg = load_config("replica")
    tau = cfg.model.inverse_dynamics(np.array(ABDUCTED), np.zeros(7), np.zeros(7))[1]
    motor = tau / cfg.joints[1].torque_constant

    def tight(data):
        data["joint"][1]["current_limit"] = motor + XM540_W270.no_load_current / 2
    cfg = config(tight)
    report = validate(cfg, hold(tmp_path / "m.csv", cfg.model.dof_names, ABDUCTED), say=quiet)
    assert failing(report) == {"current"}, report["violations"]
    assert report["violations"][0]["dof"] == "r_shoulder_abduction"


@pytest.mark.slow
def test_temperature(tmp_path):
    """The arm held out with a 1 kg payload at the hand, 40 plays of 10 s in a row: the shoulder
    abduction stays within its current limit but its winding passes 80 °C."""
    cfg = config()
    motion = hold(tmp_path / "m.csv", cfg.model.dof_names, ABDUCTED, seconds=10.0)
    once = validate(cfg, motion, payload=1.0, say=quiet)
    assert once["passed"], once["violations"]
    report = validate(cfg, motion, payload=1.0, repeat=40, say=quiet)
    assert failing(report) == {"temperature"}, report["violations"]
    v = report["violations"][0]
    assert v["dof"] == "r_shoulder_abduction" and v["value"] > 80.0 and v["limit"] == 80.0


def test_supply(tmp_path):
    """A supply rated below what holding the arm out draws."""
    cfg = config()
    motion = hold(tmp_path / "m.csv", cfg.model.dof_names, ABDUCTED)
    drawn = validate(cfg, motion, say=quiet)["supply"]["peak_current_a"]

    def weak(data):
        data["supply"] = {"voltage": 12.0, "current_limit": 0.5 * drawn}
    report = validate(config(weak), motion, say=quiet)
    assert failing(report) == {"supply"}, report["violations"]
    assert report["violations"][0]["dof"] is None, "the supply is the robot's, not a joint's"


def test_bus(tmp_path):
    """At 57,600 baud the worst tick's 239 bytes take 41 ms, far over the 1 ms period: an ordinary
    tick's 162 and, on the one in a hundred whose read runs on to Present Temperature, 11 more a
    servo (7 x 11 = 77)."""
    def slow(data):
        data["bus"]["arm"]["baud"] = 57600
    cfg = config(slow)
    report = validate(cfg, hold(tmp_path / "m.csv", cfg.model.dof_names, np.zeros(7)), say=quiet)
    assert failing(report) == {"bus"}, report["violations"]
    assert report["violations"][0]["value"] == pytest.approx((162 + 7 * 11) * 10 / 57600)


def test_the_bus_is_checked_against_the_configurations_period(tmp_path):
    """replica_can's seven motors put 14 frames of up to 135 bits on the 1 Mbit/s bus each tick,
    1.89 ms: over a 1 ms period, 76 % of the configuration's own 2.5 ms, where the motion is
    sampled too."""
    cfg = load_config("replica_can")
    pose = hold(tmp_path / "m.csv", cfg.model.dof_names, np.zeros(7))
    report = validate(cfg, pose, say=quiet)
    assert report["passed"] and report["sample_period_s"] == pytest.approx(2.5e-3), \
        f"passes, sampled every 2.5 ms: {report['sample_period_s']}"
    at_1khz = validate(dataclasses.replace(cfg, control_period=1e-3), pose, say=quiet)
    assert failing(at_1khz) == {"bus"}, at_1khz["violations"]
    assert at_1khz["violations"][0]["value"] == pytest.approx(14 * 135 / 1e6), "the wire's worst case a tick"


def test_a_csv_is_played_from_its_own_first_row(tmp_path):
    """A CSV sampled every 0.5 ms from t = 5 s: played at 1 ms, tick k is its sample 2k (on the
    CSV's clock from its first row), not sample k, nor the last because t = 5 s lies beyond k = 0;
    the interpolant passes through every sample, so it differs from the row only by rounding."""
    names = load_config("replica").model.dof_names
    t = 5.0 + np.arange(401) * 0.5e-3
    q = np.zeros((len(t), 7))
    q[:, 3] = 0.5 + 0.2 * np.sin(10 * (t - 5.0))
    played = motion_path(write_csv(tmp_path / "fine.csv", names, t, q, 0 * q, 0 * q),
                         load_config("replica").model).at_scale(1.0, 1e-3)
    assert len(played.t) == 201, f"0.2 s at 1 ms: {len(played.t)} samples"
    assert np.allclose(played.q[:, 3], q[::2, 3], rtol=0, atol=1e-12), "every other row of the CSV, from its first"
    assert np.allclose(played.qd, 0, atol=1e-6), "the CSV's own qd (zero here) at its samples, not the spline's"


def test_a_coarse_csv_keeps_its_own_velocities(tmp_path):
    """A CSV every 50 ms with its own qd and qdd of a known motion (q = 0.3 sin 2t): sampled at
    1 ms, the quintic Hermite through its samples follows the motion between them to 1e-6 rad
    (a spline of q alone is off by ~1e-4 rad and ignores the columns); and at the samples the
    velocity is the file's, even where it is not the motion's (a column changed on purpose)."""
    names = load_config("replica").model.dof_names
    t = np.arange(21) * 0.05
    q, qd, qdd = (np.zeros((len(t), 7)) for _ in range(3))
    q[:, 3], qd[:, 3], qdd[:, 3] = 0.5 + 0.3 * np.sin(2 * t), 0.6 * np.cos(2 * t), -1.2 * np.sin(2 * t)
    model = load_config("replica").model
    played = motion_path(write_csv(tmp_path / "coarse.csv", names, t, q, qd, qdd), model).at_scale(1.0, 1e-3)
    exact = 0.5 + 0.3 * np.sin(2 * played.t)
    assert np.abs(played.q[:, 3] - exact).max() < 1e-6, np.abs(played.q[:, 3] - exact).max()
    qd[10, 3] = 1.0
    bent = motion_path(write_csv(tmp_path / "bent.csv", names, t, q, qd, qdd), model).at_scale(1.0, 1e-3)
    assert bent.qd[500, 3] == pytest.approx(1.0, abs=1e-9), "the file's own velocity at its sample (t = 0.5 s)"


def test_command_range_and_its_quantization():
    """On Dynamixel the wire commands Goal Current within ±Current Limit in 2.69 mA units: the
    range is the current limit's torque (so the current check, which adds the no-load current,
    always trips first: the check exists for CAN dialects' TMAX), the step one unit's torque."""
    cfg = load_config("replica")
    limits = Limits.of(cfg, 12.0)
    assert limits.command_step[0] == pytest.approx(2.69e-3 * 2.409), "one current unit at the shoulder"
    assert limits.command[0] == pytest.approx(round(4.4 / 2.69e-3) * 2.69e-3 * 2.409)
    result = check(cfg.model, limits, motion_path("tennis_forehand", cfg.model).at_scale(1.0))
    assert np.all(result.ratios["command_range"] <= result.ratios["current"]), "current trips first"


@pytest.mark.slow
def test_every_check_is_in_the_report(tmp_path):
    report = validate(load_config("replica"), "tennis_forehand", time_scale=4.0, out=tmp_path, say=quiet)
    saved = json.loads((tmp_path / "report.json").read_text())
    assert saved["passed"] and saved["time_scale"] == 4.0 and saved["duration_s"] == pytest.approx(7.2)
    for row in saved["joints"].values():
        assert set(row["checks"]) == set(CHECKS)
        for key in ("peak_torque_nm", "peak_speed_rad_s", "peak_current_a", "peak_temperature_c",
                    "worst_check", "worst_ratio", "passed"):
            assert key in row, key
    assert (tmp_path / "envelopes.png").stat().st_size > 10_000, "the torque-speed planes were drawn"
    assert report["violations"] == []


# --- the command line -----------------------------------------------------------------------------

@pytest.mark.slow
def test_cli_exit_status(tmp_path):
    """0 pass, 1 fail with the first violation in one line, 2 bad input with one line."""
    ok = run_cli("validate", "replica", "tennis_forehand", "--time-scale", 4, "--out", tmp_path / "a")
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert json.loads((tmp_path / "a" / "report.json").read_text())["passed"], "the report says so too"
    bad = run_cli("validate", "replica", "tennis_forehand", "--time-scale", 1, "--out", tmp_path / "b")
    assert bad.returncode == 1, bad.stdout + bad.stderr
    first = json.loads((tmp_path / "b" / "report.json").read_text())["violations"][0]
    assert first["dof"] == "r_shoulder_rotation", "at time scale 1 the upper arm's rotation is the first too fast"
    assert first["message"] in bad.stdout + bad.stderr, "the first violation printed, in one line"


@pytest.mark.parametrize("args, words", [
    (["replica", "no_such_motion"], ["no_such_motion"]),
    (["no_such_config", "tennis_forehand"], ["no_such_config"]),
    (["replica", "tennis_forehand", "--time-scale", "-1"], ["--time-scale"]),
    (["replica", "tennis_forehand", "--time-scale", "0"], ["--time-scale"]),
    (["replica", "tennis_forehand", "--time-scale", "nan"], ["--time-scale"]),
    (["replica", "tennis_forehand", "--time-scale", "inf"], ["--time-scale"]),
    (["replica", "tennis_forehand", "--time-scale", "1e9"], ["time scale 1e+09", "at most 600 s"]),
    (["replica", "tennis_forehand", "--time-scale", "1e-6"], ["time scale 1e-06", "too fast"]),
    (["replica", "tennis_forehand", "--margin", "0"], ["--margin"]),
    (["replica", "tennis_forehand", "--repeat", "0"], ["--repeat"]),
    (["replica", "tennis_forehand", "--repeat", "100000000"], ["--repeat", "10000"]),
    (["replica", "tennis_forehand", "--supply-voltage", "nan"], ["--supply-voltage"]),
    (["replica", "tennis_forehand", "--payload", "-2"], ["payload"]),
    (["replica", "tennis_forehand", "--payload", "1", "--payload-body", "tail"], ["tail"]),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, args, words):
    res = run_cli("validate", *args, "--out", tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("servodyn: error:"), res.stderr
    for word in words:
        assert word in lines[0], (word, lines[0])


def test_cli_bad_csv(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,q_nothing\n0,0\n0.1,0.1\n")
    res = run_cli("validate", "replica", bad, "--out", tmp_path)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr


@pytest.mark.slow
def test_retime_is_faster_than_the_uniform_fit_and_passes(tmp_path):
    """TOPP-RA plans the forehand to the linearised envelope: the result passes the dense check
    (re-read from the CSV it writes, the way `servodyn swing --motion` would play it) and is
    shorter than the uniform fit, which slows every part of the swing alike."""
    cfg = load_config("replica")
    report = validate(cfg, "tennis_forehand", time_scale=1.0, fit=True, retime_motion=True, out=tmp_path, say=quiet)
    retimed = report["retime"]
    assert retimed["passed"], retimed
    fitted = report["fit_time_scale"] * 1.8
    assert retimed["duration_s"] < fitted, f"TOPP-RA {retimed['duration_s']:.2f} s vs uniform {fitted:.2f} s"
    assert retimed["trimmed_rad"] < 1e-5, "cutting the rest at the ends moves the joints by nothing visible"
    again = validate(cfg, retimed["file"], say=quiet)
    assert again["passed"], again["violations"][:1]
    assert again["duration_s"] == pytest.approx(retimed["duration_s"], abs=1e-3)


@pytest.mark.slow
def test_prediction_confirmed_by_simulation(tmp_path):
    """The forehand at human speed on the simulated servos: the first servo to saturate is the one
    the validator names first, within a few ticks of its time. At 3x, where it passes, no servo
    saturates and the swing tracks within 5 degrees."""
    cfg = load_config("replica")
    fails = validate(cfg, "tennis_forehand", time_scale=1.0, simulate_motion=True, out=tmp_path / "fast", say=quiet)["simulation"]
    first = fails["first"]
    assert first["saturated"]["dof"] == first["predicted"]["dof"] == "r_shoulder_rotation", first
    assert abs(first["ticks_apart"]) <= 10, f"first saturation {first['ticks_apart']} ticks from the prediction"
    passes = validate(cfg, "tennis_forehand", time_scale=3.0, simulate_motion=True, out=tmp_path / "slow", say=quiet)
    assert passes["passed"] and passes["simulation"]["first"]["saturated"] is None, passes["simulation"]["first"]
    assert passes["simulation"]["tracks"], f"tracking max {np.degrees(passes['simulation']['tracking_max_rad']):.2f} deg"


def test_the_envelope_follows_the_supply_voltage():
    """The data sheet's rows at 11.1, 12 and 14.8 V, linear between them: at 14.8 V an XM540-W270
    turns 37 rpm and stalls at 12.9 N m (e-manual), at 11.1 V 28 rpm and 10.0 N m; the forehand's
    worst torque-speed ratio falls as the voltage rises."""
    cfg = load_config("replica")
    rpm = 2 * np.pi / 60
    high, low = Limits.of(cfg, 14.8), Limits.of(cfg, 11.1)
    assert high.no_load_speed[0] == pytest.approx(37 * rpm) and high.stall_torque[0] == pytest.approx(12.9)
    assert low.no_load_speed[0] == pytest.approx(28 * rpm) and low.stall_torque[0] == pytest.approx(10.0)
    worst = [validate(cfg, "tennis_forehand", time_scale=3.0, supply_voltage=v, say=quiet)["joints"]
             ["r_shoulder_rotation"]["checks"]["torque_speed"] for v in (11.1, 12.0, 14.8)]
    assert worst[0] > worst[1] > worst[2], f"torque-speed ratios at 11.1, 12, 14.8 V: {worst}"


def test_cli_csv_whose_spline_overflows(tmp_path):
    """Given qd and qdd, the reader never splines q, but the validator does between samples
    coarser than the control period: values near the double range made scipy raise (after ten
    lines of RuntimeWarnings) a message naming no file."""
    names = load_config("replica").model.dof_names
    t = np.array([0.0, 1.0, 2.0, 3.0])
    q = np.tile(np.array([0.0, 1e308, -1e308, 0.0])[:, None], (1, len(names)))
    path = write_csv(tmp_path / "huge.csv", names, t, q, 0 * q, 0 * q)
    res = run_cli("validate", "replica", path, "--out", tmp_path / "out")
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert "huge.csv: the motion between the samples overflows" in lines[0], lines[0]


@pytest.mark.slow
def test_identified_friction_scale_thermal_and_payload_change_the_checks(tmp_path):
    """The configuration's identified numbers are what the checks use. The elbow spun at a constant
    1 rad/s: with 0.3 N m of Coulomb and 0.1 N m s/rad of viscous friction the torque it needs is
    the rigid body's + 0.4 N m, and with torque_constant_scale 0.8 its current is that over
    0.8 x 1.783 N m/A (each to 1e-9: the same arithmetic); a [payload] of 0.5 kg is the model's
    (its hold torque equals --payload 0.5's, 1e-9); thermal constants of 24 K/W, 60 s heat the
    abduction more than the data sheet's 6 K/W, 420 s over the same hold."""
    names = load_config("replica").model.dof_names
    elbow = names.index("r_elbow_flexion")
    start = np.zeros(7)
    start[elbow] = 0.5
    motion = ramp(tmp_path / "spin.csv", names, elbow, 1.0, seconds=0.5, start=start)
    nominal = config()

    def identified(data):
        data["joint"][elbow].update(friction_coulomb_nm=0.3, friction_viscous_nm_s=0.1, torque_constant_scale=0.8)
    tuned = config(identified)
    path = motion_path(motion, nominal.model)
    base = check(nominal.model, Limits.of(nominal, 12.0), path.at_scale(1.0, 1e-3))
    got = check(tuned.model, Limits.of(tuned, 12.0), path.at_scale(1.0, 1e-3))
    moving = np.abs(base.qd[:, elbow]) > 0.5
    assert np.allclose(got.tau[moving, elbow], base.tau[moving, elbow] + 0.4, atol=1e-9), "RNEA + F_c + F_v q̇"
    no_load = tuned.joints[elbow].servo.no_load_current
    expected = np.abs(got.tau[:, elbow]) / (0.8 * 1.783) + no_load
    assert np.allclose(got.current[:, elbow], expected, atol=1e-9), "current through the scaled torque constant"
    assert got.peak("current")[elbow] > 1.5 * base.peak("current")[elbow], "a larger current ratio"

    loaded = config(lambda d: d.update(payload={"mass_kg": 0.5}))
    held = hold(tmp_path / "hold.csv", names, ABDUCTED, seconds=5.0)
    with_table = validate(loaded, held, say=quiet)
    with_flag = validate(nominal, held, payload=0.5, say=quiet)
    for dof in names:
        assert with_table["joints"][dof]["peak_torque_nm"] == pytest.approx(
            with_flag["joints"][dof]["peak_torque_nm"], abs=1e-9), f"{dof}: [payload] is --payload"

    def hot(data):
        data["joint"][1].update(thermal_resistance_k_w=24.0, thermal_time_constant_s=60.0)
    datasheet = with_flag["joints"]["r_shoulder_abduction"]["peak_temperature_c"]
    assert validate(config(hot), held, payload=0.5, say=quiet)["joints"]["r_shoulder_abduction"][
        "peak_temperature_c"] > datasheet + 5.0, "the configured thermal constants, not the data sheet's"
