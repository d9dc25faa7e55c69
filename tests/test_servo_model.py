"""The voltage-level servo model (hal.motor) against recorded real servos: the XL330 pendulum logs of
Rhoban's BAM (data/servo-logs in the shared folder beside the repository; nobody in this project
recorded them), BAM's own published figures on them, and the motor's closed-form envelope."""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from servodyn.hal.dynamixel.control_table import PWM_FULL, SERVOS, XL330_M288
from servodyn.hal.motor import MotorModel
from servodyn.identification.actuator import identify_actuator, law_duty, pwm_read_lag
from servodyn.identification.bench import BenchLog, Grid, read_bench_log, rollout

REPO = Path(__file__).resolve().parent.parent


def servo_logs() -> Path:
    """The shared data folder's servo-logs: beside the repository (main checkout) or beside its
    worktree folder; SERVODYN_SERVO_LOGS names another place."""
    named = os.environ.get("SERVODYN_SERVO_LOGS")
    for root in ([Path(named)] if named else []) + [REPO.parent / "shared/data/servo-logs",
                                                    REPO.parent.parent / "shared/data/servo-logs"]:
        if (root / "xl330-pendulum").is_dir():
            return root
    pytest.skip("the recorded servo logs (shared/data/servo-logs) are not beside the repository")


@pytest.fixture(scope="module")
def logs():
    return [read_bench_log(p) for p in sorted((servo_logs() / "xl330-pendulum").glob("*.json"))]


@pytest.fixture(scope="module")
def fitted(logs):
    start = time.process_time()
    fit = identify_actuator(logs, XL330_M288)
    return fit, time.process_time() - start


def test_the_logs_are_the_eight_xl330_runs(logs):
    # every kp and every trajectory appear (the README's inventory): what the goals below count over
    assert len(logs) == 8
    assert sorted({log.kp for log in logs}) == [100, 200, 400, 800]
    assert len({log.trajectory for log in logs}) == 4
    assert all(log.pwm is not None for log in logs)


def test_position_law_alone_follows_the_logged_pwm(logs):
    """Present PWM = P/256 × error in ticks (the catalogue's measured XL330 law) on the logged
    positions, read where the recorder read the PWM (one register after the position): within 0.01
    duty on every log. The e-manual's P/128 is twice off."""
    gains = [XL330_M288.duty_per_rad(log.kp) for log in logs]
    lag = pwm_read_lag(logs, gains)
    assert 0.001 <= lag <= 0.005          # a register read or two at 1 Mbaud over USB: milliseconds
    for log, gain in zip(logs, gains):
        q_read = np.interp(log.t + lag, log.t, log.q)
        duty = law_duty(log, gain, q_read)
        err = np.mean(np.abs(duty - log.pwm / PWM_FULL)[log.enabled])
        assert err < 0.01, (log.name, err)
        manual = law_duty(log, 2 * gain, q_read)        # P/128
        assert np.mean(np.abs(manual - log.pwm / PWM_FULL)[log.enabled]) > 2 * err
    assert XL330_M288.p_gain_divisor == 256 and "measured" in XL330_M288.p_gain_source
    assert all(s.p_gain_divisor == 128 and "e-manual" in s.p_gain_source
               for s in SERVOS.values() if not s.name.startswith("XL330"))


def test_rollout_reproduces_bams_published_m1(logs):
    """BAM's m1 fitted on these logs (and 8 more), replayed by BAM's rule (nominal supply, no warming,
    5 ms steps), scores 0.0554 rad on these 8 (issue 32, from BAM's own simulator): the replay here is
    the same experiment."""
    p = json.loads((servo_logs() / "bam-params/xl330-fitted-on-these-logs/m1.json").read_text())
    motor = MotorModel(p["kt"], p["R"], p["armature"], p["friction_base"], p["friction_viscous"])
    grid = Grid.of(logs, 0.005)
    grid = type(grid)(**{**grid.__dict__, "volts": np.full_like(grid.volts, 7.4),
                         "temp": np.full_like(grid.temp, 25.0)})
    gains = np.array([XL330_M288.duty_per_rad(log.kp) for log in logs])
    qs = rollout(grid, motor, gains, p["q_offset"])[0]
    mean = np.mean([np.mean(np.abs(grid.sample(qs, j)[:, 0] - log.q)) for j, log in enumerate(logs)])
    assert mean == pytest.approx(0.0554, abs=0.0015)   # BAM resampled the logs to 5 ms; we keep their samples


def test_identified_model_replays_the_logs(logs, fitted):
    """Goals of issue 32: the replay of the 8 logs with parameters identified from them ≤ 0.030 rad
    (BAM m6 0.0405, m1 0.0554, fitted on these and 8 more); the armature within 10 % of the free
    swing's 0.0021–0.0022 kg·m² (pendulum period after torque off)."""
    fit, seconds = fitted
    assert np.mean(fit.errors) <= 0.030, fit.errors
    assert max(fit.errors) < 0.06, fit.errors
    armature = fit.parameters["armature_kg_m2"]
    assert armature.determined and 0.9 * 0.0021 <= armature.value <= 1.1 * 0.0022, armature
    # physical: positive torque constant and resistance, friction not negative
    assert fit.motor.torque_constant > 0 and fit.motor.resistance > 0
    assert fit.motor.friction_coulomb >= 0 and fit.motor.friction_viscous >= 0
    print(f"identify on 8 logs: {seconds:.2f} s of CPU, mean {np.mean(fit.errors):.4f} rad")


def test_replayed_duty_follows_the_logged_pwm(logs, fitted):
    """The simulated servo's duty along its own replay against the logged Present PWM, on samples
    neither saturates: mean over logs ≤ 0.04 (BAM's rollouts on held-out recordings: m1 0.051)."""
    fit, _ = fitted
    gains = [XL330_M288.duty_per_rad(log.kp) for log in logs]
    lag = pwm_read_lag(logs, gains)
    grid = Grid.of(logs)
    duties = rollout(grid, fit.motor, np.array(gains), fit.offset)[1]
    errors = []
    for j, log in enumerate(logs):
        duty = grid.sample(duties, j, lag)[:, 0]
        measured = log.pwm / PWM_FULL
        fair = log.enabled & (np.abs(measured) < 0.95) & (np.abs(duty) < 0.95)
        errors.append(np.mean(np.abs(duty - measured)[fair]))
    assert np.mean(errors) <= 0.04, errors


def test_held_out_logs(logs):
    """Identified on one kp-and-trajectory half (one log per kp, every trajectory), replayed on the
    other: the held-out mean stays within the issue's goal for unseen recordings (≤ 0.045 rad)."""
    train = [log for log in logs if (log.kp, log.trajectory) in
             {(100, "sin_sin"), (200, "lift_and_drop"), (400, "up_and_down"), (800, "sin_time_square")}]
    test = [log for log in logs if log not in train]
    assert len(train) == 4 and len(test) == 4
    fit = identify_actuator(train, XL330_M288)
    grid = Grid.of(test)
    qs = rollout(grid, fit.motor, np.array([XL330_M288.duty_per_rad(log.kp) for log in test]), fit.offset)[0]
    errors = [np.mean(np.abs(grid.sample(qs, j)[:, 0] - log.q)) for j, log in enumerate(test)]
    print("held out:", [f"{log.name} {e:.4f}" for log, e in zip(test, errors)], f"mean {np.mean(errors):.4f}")
    assert np.mean(errors) <= 0.045 and max(errors) <= 0.10, errors


@pytest.mark.parametrize("supply", [5.0, 7.4, 12.0])
def test_current_loop_envelope_emerges(supply):
    """A drive's current loop reaches its goal only as far as full duty less the back-EMF allows:
    the torque–speed line τ = k_t·(V − k_e·ω)/R, stall k_t·V/R, no-load V/k_e, from one equation."""
    m = MotorModel(torque_constant=0.5, resistance=4.0, back_emf_constant=0.6)
    for omega in (-3.0, 0.0, 2.0, 0.9 * supply / 0.6):
        amps, duty = m.current_loop(100.0, supply, omega)
        assert amps == pytest.approx((supply - 0.6 * omega) / 4.0, rel=1e-12)
        assert duty == pytest.approx(1.0, rel=1e-12)          # saturated at full duty
        low, high = m.torque_limits(supply, omega)
        assert high == pytest.approx(0.5 * amps, rel=1e-12)
        amps, duty = m.current_loop(0.1, supply, omega)         # reachable: tracked exactly
        assert amps == pytest.approx(0.1) and m.current(duty, supply, omega) == pytest.approx(0.1, rel=1e-12)
    assert m.stall_torque(supply) == pytest.approx(0.5 * supply / 4.0)
    assert m.no_load_speed(supply) == pytest.approx(supply / 0.6)
    assert m.torque(1.0, supply, m.no_load_speed(supply)) == pytest.approx(0.0, abs=1e-12)


def test_source_resistance_and_warming():
    """The supply sags by R_s·d·I (solved in closed form) and copper's resistance rises 0.393 %/°C."""
    m = MotorModel(torque_constant=0.3, resistance=2.0, source_resistance=0.5)
    duty, supply, omega = 0.8, 7.4, 1.0
    amps = m.current(duty, supply, omega)
    bus = supply - 0.5 * duty * amps                         # what the servo's input sees
    assert amps == pytest.approx((duty * bus - 0.3 * omega) / 2.0, rel=1e-12)
    assert m.resistance_at(75.0) == pytest.approx(2.0 * (1 + 0.00393 * 50), rel=1e-12)


def test_friction_holds_at_rest_and_opposes_motion():
    """The stopping budget: at rest a torque within the budget is held exactly; moving, friction
    opposes the motion with Coulomb + Stribeck + viscous (+ the load share)."""
    m = MotorModel(0.3, 2.0, friction_coulomb=0.02, friction_viscous=0.01, friction_stribeck=0.01,
                   stribeck_velocity=0.1, friction_load=0.2)
    assert m.friction(0.0, 0.025, 0.007, 0.005, motor_torque=0.05) == pytest.approx(-0.025)
    assert m.friction(0.0, 0.2, 0.007, 0.005) == pytest.approx(-0.03)     # budget at rest: 0.02 + 0.01
    f = m.friction(2.0, 0.0, 0.007, 0.005, motor_torque=0.1)
    assert f == pytest.approx(-(0.02 + 0.01 * math.exp(-400) + 0.02 + 0.02), rel=1e-9)


@pytest.mark.parametrize("supply", [9.0, 11.1, 12.0, 14.8])
def test_simulator_and_validator_share_the_envelope(supply):
    """The simulated Dynamixel's current loop at full demand reaches the validator's torque–speed
    bound (host/validation/checks.py: τ_s(V)·(1 − ω/ω₀(V)) driving, τ_s(V)·(1 + |ω|/ω₀(V)) braking)
    at every supply voltage: both are hal.motor's line, the data sheet's rows at V."""
    from servodyn.hal.config import load_config
    from servodyn.sim.dynamixel.drive import Motor
    from servodyn.validation.limits import Limits

    config = load_config("replica")
    limits = Limits.of(config, supply)
    for j, joint in enumerate(config.joints):
        spec = joint.servo
        motor = Motor.of(spec)
        kt = spec.torque_constant
        w0, ts = limits.no_load_speed[j], limits.stall_torque[j]
        assert ts == pytest.approx(spec.stall_torque_at(supply), rel=1e-12)
        for along in (0.0, 0.3, 0.8):
            omega = along * w0
            amps, pwm = motor.current_driven(1e6, PWM_FULL, supply, omega)          # driving, saturated
            assert amps * kt == pytest.approx(ts * (1 - along), rel=1e-9)
            assert pwm == pytest.approx(PWM_FULL, rel=1e-12)
            amps, _ = motor.current_driven(-1e6, PWM_FULL, supply, omega)         # braking against ω
            assert -amps * kt == pytest.approx(ts * (1 + along), rel=1e-9)


def _trajectory(name: str, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BAM's bench trajectories (data/servo-logs README): goal (rad) and torque enable."""
    if name == "sin_sin":
        return np.sin(t) * np.pi / 2 + 0.5 * np.sin(5 * t) * np.sin(2 * t), np.ones_like(t, bool)
    s = np.clip(t / 2, 0, 1)
    return -np.pi / 2 * (3 * s ** 2 - 2 * s ** 3), t < 2.0            # lift_and_drop


def test_identification_recovers_a_known_servo(tmp_path):
    """Bench logs written in the recorded logs' format by a known servo (simulated at 1 ms, positions
    quantized to the encoder's 4096 ticks, the PWM as its register, a sagging supply), identified at
    the replay's 5 ms: the armature, the torque per volt k_t/R, the load share and the zero offset
    come back."""
    truth = MotorModel(torque_constant=0.3, resistance=2.5, armature=0.0019, friction_coulomb=0.004,
                       friction_viscous=0.01, friction_load=0.3)
    offset, tick = 0.02, 2 * np.pi / 4096
    paths = []
    for i, (name, kp) in enumerate([("sin_sin", 200), ("sin_sin", 800), ("lift_and_drop", 400)]):
        t = np.arange(0.004, 6.0, 0.0053)
        goal, enabled = _trajectory(name, t)
        volts = 7.4 - 0.8 * np.abs(np.sin(1.3 * t + i))
        log = BenchLog(
            path="sim", motor="xl330", trajectory=name, mass=0.49, length=0.1, kp=kp, vin=7.4, t=t,
            q=np.zeros_like(t), speed=np.zeros_like(t), pwm=None, volts=volts, temp=np.full_like(t, 30.0),
            goal=goal, enabled=enabled)
        grid = Grid.of([log], 0.001)
        qs, duties = rollout(grid, truth, np.array([XL330_M288.duty_per_rad(kp)]), offset)
        q = np.round(grid.sample(qs, 0)[:, 0] / tick) * tick
        pwm = np.round(grid.sample(duties, 0)[:, 0] * PWM_FULL).astype(int) % 65536
        entries = [{"position": float(a), "speed": 0.0, "load": int(b), "input_volts": round(float(v), 1),
                    "temp": 30, "timestamp": float(c), "goal_position": float(g), "torque_enable": bool(e)}
                   for a, b, v, c, g, e in zip(q, pwm, volts, t, goal, enabled)]
        path = tmp_path / f"{name}_{kp}.json"
        path.write_text(json.dumps({"mass": 0.49, "length": 0.1, "kp": kp, "vin": 7.4, "motor": "xl330",
                                    "trajectory": name, "entries": entries}))
        paths.append(path)
    logs = [read_bench_log(p) for p in paths]
    fit = identify_actuator(logs, XL330_M288)
    m = fit.motor
    assert m.armature == pytest.approx(truth.armature, rel=0.05)
    assert m.torque_constant / m.resistance == pytest.approx(0.3 / 2.5, rel=0.1)
    assert m.friction_load == pytest.approx(0.3, abs=0.1)
    # the zero offset trades with the friction's dead band (the pendulum rests anywhere within it):
    # within two of its standard errors
    zero = fit.parameters["zero_offset_rad"]
    assert abs(zero.value - offset) <= 2 * zero.std
    # the replay's 5 ms steps are not the 1 ms plant: the true motor replayed at 5 ms scores 0.0014 rad
    # (about one encoder tick); the identified one within about three ticks (the free swing's armature
    # is held at its own fit, 1.5 % off)
    grid = Grid.of(logs)
    qs = rollout(grid, truth, np.array([XL330_M288.duty_per_rad(log.kp) for log in logs]), offset)[0]
    bar = np.mean([np.mean(np.abs(grid.sample(qs, j)[:, 0] - log.q)) for j, log in enumerate(logs)])
    assert bar < 1.5 * tick and np.mean(fit.errors) <= 3 * tick, (fit.errors, bar)
