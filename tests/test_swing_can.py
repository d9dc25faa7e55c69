"""The tennis swing on CAN motors: replica_can (seven Damiao motors on one simulated CAN bus,
python-can's virtual interface) and replica_mixed (Damiao shoulder and elbow on CAN, Dynamixel
forearm and wrist on a simulated serial bus: one robot, two buses, one tick), in lock-step.

Both configurations put more frames on a 1 Mbit/s bus than a 1 ms tick can carry (seven motors:
14 frames x 111-135 bits = 1.6-1.9 ms), so each sets its own control period (replica_can 2.5 ms,
replica_mixed 2 ms) and the validator passes the swing at it. What is asserted is deterministic in
lock-step: tick counts, tracking errors, which motor faulted and that every motor was switched off."""

import json
import math

import pytest

from servodyn.control.timing import HOME_DURATION
from servodyn.hal.config import load_config
from servodyn.loop import CHATTER_GOAL
from runs import run_swing

from helpers import quiet

pytestmark = pytest.mark.slow      # whole swings

CAN_PERIOD = load_config("replica_can").control_period
MIXED_PERIOD = load_config("replica_mixed").control_period
CAN_SCALE = load_config("replica_can").swing_time_scale
SWING_TICKS = round(1.8 * CAN_SCALE / CAN_PERIOD) + 1    # the 1.8 s forehand at its time scale, every period
FAULT_TIME = 0.2              # s into the swing


# one swing per fixture, so no single test pays for two under the per-test timeout
@pytest.fixture(scope="module")
def ff(tmp_path_factory):
    return run_swing("replica_can", out=tmp_path_factory.mktemp("can_ff"), say=quiet)


@pytest.fixture(scope="module")
def pd(tmp_path_factory):
    return run_swing("replica_can", out=tmp_path_factory.mktemp("can_pd"), feedforward=False, say=quiet)


def test_the_forehand_completes_on_can_motors(ff):
    assert CAN_PERIOD == 2.5e-3 and MIXED_PERIOD == 2e-3, "the configurations' control periods"
    assert ff["validated"], "the validator passes the swing at replica_can's own control period"
    assert ff["completed"] and ff["ticks"] == SWING_TICKS, f"every tick of the swing ran: {ff['ticks']}"
    assert abs(ff["sim_time_at_stop_s"] - SWING_TICKS * CAN_PERIOD) < 1e-9, \
        f"the plant moved one control period a tick: {ff['sim_time_at_stop_s']} s"
    assert ff["tracking_max_rad"] < 0.2, f"largest error {ff['tracking_max_rad']:.3f} rad: the arm followed"
    assert ff["bus"]["reads"] == ff["bus"]["writes"] + 1, "one read and one write a tick, and the start pose read"
    assert all(ff["torque_off"]), "every motor out of motor mode at the end"


def test_feedforward_cuts_the_largest_error_threefold_on_can(ff, pd):
    ratio = pd["tracking_max_rad"] / ff["tracking_max_rad"]
    assert ratio >= 3.0, (f"feed-forward {ff['tracking_max_rad']:.4f} rad vs PD alone {pd['tracking_max_rad']:.4f} "
                          f"rad: only {ratio:.2f}x")


def test_gains_planned_for_the_sensors_do_not_make_can_worse(ff):
    """The CAN motors' MIT replies are finer than a Dynamixel's (16-bit position, 12-bit velocity),
    so the resolution bound leaves replica_can's gains as they were and the error low-pass only
    smooths: the chatter stays within issue 23's 2 % (1.3 % before, 0.7 % with the low-pass), and
    the largest error is not made worse: 0.617° before, at the wrist, whose soft gains (its small
    rotor inertia at BANDWIDTH) leave the simulated motor's friction ~0.6°; 0.62° allows a
    rounding of that figure, nothing more."""
    worst = max(share["rms_share"] for share in ff["chatter_by_dof"].values())
    assert worst <= CHATTER_GOAL, f"chatter {100 * worst:.2f} % of a joint's peak torque"
    assert ff["tracking_max_rad"] <= math.radians(0.62), \
        f"largest error {math.degrees(ff['tracking_max_rad']):.3f} deg, 0.617 deg before"


def _stopped_at_the_fault(summary, out, period=CAN_PERIOD):
    fault_ticks = round(FAULT_TIME / period)
    assert not summary["completed"], "the fault stopped the swing"
    assert summary["ticks"] in (fault_ticks, fault_ticks + 1), \
        f"stopped within a tick of the fault: {summary['ticks']} ticks"
    lines = (out / "swing_log.csv").read_text().splitlines()
    assert len(lines) == 1 + summary["ticks"], "the log holds the header and every tick that ran"
    assert json.loads((out / "summary.json").read_text()) == summary, "summary.json is the summary"


def test_a_silent_motor_stops_the_swing_safely(tmp_path):
    summary = run_swing("replica_can", out=tmp_path, fault_at=(FAULT_TIME, 4), say=quiet)
    _stopped_at_the_fault(summary, tmp_path)
    assert "r_elbow_flexion" in summary["error"] and "did not answer" in summary["error"], summary["error"]
    off = summary["torque_off"]
    assert off[:3] + off[4:] == [True] * 6, "every answering motor out of motor mode"


@pytest.mark.parametrize("motor, fault, words", [(2, 0xE, "r_shoulder_abduction' (id 2) hardware error 0x0e: overload"),
                                                  (6, "overheat", "(id 6) hardware error 0x0c: coil over-temperature")])
def test_a_motor_fault_stops_the_swing_safely(tmp_path, motor, fault, words):
    summary = run_swing("replica_can", out=tmp_path, fault_at=(FAULT_TIME, motor, fault), say=quiet)
    _stopped_at_the_fault(summary, tmp_path)
    assert words in summary["error"], summary["error"]
    assert all(summary["torque_off"]), "every motor out of motor mode, the faulted one included"


def test_a_fault_on_one_bus_of_a_mixed_robot_stops_both(tmp_path):
    """An overload on Dynamixel servo 6 (the wrist bus) ends the run; the safe stop switches off the
    Damiao motors on the CAN bus as well."""
    summary = run_swing("replica_mixed", out=tmp_path, fault_at=(FAULT_TIME, 6, "overload"), say=quiet)
    _stopped_at_the_fault(summary, tmp_path, MIXED_PERIOD)
    assert "r_wrist_flexion" in summary["error"] and "overload" in summary["error"], summary["error"]
    assert summary["torque_off"] == [True] * 7, "CAN motors and Dynamixel servos all off"
    homing = int(round(HOME_DURATION / MIXED_PERIOD)) + 1
    assert summary["bus"]["writes"] == homing + round(FAULT_TIME / MIXED_PERIOD), "one robot write a tick over both buses, until the fault"
