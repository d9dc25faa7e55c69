"""Joint (SI) ↔ servo unit conversions (hal/dynamixel/units.py)."""

import numpy as np
import pytest

from servodyn.hal.config import load_config
from servodyn.hal.dynamixel.units import ServoMap

TICK = 2 * np.pi / 4096                 # rad per position unit
VELOCITY_UNIT = 0.229 * 2 * np.pi / 60  # rad/s per velocity unit


def servo_map(direction=(1, -1, 1, -1), gear=(1.0, 1.0, 2.5, 3.0), offset=(np.pi, 0.3, 2.0, 5.0),
              kt=(2.409, 2.409, 1.783, 1.783)):
    n = len(direction)
    return ServoMap(direction=direction, zero_offset=offset, gear_ratio=gear, torque_constant=kt,
                    current_unit=[2.69e-3] * n, ticks_per_rev=[4096] * n, velocity_unit=[0.229] * n)


def test_position_known_values():
    """Horn angle = d·G·q + θ0, 4096 ticks per turn: at q = 0 the horn is at its offset, a
    quarter joint turn is 1024 ticks times the gear ratio, in the servo's direction."""
    m = servo_map(offset=(np.pi, np.pi, np.pi, np.pi))
    assert np.array_equal(m.to_ticks(np.zeros(4)), [2048, 2048, 2048, 2048]), "q = 0: the horn at its offset π"
    assert np.array_equal(m.to_ticks(np.full(4, np.pi / 2)), [3072, 1024, 2048 + 2560, 2048 - 3072]), \
        "2048 ± 1024 ticks times the gear ratio (1, 1, 2.5, 3), signed by the direction (+, -, +, -)"


def test_ticks_round_trip_is_exact():
    """Ticks → q → ticks gives back the same integers (what a read then a write does)."""
    m = servo_map()
    ticks = np.random.default_rng(1).integers(-100_000, 100_000, size=(500, 4))
    assert np.array_equal(m.to_ticks(m.from_ticks(ticks)), ticks)


def test_angle_round_trip_within_half_a_tick():
    """q → ticks → q loses at most half a tick of horn angle, i.e. TICK / (2 G) at the joint."""
    m = servo_map()
    q = np.random.default_rng(2).uniform(-3.0, 3.0, size=(500, 4))
    error = np.abs(m.from_ticks(m.to_ticks(q)) - q)
    assert np.all(error <= TICK / (2 * m.gear_ratio) + 1e-15), \
        f"lost up to {np.max(error * m.gear_ratio) / TICK:.3f} ticks of horn angle (rounding loses 0.5)"


def test_velocity_units_and_round_trip():
    """0.229 rpm per unit, through direction and gear: 100 units at the horn are 2.398 rad/s."""
    m = servo_map()
    qd = m.from_velocity_units(np.full(4, 100))
    assert np.allclose(qd, 100 * VELOCITY_UNIT / (m.direction * m.gear_ratio), rtol=1e-12), \
        "0.229 rpm per unit at the horn, divided by direction and gear ratio at the joint"
    assert qd[0] == pytest.approx(2.3981, abs=1e-4), "100 x 0.229 rpm = 22.9 rpm = 2.398 rad/s, direct drive"
    units = np.random.default_rng(3).integers(-1023, 1024, size=(200, 4))
    assert np.array_equal(m.to_velocity_units(m.from_velocity_units(units)), units)
    speeds = np.random.default_rng(4).uniform(-5, 5, size=(200, 4))
    assert np.all(np.abs(m.from_velocity_units(m.to_velocity_units(speeds)) - speeds)
                  <= VELOCITY_UNIT / (2 * m.gear_ratio) + 1e-15), "more than half a velocity unit lost"


def test_torque_to_current_units():
    """1 N m at an XM430 joint (kt 1.783 N m/A, direct drive) is 0.5609 A = 208 units of 2.69 mA;
    through a 3:1 reduction the horn carries a third of it."""
    m = servo_map()
    units = m.to_current_units(np.ones(4))
    assert units[2] == round(1 / (2.5 * 1.783 * 2.69e-3)), "1 N m / 2.5 at the horn, / 1.783 N m/A, / 2.69 mA"
    assert units[3] == -round(1 / (3.0 * 1.783 * 2.69e-3)), "direction -1 flips the register sign"
    assert m.current(np.ones(4))[3] == pytest.approx(1 / (3 * 1.783), rel=1e-12), "joint-sense current"
    assert servo_map(gear=(1, 1, 1, 1)).to_current_units(np.ones(4))[2] == 208, \
        "XM430 direct drive: 1 N m / 1.783 N m/A = 0.5609 A = 208 units of 2.69 mA"


def test_current_round_trip():
    """Units → τ → units is exact; τ → units → τ within half a unit's torque (G kt 2.69 mA / 2)."""
    m = servo_map()
    units = np.random.default_rng(5).integers(-2047, 2048, size=(300, 4))
    assert np.array_equal(m.to_current_units(m.from_current_units(units)), units)
    tau = np.random.default_rng(6).uniform(-10, 10, size=(300, 4))
    half_unit = 0.5 * m.gear_ratio * m.torque_constant * m.current_unit
    assert np.all(np.abs(m.from_current_units(m.to_current_units(tau)) - tau) <= half_unit + 1e-12), \
        "more than half a current unit's torque lost"
    assert np.allclose(m.torque(m.current(tau)), tau, rtol=1e-14), "torque(current(tau)) is tau: kt and G undone"
    assert np.allclose(m.current_from_units(units), m.current(m.from_current_units(units)), rtol=1e-12), \
        "a register's current, read directly or through its torque, agrees"


def test_from_config_joints():
    """The replica's map carries each joint's direction, offset and servo constants, in dof order."""
    config = load_config("replica")
    m = ServoMap.from_joints(config.joints)
    assert m.n == 7, "one servo per dof, IDs 1-7 from the shoulder out"
    assert list(m.direction) == [1, -1, -1, 1, -1, 1, 1], "the replica.toml joints' directions, in dof order"
    assert m.torque_constant[0] == pytest.approx(2.409) and m.torque_constant[6] == pytest.approx(1.783), \
        "XM540-W270 at the shoulder (10.6 N m / 4.4 A), XM430-W350 at the wrist (4.1 N m / 2.3 A)"
    assert np.all(m.ticks_per_rev == 4096), "X-series: 4096 position units per turn"
    # the middle of every joint's range sits at 2048 ticks, as the config says
    mid = (config.model.lower + config.model.upper) / 2
    assert np.all(np.abs(m.to_ticks(mid) - 2048) <= 1), \
        f"mid-range at {m.to_ticks(mid)} ticks; zero_offset, rounded to 1e-4 rad, puts it at 2048"


def test_fields_must_agree():
    with pytest.raises(ValueError, match="same length"):
        ServoMap(direction=[1, 1], zero_offset=[0.0], gear_ratio=[1, 1], torque_constant=[1, 1],
                 current_unit=[1e-3, 1e-3], ticks_per_rev=[4096, 4096], velocity_unit=[0.229, 0.229])
