"""The simulated chain (ServoChain): one object for the plant's drives and the bus's clock, whose
work is each servo's own (Servo.output_current, output_torque, set_present, clock), and the
plant's quick check of its joint stops. Each check compares a servo driven through the chain with
a twin driven through its own methods; floats as their bits (tolerance 0: the same calls on the
same doubles). Nothing here is timed."""

import math

import numpy as np
import pytest

from servodyn.hal import load_config
from servodyn.hal.dynamixel import instructions as inst
from servodyn.hal.dynamixel.control_table import ADDR_PRESENT, PRESENT_LENGTH, SERVOS, OperatingMode
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.dynamixel import Mechanics, Servo, ServoChain, DynamixelWire
from servodyn.sim.plant import STOP_TIME_CONSTANT

CONFIG = load_config("replica")
MODELS = [m for m in SERVOS.values() if m.current_control]


def _bits(values):
    return np.asarray(values, dtype=float).view(np.uint64)


def _state(servo: Servo):
    """Everything a servo holds that the chain may change (the shaft as its bits: NaN included)."""
    return (bytes(servo._table), _bits(servo._shaft).tobytes(), servo._stale, servo._pid.integral, servo._turns,
            servo.clocked_at, servo._heard_at)


def _twins(seed: int, n: int = 7):
    """Two lists of servos alike: random models, friction, modes, drive modes, limits and goals."""
    rng = np.random.default_rng(seed)
    models = [MODELS[k] for k in rng.integers(0, len(MODELS), n)]
    zeros = [int(z) for z in rng.integers(0, 4096, n)]
    mechanics = [Mechanics.of(m, viscous_friction=float(rng.uniform(0.0, 0.05)),
                              coulomb_friction=float(rng.uniform(0, 0.1)),
                              coulomb_velocity=float(rng.uniform(0.001, 0.1))) for m in models]
    a, b = ([Servo(m, i + 1, zero_ticks=z, mechanics=f) for i, (m, z, f) in enumerate(zip(models, zeros, mechanics))]
            for _ in range(2))
    for servo_a, servo_b in zip(a, b):
        writes = [(11, bytes([int(rng.choice([m.value for m in OperatingMode]))])),     # mode
                  (10, bytes([int(rng.choice([0, 1]))])),                               # drive mode: reverse
                  (36, int(rng.integers(0, 886)).to_bytes(2, "little")),                # PWM limit
                  (98, bytes([int(rng.integers(0, 3))])),                               # bus watchdog
                  (64, bytes([int(rng.random() < 0.8)])),                               # torque
                  (102, int(rng.integers(-500, 500)).to_bytes(2, "little", signed=True))]   # goal current
        for servo in (servo_a, servo_b):
            for address, data in writes:
                try:
                    servo.write(address, data)
                except Exception:       # refused (a limit): as refused on both
                    pass
    return a, b, rng


@pytest.mark.parametrize("seed", range(10))
def test_the_chains_currents_registers_and_clocks_are_each_servos_own(seed):
    a, b, rng = _twins(seed)
    chain, n = ServoChain(a), len(a)
    now = 0.0
    for step in range(20):
        position, velocity, current = (rng.normal(0.0, s, n) for s in (3.0, 5.0, 1.0))
        dt = float(rng.choice([1e-3, 2.5e-4]))
        out, torque = np.zeros(n), np.zeros(n)
        chain.output(position, velocity, dt, out, torque)
        want = [servo.output_current(p, v, dt) for servo, p, v in zip(b, position.tolist(), velocity.tolist())]
        assert _bits(out).tobytes() == _bits(want).tobytes(), f"seed {seed} step {step}: currents bit for bit"
        assert _bits(torque).tobytes() == _bits([s.output_torque(i, v) for s, i, v in zip(
            b, want, velocity.tolist())]).tobytes(), f"seed {seed} step {step}: torques bit for bit"
        chain.publish(position, velocity, current)
        for servo, p, v, i in zip(b, position.tolist(), velocity.tolist(), current.tolist()):
            servo.set_present(p, v, i)
        now += float(rng.choice([1e-3, 0.0, 0.03]))
        chain.clock(now)
        for servo in b:
            if servo.clocked_at != now:
                servo.clock(now)
        for servo_a, servo_b in zip(a, b):
            assert servo_a.read(ADDR_PRESENT, PRESENT_LENGTH) == servo_b.read(ADDR_PRESENT, PRESENT_LENGTH), \
                f"seed {seed} step {step}: servo {servo_a.id}'s Present registers"
            assert _state(servo_a) == _state(servo_b), f"seed {seed} step {step}: servo {servo_a.id}"


def test_the_replicas_servos_are_one_chain_of_the_plant_and_the_bus():
    arm = SimulatedRobot(CONFIG).port()
    assert arm.bus.chain.covers(arm.servos) and arm.plant.chain is arm.bus.chain, "the replica's 7 servos are one"


def test_a_bus_whose_servos_changed_clocks_them_all():
    servos = [Servo(servo_id=i) for i in (1, 2)]
    bus = DynamixelWire(servos, byte_timeout=None)
    bus.servos.append(Servo(servo_id=3))
    bus.tick(0.25)
    assert [s.get("realtime_tick") for s in bus.servos] == [250] * 3, "Realtime Tick 250 ms on all three"
    reply = bus.handle(inst.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, [1, 3]).encode(), 0.5)
    blocks = [inst.FastReadBlock(i, 0, bus.servo(i).read(ADDR_PRESENT, PRESENT_LENGTH)) for i in (1, 3)]
    assert reply == inst.encode_fast_reply(blocks), "the servo added answers its block"


def _stop_torque(plant):
    """The stops' torque as the numpy expressions alone give it (Plant.stop_torque checks first
    whether every joint is finite and inside its limits)."""
    q, qd = plant.q, plant.qd
    past = np.minimum(q - plant.lower, 0.0) + np.maximum(q - plant.upper, 0.0)
    if not past.any():
        return np.zeros_like(q)
    w = 1.0 / STOP_TIME_CONSTANT
    push = -plant._stop_inertia * (w * w * past + 2.0 * w * qd)
    push = np.where(past > 0, np.minimum(push, 0.0), np.maximum(push, 0.0))
    return np.where((past != 0) & plant.stops, push, 0.0)


def test_the_stops_quick_check_gives_what_the_full_expressions_give():
    plant = SimulatedRobot(CONFIG).port().plant
    rng = np.random.default_rng(5)
    for trial in range(3000):
        q = rng.uniform(plant.lower - 0.1, plant.upper + 0.1)
        at = rng.integers(0, len(q), 3)
        q[at[0]] = plant.lower[at[0]]                          # exactly on a limit
        q[at[1]] = plant.upper[at[1]]
        if trial % 10 == 0:
            q[at[2]] = rng.choice([math.inf, -math.inf, math.nan])
        plant.q, plant.qd = q, rng.normal(0.0, 2.0, len(q))
        plant.stops = rng.random(len(q)) < 0.8                 # now and then a stop broken
        with np.errstate(invalid="ignore"):
            got, want = plant.stop_torque(), _stop_torque(plant)
        assert _bits(got).tobytes() == _bits(want).tobytes(), f"trial {trial}: q {q} bit for bit"
