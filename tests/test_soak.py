"""The fault-injection soak's parts (the soak itself is `make soak`, minutes long): the wire
faults of the simulated Dynamixel and CAN buses, the swing's exit statuses (the firmware's fault
codes), the controller's refusal of a non-finite state, and one short run of several fault classes,
Dynamixel and CAN, through the soak's own checks (safe stop, torque off, exit status, complete log)."""

import re
from pathlib import Path

import numpy as np
import pytest

from servodyn.control import ControlConfig, ControlFault, Controller
from servodyn.hal.dynamixel import BROADCAST_ID, FastReadBlock, StatusPacket, decode_frame, encode_fast_reply
from servodyn.hal.errors import ServoHardwareError, ServoLimitError, ServoOperationError, ServoTimeoutError
from servodyn.model import load_model
from servodyn.sim.faults import CAN_ERR_PROT, CanWireFault, WireFault, _frames
from servodyn.tools import soak
from servodyn.loop import Overrun
from servodyn.errors import ExitCode, ServodynError, exit_code
from servodyn.hal.errors import BusStallError, HalError
from servodyn.loop import Interrupted
from servodyn.validation import MotionRefused

ROOT = Path(__file__).resolve().parent.parent


def test_exit_codes_are_the_firmware_fault_codes():
    """One table of exit statuses (servodyn.errors.ExitCode), the firmware's enum fw_fault_ entry for
    entry: a run stopped by the Python loop, the native loop or the firmware exits alike."""
    header = (ROOT / "firmware" / "app" / "fw_app.h").read_text()
    enum = header[header.index("enum fw_fault_"):]
    enum = enum[:enum.index("};")]
    codes = {name: int(v) for name, v in re.findall(r"FW_(?:FAULT_)?(\w+) = (\d+)", enum)}
    python = {code.name: int(code) for code in ExitCode if code is not ExitCode.BAD_INPUT}
    assert codes == python, f"fw_app.h's fault codes {codes} are servodyn.errors.ExitCode's {python}"
    expected = {ServoTimeoutError("j", 3): ExitCode.TIMEOUT, BusStallError("arm"): ExitCode.TIMEOUT,
                TimeoutError(): ExitCode.TIMEOUT, ServoHardwareError("j", 3, 1, ("overload",)): ExitCode.STATUS,
                ServoOperationError("x"): ExitCode.CORRUPT, ControlFault("x"): ExitCode.NONFINITE,
                FloatingPointError(): ExitCode.NONFINITE, Overrun("x"): ExitCode.OVERRUN,
                ServoLimitError("j", 9.0, (-1.0, 1.0)): ExitCode.RANGE, MotionRefused("x"): ExitCode.BAD_INPUT,
                Interrupted(15): 128 + 15, RuntimeError("x"): ExitCode.BAD_INPUT, None: ExitCode.OK}
    for error, code in expected.items():
        assert exit_code(error) == code, f"{type(error).__name__} stops a run with exit status {int(code)}"
    for error in expected:
        if error is not None and not isinstance(error, (TimeoutError, FloatingPointError, RuntimeError)) \
                or isinstance(error, (Overrun, HalError)):
            assert isinstance(error, ServodynError), f"{type(error).__name__} is in servodyn's exception tree"


def test_controller_refuses_a_non_finite_state_as_a_control_fault():
    model = load_model("human_arm")
    controller = Controller(model, ControlConfig(), q_start=np.zeros(model.nq))
    z = np.zeros(model.nq)
    nan = z.copy()
    nan[2] = np.nan
    with pytest.raises(ControlFault, match="non-finite"):
        controller.step(nan, z, z, z, z)
    with pytest.raises(ValueError) as err:
        controller.step(np.zeros(3), z, z, z, z)        # a wrong shape is not a control fault
    assert not isinstance(err.value, ControlFault), "only a non-finite state is a ControlFault"


def _fast_reply(n=7, size=10):
    blocks = [FastReadBlock(i + 1, 0, bytes(range(i, i + size))) for i in range(n)]
    return encode_fast_reply(blocks), blocks


def test_flipped_byte_changes_one_bit_of_each_reply():
    reply, _ = _fast_reply()
    fault = WireFault("flipped_byte", 7, seed=3)
    for _ in range(20):
        out = fault.apply(reply)
        diff = [a ^ b for a, b in zip(reply, out)]
        assert len(out) == len(reply) and sum(bin(d).count("1") for d in diff) == 1, "exactly one bit flipped"


def test_wrong_id_gives_valid_frames_from_another_id():
    reply, blocks = _fast_reply()
    single = StatusPacket(4, 0, b"\x01\x02").encode()
    out = WireFault("wrong_id", 7).apply(reply + single)
    frames = _frames(out)
    assert len(frames) == 2, "the two frames stay two frames"
    fast, status = decode_frame(frames[0]), decode_frame(frames[1])
    assert status.id == 5 and status.params == b"\x01\x02", "a single servo's reply from the next ID, CRC valid"
    assert fast.id == BROADCAST_ID, "a fast reply stays a fast reply, its CRCs valid"
    assert fast.params[0] == 2 and fast.params[1:11] == blocks[0].data, "its first block from ID 2 instead of 1"


def test_garbage_replaces_the_reply_and_delay_and_stall_keep_it():
    reply, _ = _fast_reply()
    garbage = WireFault("garbage", 7, seed=1).apply(reply)
    assert garbage != reply and len(garbage) >= len(reply), "a burst at least as long as the reply"
    stall = WireFault("stall", 7, delay=0.0)
    assert stall.apply(reply) == reply and stall.stalled, "a stall delays, once, and changes no byte"
    assert WireFault("delayed_reply", 7, delay=0.0).apply(reply) == reply, "a delay changes no byte"
    with pytest.raises(ValueError, match="unknown wire fault"):
        WireFault("noise", 7)


@pytest.mark.parametrize("name", ["nan in motion", "beyond limit", "hardware error", "flipped byte"])
@pytest.mark.slow
def test_a_soak_run_of_each_kind_ends_in_a_safe_stop(name):
    spec = next(s for s in soak.plan(len(soak.CLASSES), 7, 0) if s["class"] == name)
    result = soak._one(spec)
    assert not result.get("traceback"), f"{name}: the run raised: {result['problems']}"
    assert result["problems"] == [], f"{name}: {result['problems']}"
    assert result["stopped"] and result["code"] in soak.CLASSES[name][1], \
        f"{name}: a safe stop with the class's exit status, got {result['code']} ({result['error']})"
    assert result["late_ticks"] <= soak.STOP_TICKS, f"{name}: torque off {result['late_ticks']} ticks after the fault"


def test_can_wire_faults_act_on_a_motors_frames():
    damiao = [(0x14, bytes([0x14, 0x80, 0x00, 0x80, 0x07, 0xFF, 35, 41]))]
    garbage = CanWireFault("garbage", seed=2)
    lengths = set()
    for _ in range(60):
        (arbitration_id, data), = garbage.apply(damiao, "damiao")
        assert arbitration_id == 0x14, "garbage stays on the motor's reply id"
        lengths.add(len(data))
    assert lengths == set(range(9)), f"random lengths 0-8: {sorted(lengths)}"
    (_, wrong), = CanWireFault("wrong_id").apply(damiao, "damiao")
    assert wrong[0] == 0x15 and wrong[1:] == damiao[0][1][1:], "Damiao: the low nibble names motor 5, status kept"
    (_, wrong), = CanWireFault("wrong_id").apply([(0, bytes([3, 1, 2, 3, 4, 5]))], "mit")
    assert wrong[0] == 4, "mit: byte 0 names motor 4"
    (arbitration_id, _), = CanWireFault("error_frame").apply(damiao, "damiao")
    assert arbitration_id == -CAN_ERR_PROT, "an error frame, its class (protocol error) as a negative id"
    with pytest.raises(ValueError, match="unknown CAN fault"):
        CanWireFault("noise")


@pytest.mark.parametrize("name, fault, servo, config", [
    ("fault status", 0xA, 3, "replica_can"),
    ("fault status", "overload", 6, "replica_mixed"),
    ("garbage frame", "garbage", 5, "replica_can"),
    ("wrong id", "wrong_id", 2, "replica_mixed"),
    ("error frame", "error_frame", 7, "replica_can"),
    ("bus-off", "bus_off", 1, "replica_can"),
    ("beyond limit", "pushed", 4, "replica_can"),
])
@pytest.mark.slow
def test_a_soak_run_on_can_motors_ends_in_a_safe_stop(name, fault, servo, config):
    """A CAN fault mid-swing: every motor (and servo) off within two plant ticks, the class's exit
    status, the log complete. A bus-off also makes the stop's exit frames fail until the controller
    rejoins the bus: without the stop's retries the motors stayed in motor mode."""
    spec = {"run": 0, "class": name, "fault": fault, "servo": servo, "tick": 60, "seed": 11, "firmware": False,
            "config": config}
    result = soak._one(spec)
    assert not result.get("traceback"), f"{name}: the run raised: {result['problems']}"
    assert result["problems"] == [], f"{name} on {config}: {result['problems']}"
    assert result["stopped"] and result["code"] in soak.CAN_CLASSES[name][2], \
        f"{name}: a safe stop with the class's exit status, got {result['code']} ({result['error']})"


def test_the_soak_plans_can_runs_of_every_class_on_both_configurations():
    specs = soak.plan(0, 2026, 0, can=48)
    where = {(s["class"], s["config"]) for s in specs}
    assert {c for c, _ in where} == set(soak.CAN_CLASSES), "every CAN fault class is drawn"
    assert sum(s["config"] == "replica_mixed" for s in specs) == 12, "every 4th run on the mixed robot"
    assert len({c for c, config in where if config == "replica_mixed"}) >= 6, "the mixed runs cover most classes"
    for s in specs:
        on_can, on_dynamixel, _ = soak.CAN_CLASSES[s["class"]]
        dynamixel = s["config"] == "replica_mixed" and s["servo"] > 4
        assert s["fault"] in (on_dynamixel if dynamixel else on_can), f"{s}: a fault its device can have"


def test_a_delayed_reply_and_a_stall_last_past_the_simulated_bus_patience():
    """Otherwise the swing rides through them and the soak's two classes cannot stop (a 0.3 s delay
    did, once the simulated bus's patience grew from 0.25 s to 1 s)."""
    from servodyn.sim import faults
    from servodyn.hal.ports import PTY_REPLY_TIMEOUT
    assert faults.DELAY > PTY_REPLY_TIMEOUT["dynamixel"] and faults.STALL > PTY_REPLY_TIMEOUT["dynamixel"], \
        (faults.DELAY, faults.STALL, PTY_REPLY_TIMEOUT)
