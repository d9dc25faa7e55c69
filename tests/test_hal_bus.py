"""The servo bus interface (hal/bus.py) and its loopback backend (hal/loopback.py)."""

import numpy as np
import pytest

from servodyn.control.motion import load_motion
from servodyn.hal import (ConfigError, HalError, JointCommand, ProtocolError, ServoError, ServoHardwareError,
                          ServoInitializationError, ServoLimitError, ServoOperationError, ServoTimeoutError,
                          load_config, make_bus)
from servodyn.hal import backend as hal_backend
from servodyn.hal.dynamixel import FieldRangeError, PacketError, StatusError
from servodyn.hal.dynamixel.control_table import hardware_faults
from servodyn.hal.loopback import LoopbackBus

CONFIG = load_config("replica")
MODEL = CONFIG.model


def test_command_broadcasts_and_checks():
    c = JointCommand.position(np.ones(7), kp=2.0, kd=0.1)
    assert c.qd.shape == c.tau_ff.shape == c.kp.shape == (7,) and np.all(c.kd == 0.1), \
        "scalars broadcast to one value per joint"
    q, qd = np.zeros(7), np.full(7, 0.5)
    assert np.allclose(c.torque_at(q, qd), 2.0 * 1.0 + 0.1 * (0.0 - 0.5)), "tau_ff + kp e + kd ė"
    t = JointCommand.torque(np.arange(7.0))
    assert np.array_equal(t.torque_at(np.full(7, 3.0), qd), np.arange(7.0)), "pure torque ignores the state"
    for bad in (dict(q=np.ones(7), kp=-1.0, kd=0.0), dict(q=[np.nan] * 7, kp=1.0, kd=0.0),
                dict(q=np.ones((2, 7)), kp=1.0, kd=0.0)):
        with pytest.raises(ValueError):
            JointCommand.position(**bad)


def test_exception_tree():
    """One root: the bus errors, the configuration's and every codec's (python-can's CanError)."""
    for cls in (ServoInitializationError, ServoOperationError, ServoTimeoutError, ServoHardwareError,
                ServoLimitError):
        assert issubclass(cls, ServoError), cls
    for cls in (ServoError, ConfigError, ProtocolError, PacketError, FieldRangeError, StatusError):
        assert issubclass(cls, HalError), cls
    assert issubclass(ConfigError, ValueError), "a bad configuration is a bad value too"
    timeout = ServoTimeoutError("r_elbow_flexion", 4)
    assert isinstance(timeout, TimeoutError) and (timeout.joint, timeout.servo_id) == ("r_elbow_flexion", 4), \
        "also a built-in TimeoutError, carrying the joint and the servo ID"
    hardware = ServoHardwareError("r_wrist_flexion", 6, 0b100100, hardware_faults(0b100100))
    assert hardware.faults == ("overheating", "overload"), "bits 2 and 5 of Hardware Error Status"
    assert "id 6" in str(hardware) and "0x24" in str(hardware), f"servo ID and raw status byte named: {hardware}"


def test_make_bus_finds_backends_by_kind(monkeypatch):
    """The bus's kind picks the backend, imported on first use; `kind` overrides it; a backend
    that cannot be imported or an unknown kind is a ServoInitializationError."""
    bus = make_bus(CONFIG, kind="loopback")
    assert isinstance(bus, LoopbackBus) and not bus.is_open and bus.dof_names == MODEL.dof_names, \
        "the loopback backend, not opened until used, driving the model's dofs in order"
    monkeypatch.setitem(hal_backend.BACKENDS, "dynamixel", "servodyn.hal.no_such_module:Bus")
    with pytest.raises(ServoInitializationError, match="no_such_module"):
        make_bus(CONFIG)
    with pytest.raises(ServoInitializationError, match="'ethercat'"):
        make_bus(CONFIG, kind="ethercat")
    with pytest.raises(ServoInitializationError, match="no bus 'leg'"):
        make_bus(CONFIG, "leg", kind="loopback")


def test_closed_bus_refuses():
    bus = make_bus(CONFIG, kind="loopback")
    with pytest.raises(ServoOperationError, match="not open"):
        bus.read_state()
    with bus:
        assert bus.is_open, "the with block opens the bus"
        bus.read_state()
    assert not bus.is_open, "and closes it on leaving"


def test_loopback_tracks_the_swing_with_feedforward():
    """Smoke test of a control loop through the bus: the swing at the replica's time scale, one
    read and one write per 1 ms tick, PD at 60 rad/s on each joint's diagonal inertia. With the
    inverse-dynamics feed-forward the largest error stays below 0.05 deg (measured 0.0002); the
    PD alone lags a thousand times more (measured 0.26 deg). The diagonal inertia includes the
    servos' rotor inertia reflected through their gears (armature: 0.14 and 0.045 kg m², 7 to
    350 times the links' own at the shoulder and the wrist), so the gains are that much stiffer
    than on the bare links, where the PD alone lagged 8.3 deg. Nothing is clamped: the swing fits
    the servos."""
    swing = load_motion("tennis_forehand", MODEL).sample(1e-3, time_scale=CONFIG.swing_time_scale)
    tau_ff = MODEL.inverse_dynamics(swing.q, swing.qd, swing.qdd)
    inertia = 1 / np.diag(np.linalg.inv(MODEL.mass_matrix(swing.q[0])))
    kp, kd = inertia * 60.0**2, inertia * 2 * 60.0
    worst = {}
    for feedforward in (True, False):
        with make_bus(CONFIG, kind="loopback", q0=swing.q[0]) as bus:
            bus.enable_torque(True)
            error = 0.0
            for k in range(len(swing.t)):
                state = bus.read_state()
                assert state.t == pytest.approx(k * 1e-3), "each write advances the loopback plant by 1 ms"
                error = max(error, np.abs(state.q - swing.q[k]).max())
                bus.write(JointCommand.position(swing.q[k], kp=kp, kd=kd, qd=swing.qd[k],
                                                tau_ff=tau_ff[k] if feedforward else 0.0))
            assert bus.stats.limited.sum() == 0, "nothing clamped: the swing is inside every limit"
        worst[feedforward] = np.degrees(error)
    assert worst[True] < 0.05, f"largest error with feed-forward {worst[True]:.4f} deg (measured 0.0002)"
    assert worst[False] > 100 * worst[True] and worst[False] > 0.1, \
        f"the PD alone lagged only {worst[False]:.3f} deg (measured 0.26), with feed-forward {worst[True]:.4f}"


def test_loopback_clamps_to_the_current_limit():
    """A 100 N m request is limited to the joint's torque at its current limit (kt x limit), counted
    in `limited`; the servo reports that current."""
    with make_bus(CONFIG, kind="loopback") as bus:
        bus.enable_torque(True)
        bus.write(JointCommand.torque(np.full(7, 100.0)))
        state = bus.read_state()
    assert np.array_equal(bus.stats.limited, np.ones(7)), "each joint's command was clamped once"
    assert np.allclose(state.tau, [2.409 * 4.4] * 3 + [1.783 * 2.3] * 4), \
        "kt x current limit: XM540-W270 2.409 N m/A x 4.4 A, XM430-W350 1.783 N m/A x 2.3 A"
    assert np.allclose(state.current, [4.4] * 3 + [2.3] * 4), "each servo at its current limit (the stall current)"


def test_limp_arm_falls_and_trips_the_limit():
    """Torque off: the arm, released near straight up (flexion 172 deg) with the elbow straight
    at its 0 limit, starts to fall forward, and the elbow, which the falling upper arm bends
    backwards, passes its limit by more than the margin first, after 0.36 s: ServoLimitError,
    naming the joint and carrying the state. (Without the servos' rotor inertia the limp wrist,
    0.0003 kg m² about its axis against the XM430-W350's armature of 0.045, flopped beyond its
    extension limit first, after 0.18 s.)"""
    q0 = np.zeros(7)
    q0[0] = 3.0
    with make_bus(CONFIG, kind="loopback", q0=q0) as bus:
        with pytest.raises(ServoLimitError) as err:
            for _ in range(1000):
                state = bus.read_state()
                assert np.all(state.tau == 0) and np.all(state.current == 0), "torque off: no current, no torque"
                bus.write(JointCommand.position(q0, kp=10.0, kd=1.0))
    k = MODEL.dof_names.index(err.value.joint)
    assert err.value.joint == "r_elbow_flexion" and err.value.state.q[k] == err.value.value, \
        f"{err.value.joint} tripped; the elbow should, the error's value its position in the state"
    assert err.value.value < MODEL.lower[k] - bus.position_margin, \
        "read_state raises only beyond a limit by more than position_margin"
    assert err.value.state.t == pytest.approx(0.36, abs=0.02), f"tripped at {err.value.state.t:.3f} s (measured 0.363)"
    assert err.value.state.q[0] < 3.0 - 0.1, "the shoulder is falling forward (measured 2.896 rad)"
