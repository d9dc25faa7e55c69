"""The simulated chain's fast path (ServoChain: the servos' per-tick work in C, the bus's repeated
command and request) gives what the general path (each Servo's own methods, the packet reader)
gives: bit for bit, over randomized servo states, modes, faults and a seeded trace of every
instruction. Each check compares two twins built alike, one with the chain and one without;
floats are compared as their bits (tolerance 0: the C side does the same operations in the same
order on the same doubles). Nothing here is timed."""

import math

import numpy as np
import pytest

from servodyn.hal import load_config
from servodyn.hal.dynamixel import BROADCAST_ID, ResetOption
from servodyn.hal.dynamixel import instructions as inst
from servodyn.hal.dynamixel.control_table import (ADDR_GOAL_CURRENT, ADDR_PRESENT, PRESENT_LENGTH, SERVOS, TABLE_SIZE,
                                                  HardwareError, OperatingMode)
from servodyn.sim.robot import SimulatedRobot
from servodyn.sim.dynamixel import Mechanics, Servo, ServoChain, DynamixelWire
from servodyn.sim.plant import STOP_TIME_CONSTANT, Drives

CONFIG = load_config("replica")
# the models one C chain drives (a model without current control has other items: each servo on its own)
MODELS = [m for m in SERVOS.values() if m.current_control]
RAM_WRITABLE = [item for item in MODELS[0].items() if item.writable and not item.eeprom]


def _bits(values):
    return np.asarray(values, dtype=float).view(np.uint64)


def _state(servo: Servo):
    """Everything a servo holds that the chain may change (the shaft as its bits: NaN included)."""
    return (bytes(servo._table), [type(x) for x in servo._shaft], _bits(servo._shaft).tobytes(), servo._stale,
            servo._pid.integral, servo._turns, servo.clocked_at,
            servo._heard_at)


def _twins(seed: int, n: int = 7):
    """Two lists of servos alike: random models, IDs 1..n, each put in a random state by the
    general path (Servo.write), the same for both."""
    rng = np.random.default_rng(seed)
    models = [MODELS[k] for k in rng.integers(0, len(MODELS), n)]
    zeros = [int(z) for z in rng.integers(0, 4096, n)]
    # each servo's friction drawn (now and then an int, which Mechanics.torque takes as well)
    mechanics = [Mechanics.of(m, viscous_friction=float(rng.uniform(0.0, 0.05)),
                              coulomb_friction=(int(rng.integers(0, 2)) if rng.random() < 0.2
                                                else float(rng.uniform(0, 0.1))),
                              coulomb_velocity=float(rng.uniform(0.001, 0.1))) for m in models]
    a, b = ([Servo(m, i + 1, position=0.0, zero_ticks=z, mechanics=f)
             for i, (m, z, f) in enumerate(zip(models, zeros, mechanics))] for _ in range(2))
    for servo_a, servo_b in zip(a, b):
        writes = []
        mode = int(rng.choice([m.value for m in OperatingMode]))
        writes.append((11, bytes([mode])))
        writes.append((10, bytes([int(rng.choice([0, 1, 4, 5]))])))                      # drive mode: reverse bit
        writes.append((20, int(rng.integers(-5000, 5000)).to_bytes(4, "little", signed=True)))   # homing offset
        writes.append((24, int(rng.integers(0, 1024)).to_bytes(4, "little")))              # moving threshold
        writes.append((36, int(rng.integers(0, 886)).to_bytes(2, "little")))               # PWM limit
        writes.append((38, int(rng.integers(0, servo_a.model.current_limit_max + 1)).to_bytes(2, "little")))
        writes.append((64, bytes([int(rng.random() < 0.8)])))                              # torque
        writes.append((100, int(rng.integers(-885, 886)).to_bytes(2, "little", signed=True)))   # goal PWM
        writes.append((102, int(rng.integers(-2047, 2048)).to_bytes(2, "little", signed=True)))  # goal current
        for servo in (servo_a, servo_b):
            for address, data in writes:
                try:
                    servo.write(address, data)
                except Exception:       # refused (a limit): as refused on both
                    pass
        if rng.random() < 0.2:                                                             # the supply
            supply = 0 if rng.random() < 0.3 else int(rng.integers(95, 161))
            for servo in (servo_a, servo_b):
                servo._table[144:146] = supply.to_bytes(2, "little")
    return a, b, rng


def _shafts(rng, n):
    """Horn states, now and then a huge or non-finite value (refused by Python with an exception)."""
    position = rng.normal(0.0, 3.0, n)
    velocity = rng.normal(0.0, 5.0, n)
    current = rng.normal(0.0, 1.0, n)
    for values in (position, velocity, current):
        if rng.random() < 0.1:
            values[rng.integers(0, n)] = rng.choice([1e300, -1e300, math.inf, math.nan, 1e12])
    return position, velocity, current


def _outcome(call):
    try:
        return call()
    except Exception as err:          # the same exception on both sides, or the test fails
        return (type(err), str(err))


@pytest.mark.parametrize("seed", range(40))
def test_currents_shafts_and_present_registers_are_the_servos_own(seed):
    a, b, rng = _twins(seed)
    chain, each = ServoChain(a), Drives(b)
    n = len(a)
    for step in range(6):
        position, velocity, current = _shafts(rng, n)
        dt = float(rng.choice([1e-3, 2.5e-4]))
        out_a, torque_a, out_b, torque_b = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
        got = _outcome(lambda: chain.output(position, velocity, dt, out_a, torque_a))
        want = _outcome(lambda: each.output(position, velocity, dt, out_b, torque_b))
        assert got == want, f"seed {seed} step {step}: the same outcome ({want})"
        assert np.array_equal(_bits(out_a), _bits(out_b)), f"seed {seed} step {step}: currents bit for bit"
        # the torques are the plant's scratch: after an exception (a non-finite shaft) it drops them
        assert want is not None or np.array_equal(_bits(torque_a), _bits(torque_b)), \
            f"seed {seed} step {step}: torques bit for bit"
        chain.publish(position, velocity, current)
        each.publish(position, velocity, current)
        for servo_a, servo_b in zip(a, b):
            assert _state(servo_a) == _state(servo_b), f"seed {seed} step {step}: servo {servo_a.id} after output"
        chain.refresh()
        for servo_a, servo_b in zip(a, b):
            read_a = _outcome(lambda: servo_a.read(ADDR_PRESENT, PRESENT_LENGTH + 8))
            read_b = _outcome(lambda: servo_b.read(ADDR_PRESENT, PRESENT_LENGTH + 8))
            assert read_a == read_b, f"seed {seed} step {step}: servo {servo_a.id}'s Present registers"
            assert _state(servo_a) == _state(servo_b), f"seed {seed} step {step}: servo {servo_a.id} after a read"


@pytest.mark.parametrize("seed", range(20))
def test_clocks_watchdogs_and_writes_are_the_servos_own(seed):
    a, b, rng = _twins(seed)
    bus_a, bus_b = DynamixelWire(a, byte_timeout=None), DynamixelWire(b, byte_timeout=None, chain=ServoChain([]))
    assert bus_a.chain.covers(bus_a.servos) and not bus_b.chain.covers(bus_b.servos), "one twin has the chain"
    for servo_a, servo_b in zip(a, b):
        if rng.random() < 0.5:
            watchdog = bytes([int(rng.integers(1, 4))])                 # bus watchdog: 20..60 ms
            for servo in (servo_a, servo_b):
                servo.write(98, watchdog)
        if rng.random() < 0.2:
            secondary = int(rng.integers(1, 9))
            for servo in (servo_a, servo_b):
                servo._table[12] = secondary                           # a secondary ID (EEPROM)
    now = 0.0
    for step in range(60):
        now += float(rng.choice([1e-3, 0.0, 0.03, 0.1, 1e-4]))
        kind = rng.random()
        if kind < 0.3:
            bus_a.tick(now), bus_b.tick(now)
        else:
            item = RAM_WRITABLE[int(rng.integers(0, len(RAM_WRITABLE)))] if kind < 0.6 else \
                next(i for i in RAM_WRITABLE if i.name == "goal_current")
            ids = [int(i) for i in rng.integers(1, 10, int(rng.integers(1, 9)))]
            span = item.size if rng.random() < 0.9 else item.size + 1
            blocks = {i: bytes(rng.integers(0, 256, span, dtype=np.uint8)) for i in ids}
            if rng.random() < 0.5:                                   # small values, mostly in range
                blocks = {i: int(rng.integers(-300, 300)).to_bytes(8, "little", signed=True)[:span] for i in ids}
            packet = inst.sync_write(item.address, span, blocks).encode()
            if rng.random() < 0.3:                                   # a block duplicated by hand
                params = bytes(packet[8:-2]) + bytes([ids[0]]) + blocks[ids[0]]
                packet = inst.InstructionPacket(BROADCAST_ID, packet[7], params).encode()
            assert bus_a.handle(packet, now) == bus_b.handle(packet, now) == b"", "a broadcast write is not answered"
        for servo_a, servo_b in zip(a, b):
            assert _state(servo_a) == _state(servo_b), \
                f"seed {seed} step {step}: servo {servo_a.id}" + _diff(servo_a, servo_b)


def _diff(a: Servo, b: Servo) -> str:
    """Where two servos' tables differ, for a failing assertion's message."""
    def field(servo, item):
        return servo._table[item.address:item.address + item.size]
    return "".join(f"; {item.name} {a.get(item.name)} != {b.get(item.name)}" for item in a.items.values()
                   if field(a, item) != field(b, item))


@pytest.mark.parametrize("seed", range(20))
def test_fast_reads_are_the_general_paths(seed):
    a, b, rng = _twins(seed)
    bus_a, bus_b = DynamixelWire(a, byte_timeout=None), DynamixelWire(b, byte_timeout=None, chain=ServoChain([]))
    for step in range(30):
        position, velocity, current = _shafts(rng, len(a))
        for servos in (a, b):
            for servo, p, v, i in zip(servos, position.tolist(), velocity.tolist(), current.tolist()):
                servo.set_present(p, v, i)
        k = int(rng.integers(0, len(a)))
        change, level = rng.random(), int(rng.integers(0, 3))
        for servos in (a, b):
            if change < 0.1:
                servos[k].silent = not servos[k].silent
            elif change < 0.2:
                servos[k].set_hardware_error(HardwareError.OVERLOAD)
            elif change < 0.3:
                servos[k]._table[68] = level                          # Status Return Level
        ids = [int(i) for i in rng.permutation(np.arange(1, 10))[:int(rng.integers(1, 8))]] \
            if rng.random() < 0.3 else [s.id for s in a]
        address, length = (ADDR_PRESENT, PRESENT_LENGTH) if rng.random() < 0.7 else (
            int(rng.integers(0, TABLE_SIZE)), int(rng.integers(1, 12)))
        packet = (inst.fast_sync_read(address, length, ids) if rng.random() < 0.8 else
                  inst.fast_bulk_read([(i, address, length) for i in ids])).encode()
        got = _outcome(lambda: bus_a.handle(packet, 0.001 * step))
        want = _outcome(lambda: bus_b.handle(packet, 0.001 * step))
        assert got == want, f"seed {seed} step {step}: the same reply to {packet.hex()}"
        for servo_a, servo_b in zip(a, b):
            assert _state(servo_a) == _state(servo_b), \
                f"seed {seed} step {step}: servo {servo_a.id}" + _diff(servo_a, servo_b)


def _trace(rng, arm):
    """One host's chunk of bytes: mostly the loop's tick (a sync write of Goal Current, a fast
    sync read of the Present registers), else any instruction, a fault or broken bytes."""
    ids = [j.id for j in arm.joints]
    goal = inst.sync_write(ADDR_GOAL_CURRENT, 2, {i: int(rng.integers(-15, 16)).to_bytes(2, "little", signed=True)
                                                  for i in ids}).encode()
    read = inst.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, ids).encode()
    r = rng.random()
    servo_id = int(rng.choice(ids + [BROADCAST_ID, 99]))
    one = int(rng.choice(ids))
    if r < 0.55:
        return [goal, read] if rng.random() < 0.8 else [goal + read]
    if r < 0.6:                                                       # split, garbage, a bad CRC
        return [goal[:9], goal[9:]] if rng.random() < 0.5 else [b"\x00\xff" + goal] if rng.random() < 0.5 else \
            [goal[:-1] + bytes([goal[-1] ^ 0x40])]
    if r < 0.63:                                                      # stuffed: FF FF FD in the data
        return [inst.sync_write(ADDR_GOAL_CURRENT, 2, {ids[0]: b"\xff\xff", ids[1]: b"\xfd\x00"}).encode()]
    if r < 0.68:          # mostly Current Control (the others' PID can make a light link diverge)
        mode = int(rng.choice([m.value for m in OperatingMode])) if rng.random() < 0.3 else OperatingMode.CURRENT
        return [inst.write(one, 64, b"\x00").encode(), inst.write(one, 11, bytes([mode])).encode(),
                inst.write(one, 64, bytes([int(rng.random() < 0.8)])).encode()]
    if r < 0.71:
        return [inst.write(one, 64, b"\x00").encode(), inst.write(one, 10, bytes([int(rng.choice([0, 1]))])).encode(),
                inst.write(one, 64, b"\x01").encode()]
    if r < 0.73:
        return [inst.write(servo_id, 98, bytes([int(rng.integers(0, 3))])).encode()]      # bus watchdog
    if r < 0.76:
        return [inst.write(servo_id, int(rng.choice([100, 104, 116, 65, 84])),
                           bytes(rng.integers(0, 256, 4 if rng.random() < 0.5 else 2, dtype=np.uint8))).encode()]
    if r < 0.78:
        size = 4 if rng.random() < 0.7 else 2
        return [inst.sync_write(int(rng.choice([100, 104, 116, 108])), size,
                                {i: bytes(rng.integers(0, 256, size, dtype=np.uint8)) for i in ids}).encode()]
    if r < 0.80:
        return [inst.read(servo_id, int(rng.integers(0, TABLE_SIZE)), int(rng.integers(1, 20))).encode()]
    if r < 0.82:
        return [inst.sync_read(ADDR_PRESENT, PRESENT_LENGTH, ids).encode(),
                inst.bulk_read([(i, ADDR_PRESENT, PRESENT_LENGTH) for i in ids]).encode()]
    if r < 0.84:
        return [inst.fast_bulk_read([(i, int(rng.integers(100, 140)), 4) for i in ids]).encode()]
    if r < 0.86:
        return [inst.bulk_write([(i, ADDR_GOAL_CURRENT, b"\x05\x00") for i in ids]).encode()]
    if r < 0.87:
        return [inst.ping(servo_id).encode()]
    if r < 0.88:
        return [inst.reg_write(one, ADDR_GOAL_CURRENT, b"\x10\x00").encode(), inst.action(one).encode()]
    if r < 0.89:
        return [inst.reboot(one).encode()]
    if r < 0.895:
        return [inst.factory_reset(one, ResetOption.EXCEPT_ID_AND_BAUD).encode()]
    if r < 0.90:
        return [inst.clear_multi_turn(one).encode()]
    if r < 0.93:
        return [("fault", one, str(rng.choice(["silent", "overload", "overheating", "pushed"])))]
    if r < 0.95:
        return [("clear",)]
    if r < 0.97:
        return [inst.write(one, 68, bytes([int(rng.integers(0, 3))])).encode()]          # status return level
    return [("advance", float(rng.choice([1e-3, 0.05])))]


def _arms():
    with_chain, without = SimulatedRobot(CONFIG).port(), SimulatedRobot(CONFIG).port()
    without.plant.chain = Drives(without.servos)          # the drives one by one
    without.bus.chain = ServoChain([])                   # covers no bus: the general path
    for arm in (with_chain, without):
        arm.lockstep()
    return with_chain, without


def _act(arm, chunk):
    """One step of the trace on one arm: a chunk of bytes (its reply), or a fault, or time."""
    if not isinstance(chunk, tuple):
        return arm.handle(chunk)
    if chunk[0] == "fault":
        return arm.inject_fault(chunk[1], chunk[2])
    if chunk[0] == "clear":
        return arm.clear_faults()
    return arm.advance(chunk[1])


@pytest.mark.slow
def test_a_seeded_trace_of_every_instruction_is_answered_as_without_the_chain():
    rng = np.random.default_rng(2024)
    arms = _arms()
    steps = restarts = 0
    while steps < 8000:
        for chunk in _trace(rng, arms[0]):
            got, want = (_outcome(lambda: _act(arm, chunk)) for arm in arms)
            steps += 1
            what = chunk.hex() if isinstance(chunk, bytes) else chunk
            assert got == want, f"step {steps} ({what}): the same reply"
            assert np.array_equal(_bits(arms[0].q), _bits(arms[1].q)) and \
                np.array_equal(_bits(arms[0].qd), _bits(arms[1].qd)), f"step {steps} ({what}): the plant bit for bit"
            for servo_a, servo_b in zip(arms[0].servos, arms[1].servos):
                assert _state(servo_a) == _state(servo_b), f"step {steps} ({what}): servo {servo_a.id}" + \
                    _diff(servo_a, servo_b)
            if isinstance(got, tuple):             # an exception (the plant failed): start again
                arms = _arms()
                restarts += 1
                break
    # a restart is a plant that diverged, the same on both (76 with this seed): mostly the lightest
    # link under the position PID's default gains, which a 1 ms RK4 step does not hold
    assert restarts < 120, f"{restarts} plant failures in {steps} steps: the trace should mostly run"


def test_servos_that_cannot_be_one_chain_are_served_each_on_its_own():
    servos = [Servo(servo_id=i) for i in range(1, 64)]         # 63: more than a chain's 62
    bus = DynamixelWire(servos, byte_timeout=None)
    assert not bus.chain.covers(bus.servos), "no chain for them"
    reply = bus.handle(inst.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, [1, 63]).encode(), 0.0)
    blocks = [inst.FastReadBlock(i, 0, servos[i - 1].read(ADDR_PRESENT, PRESENT_LENGTH)) for i in (1, 63)]
    assert reply == inst.encode_fast_reply(blocks), "answered by the general path"
    arm = SimulatedRobot(CONFIG).port()
    assert arm.bus.chain.covers(arm.servos) and arm.plant.chain is arm.bus.chain, "the replica's 7 servos are one"


def test_a_fast_read_of_hundreds_of_blocks_is_the_general_paths():
    a, b, _ = _twins(3)
    bus_a, bus_b = DynamixelWire(a, byte_timeout=None), DynamixelWire(b, byte_timeout=None, chain=ServoChain([]))
    for count in (250, 300):            # the chain sorts up to 256 IDs, the reply's seal 256 blocks
        packet = inst.fast_sync_read(ADDR_PRESENT, PRESENT_LENGTH, [1 + k % 7 for k in range(count)]).encode()
        got, want = _outcome(lambda: bus_a.handle(packet, 0.0)), _outcome(lambda: bus_b.handle(packet, 0.0))
        assert got == want, f"{count} blocks (IDs repeated): as the general path answers them"
        assert count > 256 or len(got) == inst.fast_reply_size([PRESENT_LENGTH] * count), f"{count} whole blocks"


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
