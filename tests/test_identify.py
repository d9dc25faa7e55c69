"""Identification (servodyn.identification, servodyn identify, servodyn excite) on logs made with
the core's direct dynamics from known numbers, with the sensors' quantisation: encoder 4096 counts
per turn, velocity 0.229 rpm, current 2.69 mA (servodyn.identification.synthetic)."""

import csv
import json
import math

import numpy as np
import pytest
import tomlkit

from servodyn.control.trajectory import read_trajectory_csv
from servodyn.hal.config import load_config
from servodyn.identification import (IdentificationError, design_excitation, fit_thermal, identify,
                                     measured_torque, prepare)
from servodyn.identification.synthetic import Plant, simulate_log
from servodyn.loop.log import columns
from servodyn.tools.cli import main

pytestmark = pytest.mark.slow      # its plant's logs are whole runs

KNOWN_KG = 0.5
DURATION = 12.0          # s: one period of the excitation, 12 000 ticks at 1 kHz

# The estimator's standard errors come from its residuals, which here are the quantisation's
# noise; they assume independent rows, but the rows are 50 Hz samples of a 10 Hz low-pass, so
# neighbours are correlated and the true spread is about sqrt(50 / (2 x 10)) = 1.6 times wider:
# 4 sigma (two-sided 99.99 %) x 1.6 = 6.5 sigma. Besides the noise, the synthetic plant holds
# each tick's torque (zero-order hold) and smooths its Coulomb step (tanh, 1 mrad/s) where the
# model is continuous and sharp: 1 % of each value covers what that leaves (0.8 % measured on the
# armature of the shoulder, the largest).
SIGMAS = 6.5
MODEL_FLOOR = 0.01


@pytest.fixture(scope="module")
def replica():
    config = load_config("replica")
    model = config.model
    joints = [{j.dof: j for j in config.joints}[d] for d in model.dof_names]
    lower = np.array([j.position_limits[0] for j in joints])
    upper = np.array([j.position_limits[1] for j in joints])
    speed = np.array([j.velocity_limit for j in joints])
    excitation, _ = design_excitation(model, lower, upper, speed, DURATION, iterations=4)
    plant = Plant(payload_kg=0.3, coulomb=np.array([0.3, 0.3, 0.2, 0.15, 0.1, 0.08, 0.08]),
                  viscous=np.array([0.5, 0.5, 0.3, 0.2, 0.1, 0.05, 0.05]), armature=model.armature * 1.3,
                  torque_scale=np.array([1.1, 0.9, 1.15, 1.2, 0.85, 1.1, 0.9]))
    plain = simulate_log(model, joints, excitation.evaluate, DURATION, plant)
    loaded = simulate_log(model, joints, excitation.evaluate, DURATION,
                          Plant(**{**plant.__dict__, "payload_kg": plant.payload_kg + KNOWN_KG}))
    return dict(config=config, model=model, joints=joints, excitation=excitation, plant=plant,
                logs=[plain, loaded], lower=lower, upper=upper)


def _prepared(replica, log):
    return prepare(log["t"], log["q"], measured_torque(log["current"], replica["joints"]))


def _close(name, p, truth):
    assert p.determined, f"{name}: not determined ({p.note})"
    tol = SIGMAS * p.std + MODEL_FLOOR * abs(truth)
    assert abs(p.value - truth) <= tol, f"{name}: {p.value:.5g} ± {p.std:.2g}, true {truth:.5g} (tolerance {tol:.2g})"


def test_recovers_the_plant_with_a_known_payload(replica):
    """Two logs, the second carrying 0.5 kg more at the hand's centre of mass: friction, armature
    and the torque-constant scale of every joint, and the unknown 0.3 kg payload and where it is."""
    model, plant = replica["model"], replica["plant"]
    est = identify(model, replica["joints"], [_prepared(replica, log) for log in replica["logs"]],
                   known_payload=KNOWN_KG)
    for j, dof in enumerate(model.dof_names):
        got = est.joints[dof]
        _close(f"{dof} Coulomb", got["friction_coulomb_nm"], plant.coulomb[j])
        _close(f"{dof} viscous", got["friction_viscous_nm_s"], plant.viscous[j])
        _close(f"{dof} armature", got["armature_kg_m2"], plant.armature[j])
        _close(f"{dof} torque constant scale", got["torque_constant_scale"], plant.torque_scale[j])
    _close("payload mass", est.payload["mass_kg"], plant.payload_kg)
    hand = model.bodies[-1]
    assert est.payload["body"] == hand.name, "the payload body defaults to the last"
    for k, p in enumerate(est.payload["com_m"]):
        # a point 0.07 m from the hand's origin: each coordinate to a tenth of a millimetre's noise
        _close(f"payload com {'xyz'[k]}", p, hand.com[k])
    assert est.condition_number < 100, f"a well conditioned experiment, got {est.condition_number:.3g}"


def test_the_log_carrying_the_known_payload_is_named_not_placed(replica):
    """The loaded log given first and named so (loaded=0): the same numbers as in the usual order.
    Given first and taken for the last (the mass put on the log without it), the scales fit about
    -s (s(tau_without - tau_with) is the payload's torque): refused, not a payload of -1.5 kg."""
    model, plant = replica["model"], replica["plant"]
    plain, loaded = (_prepared(replica, log) for log in replica["logs"])
    est = identify(model, replica["joints"], [loaded, plain], known_payload=KNOWN_KG, loaded=0)
    _close("payload mass", est.payload["mass_kg"], plant.payload_kg)
    for j, dof in enumerate(model.dof_names):
        _close(f"{dof} torque constant scale", est.joints[dof]["torque_constant_scale"], plant.torque_scale[j])
    with pytest.raises(IdentificationError, match="negative on 7 of 7 joints"):
        identify(model, replica["joints"], [loaded, plain], known_payload=KNOWN_KG)


def test_a_payload_below_zero_is_not_determined(replica):
    """A model 0.6 kg heavier at the hand than the plant (which carries 0.3): the payload fits about
    -0.3 kg with a small standard error, which no payload has: not determined, and said why."""
    heavy = replica["model"].with_payload(0.6)
    est = identify(heavy, replica["joints"], [_prepared(replica, replica["logs"][0])])
    mass = est.payload["mass_kg"]
    assert mass.value is None and "below zero" in mass.note, mass
    assert all(c.value is None for c in est.payload["com_m"]), "nor is its centre of mass"


def test_one_log_leaves_the_torque_constant_free(replica):
    """Current and inertia alone leave each joint's scale free: not determined, said so."""
    est = identify(replica["model"], replica["joints"], [_prepared(replica, replica["logs"][0])])
    for dof, got in est.joints.items():
        scale = got["torque_constant_scale"]
        assert scale.value is None and "--known-payload" in scale.note, f"{dof}: {scale}"
    # the rest is in the measured torque's units, so off by the scale: the 0.3 kg payload reads
    # within the scales' spread (0.85 to 1.2) of its truth
    mass = est.payload["mass_kg"].value
    assert 0.3 * 0.8 <= mass <= 0.3 * 1.25, f"payload {mass:.3g} kg"
    assert any("torque constants taken as configured" in n and "--known-payload" in n for n in est.notes), \
        f"one log: the user is told the scales are assumed, and what identifies them: {est.notes}"
    # whatever the mismatch makes of the rest, no friction or armature is reported negative: a
    # negative one is not the joint's (seen on a 0.85 elbow: viscous -0.16 N m s) and says so
    for dof, got in est.joints.items():
        for key in ("friction_coulomb_nm", "friction_viscous_nm_s", "armature_kg_m2"):
            p = got[key]
            assert p.value is None or p.value >= 0, f"{dof} {key} = {p.value}"
            assert p.value is not None or "not determined" in p.note, f"{dof} {key}: {p.note}"


def test_a_negative_friction_is_not_reported_as_the_joints():
    from servodyn.identification.estimate import _judged
    got = _judged(-0.16, 0.01, "N m s", physical=True)
    assert got.value is None and "negative" in got.note and "--known-payload" in got.note, got
    assert _judged(0.05, 0.001, "N m s", physical=True).value == 0.05, "a positive one stands"


def test_one_move_of_a_second_determines_no_friction_or_armature(replica):
    """A heating run's log: the arm holds, makes one minimum-jerk move of 1.5 s, and holds again.
    Every joint moves one way only, for under 2 s: its friction and armature are not determined,
    said why, not fitted (before the rule, such a log gave armatures 30 % off with 6 % standard
    errors, from a few smooth, correlated samples)."""
    model, joints = replica["model"], replica["joints"]
    q0 = 0.5 * (replica["lower"] + replica["upper"])
    q1 = q0 + 0.3 * (replica["upper"] - q0)

    def move(t):
        s = np.clip((np.asarray(t, dtype=float) - 1.0) / 1.5, 0.0, 1.0)[..., None]
        p = 10 * s**3 - 15 * s**4 + 6 * s**5
        pd = (30 * s**2 - 60 * s**3 + 30 * s**4) / 1.5
        pdd = (60 * s - 180 * s**2 + 120 * s**3) / 1.5**2
        return q0 + p * (q1 - q0), pd * (q1 - q0), pdd * (q1 - q0)
    log = simulate_log(model, joints, move, 4.0, replica["plant"])
    est = identify(model, joints, [_prepared(replica, log)])
    for dof, entry in est.joints.items():
        for key in ("friction_coulomb_nm", "friction_viscous_nm_s", "armature_kg_m2"):
            p = entry[key]
            assert not p.determined, f"{dof} {key}: {p.value} ± {p.std} from one 1.5 s move"
            assert "one way" in p.note and "servodyn excite" in p.note, p.note


def test_thermal_constants_from_a_heating_run():
    """A winding heated by a constant current, read in whole degrees (as a Dynamixel reports):
    R_th and τ_th come back within the fit's own 6.5 sigma and 3 % (the 1 °C steps are not noise
    a least-squares error describes)."""
    r_th, tau, resistance, current = 6.0, 300.0, 2.7, 1.5
    t = np.arange(0.0, 1500.0, 0.01)
    # exact first-order response at the copper's rising resistance, integrated finely
    temp = np.empty_like(t)
    T = 25.0
    for k in range(len(t)):
        temp[k] = T
        power = current**2 * resistance * (1 + 0.00393 * (T - 25.0))
        T += 0.01 * (power - (T - 25.0) / r_th) / (tau / r_th)
    fit = fit_thermal(t, np.full_like(t, current), np.round(temp), resistance, ambient=25.0)
    for p, truth, name in ((fit.resistance_k_w, r_th, "R_th"), (fit.time_constant_s, tau, "tau_th")):
        assert p.determined, f"{name}: {p.note}"
        assert abs(p.value - truth) <= 6.5 * p.std + 0.03 * truth, f"{name}: {p.value:.4g} ± {p.std:.2g}, true {truth}"
    cold = fit_thermal(t[:1000], np.full(1000, 0.1), np.full(1000, 25.0), resistance)
    assert not cold.resistance_k_w.determined and "warms by 0.0 °C" in cold.resistance_k_w.note


# ------------------------------------------------------------------------ the commands


def write_log(path, model, log, drop=()):
    """A swing_log.csv as the loop writes it (loop.log.columns), without the `drop` quantities."""
    header = [c for c in columns(model.dof_names) if not any(c.startswith(d + "_") for d in drop)]
    tau = measured_torque(log["current"], load_config("replica").joints)
    data = {"t": log["t"]}
    for k, d in enumerate(model.dof_names):
        data.update({f"q_d_{d}": log["q"][:, k], f"q_{d}": log["q"][:, k], f"qd_{d}": log["qd"][:, k],
                     f"tau_{d}": tau[:, k], f"current_{d}": log["current"][:, k],
                     f"temperature_{d}": log["temperature"][:, k] if "temperature" in log else np.full(len(tau), np.nan)})
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(np.column_stack([data[c] for c in header]).tolist())
    return path


def test_identify_writes_the_report_the_patch_and_the_plot(replica, tmp_path, capsys):
    model = replica["model"]
    logs = [write_log(tmp_path / f"log{k}.csv", model, log) for k, log in enumerate(replica["logs"])]
    out = tmp_path / "id"
    code = main(["identify", "--config", "replica", str(logs[0]), str(logs[1]), "--known-payload", str(KNOWN_KG),
                 "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    result = json.loads((out / "identified.json").read_text())
    assert set(result["joints"]) == set(model.dof_names), "every dof"
    keys = {"friction_coulomb_nm", "friction_viscous_nm_s", "armature_kg_m2", "torque_constant_scale",
            "thermal_resistance_k_w", "thermal_time_constant_s"}
    assert all(set(entry) == keys for entry in result["joints"].values()), "the issue's keys, each with its std"
    scale = result["joints"]["r_elbow_flexion"]["torque_constant_scale"]
    assert abs(scale["value"] - 1.2) <= SIGMAS * scale["std"] + MODEL_FLOOR * 1.2, scale
    assert result["joints"]["r_elbow_flexion"]["thermal_resistance_k_w"]["value"] is None, \
        "no temperature column: the heat is not determined, and not invented"
    assert abs(result["payload"]["mass_kg"]["value"] - 0.3) <= 0.01, result["payload"]
    assert result["filter"]["lag_s"] == 0.0 and result["condition_number"] < 100
    patch = tomlkit.parse((out / "patch.toml").read_text())
    elbow = [t for t in patch["joint"] if t["dof"] == "r_elbow_flexion"][0]
    assert abs(elbow["friction_coulomb_nm"] - 0.15) <= 0.01, "the patch carries the determined values"
    assert abs(patch["payload"]["mass_kg"] - 0.3) <= 0.01 and patch["payload"]["body"] == model.bodies[-1].name
    assert (out / "torque_fit.png").stat().st_size > 10_000, "a plot of measured vs predicted torque"
    said = printed.out + printed.err
    assert "payload at r_hand" in said and "r_wrist_deviation" in said, "the summary table"


def test_a_joint_that_never_moves_is_said_in_one_line(replica, tmp_path, capsys):
    model = replica["model"]
    log = {k: np.array(v, copy=True) for k, v in replica["logs"][0].items()}
    held = model.dof_names.index("r_wrist_deviation")
    log["q"][:, held] = 0.1
    path = write_log(tmp_path / "held.csv", model, log)
    code = main(["identify", "--config", "replica", str(path), "--out", str(tmp_path / "id")])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    lines = [line for line in printed.err.splitlines() if "never moves" in line]
    assert len(lines) == 1 and "r_wrist_deviation" in lines[0], printed.err
    result = json.loads((tmp_path / "id" / "identified.json").read_text())
    assert result["joints"]["r_wrist_deviation"]["armature_kg_m2"]["value"] is None, "not invented"
    assert result["joints"]["r_elbow_flexion"]["armature_kg_m2"]["value"] is not None, "the others still are"


@pytest.mark.parametrize("case, message", [
    ("no_current", "no current_<dof> columns"),
    ("malformed", "a value that is not a number"),
    ("still", "no joint moves in the logs"),
])
def test_logs_that_identify_nothing_exit_2_in_one_line(replica, tmp_path, capsys, case, message):
    model = replica["model"]
    log = {k: np.array(v, copy=True) for k, v in replica["logs"][0].items()}
    if case == "still":
        log["q"][:] = 0.2
    path = write_log(tmp_path / "log.csv", model, log, drop=("current",) if case == "no_current" else ())
    if case == "malformed":
        text = path.read_text().splitlines()
        text[5] = text[5].replace(",", ",x", 1)
        path.write_text("\n".join(text) + "\n")
    code = main(["identify", "--config", "replica", str(path), "--out", str(tmp_path / "id")])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and message in err, err


@pytest.mark.parametrize("case", ["reversed", "one file twice", "a copy"])
def test_logs_whose_roles_are_unknown_exit_2_in_one_line(replica, tmp_path, capsys, case):
    """With --known-payload the last log carried the mass: given in the other order, or the same
    samples twice (one file, or two files holding the same rows), nothing separates the log with
    it from the one without it: refused in one line, no numbers written."""
    model = replica["model"]
    plain, loaded = (write_log(tmp_path / f"{name}.csv", model, log) for name, log in zip(("plain", "loaded"),
                                                                                           replica["logs"]))
    copy = tmp_path / "copy.csv"
    copy.write_bytes(plain.read_bytes())
    logs = {"reversed": [loaded, plain], "one file twice": [plain, plain], "a copy": [plain, copy]}[case]
    out = tmp_path / "id"
    code = main(["identify", "--config", "replica", *map(str, logs), "--known-payload", str(KNOWN_KG), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert not (out / "identified.json").exists(), "nothing reported as determined"


def test_excite_starts_and_ends_at_rest_inside_the_limits_and_passes_validate(tmp_path, capsys):
    out = tmp_path / "excite.csv"
    assert main(["excite", "--config", "replica", "--duration", "10", "--out", str(out)]) == 0, capsys.readouterr().err
    config = load_config("replica")
    model = config.model
    traj = read_trajectory_csv(out, model.dof_names)
    assert traj.t[-1] == pytest.approx(10.0, abs=1e-9), "whole periods of the duration asked"
    for k in (0, -1):
        # rest at both ends: the series' constraints make q̇ and q̈ zero there up to rounding
        assert np.abs(traj.qd[k]).max() <= 1e-9 and np.abs(traj.qdd[k]).max() <= 1e-9, (traj.qd[k], traj.qdd[k])
    lower = np.array([j.position_limits[0] for j in config.joints])
    upper = np.array([j.position_limits[1] for j in config.joints])
    inside = (traj.q >= lower + 0.1 * (upper - lower) - 1e-9) & (traj.q <= upper - 0.1 * (upper - lower) + 1e-9)
    assert inside.all(), "inside each joint's range less the 10 % margin at both ends"
    assert np.ptp(traj.q, axis=0).min() > math.radians(5), "every joint moves"
    capsys.readouterr()
    assert main(["validate", "replica", str(out), "--out", str(tmp_path / "validate")]) == 0, \
        "servodyn validate passes it on the configuration"
