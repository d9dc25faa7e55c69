"""`servodyn calibrate`: torque off on every bus of a configuration; per joint, its + direction, its
zero (the mean of two approaches) and both stops, moved by hand and read through its bus kind's
bring-up (hal.bringup); then the configuration patched (comments kept) after the change is shown
and confirmed, with the writes a kind that keeps the calibration in its devices makes (a Feetech
servo's Homing_Offset and position limits, made after the yes and before the file is written).
Its errors are the HAL's, one line each (tools/bringup makes them the command's); nothing is
written unless every joint asked for was calibrated."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from contextlib import ExitStack

from ...hal.backend import backend
from ...hal.bringup import BadRequest, PortLost, config_and_ports, open_limp
from ...hal.config import load_config
from ...hal.config_patch import ConfigPatch
from ...hal.errors import ServoError, ServoOperationError
from ...validation.lerobot_motion import GRIPPERS, RESOLUTION

MIN_TRAVEL = math.radians(3.0)      # a "move it" step that turns the horn less is asked again


def wait_enter(prompt: str, say: Callable = print) -> None:
    """A step a person does by hand, then Enter; end of input stops the command."""
    say(f"{prompt} [Enter] ", end="", flush=True)
    if not sys.stdin.readline():
        say("")
        raise BadRequest("no more input: stopped before the end (nothing was written)")


def calibrate(config_name: str, port, joints: list[str] | None, margin_deg: float, confirm,
              write_to: str | None, say=print) -> int:
    """Torque off; per joint: its + direction, its zero (the mean of two approaches), both stops;
    then the configuration patched (comments kept) after the change is shown and confirmed."""
    config, ports = config_and_ports(config_name, port)
    chosen = [j for j in config.joints if joints is None or j.dof in joints]
    unknown = sorted(set(joints or ()) - {j.dof for j in config.joints})
    if unknown:
        raise BadRequest(f"'{config.name}' has no joint '{unknown[0]}'")
    if not math.isfinite(margin_deg) or margin_deg < 0:
        raise BadRequest(f"--margin must be a finite number of degrees >= 0, got {margin_deg:g}")
    margin = math.radians(margin_deg)
    try:
        patch = ConfigPatch.of(config, write_to)
    except OSError as err:
        raise BadRequest(str(err)) from None
    results, writes = {}, []
    with ExitStack() as stack:
        sessions = open_limp(config, ports, stack, ": move the joints by hand", say)
        for joint in chosen:
            results[joint.dof] = _calibrate_joint(joint, _horn(joint, sessions[joint.bus]), config, margin, say)
        for joint in chosen:        # a kind that keeps the calibration in its devices (Feetech: Homing_Offset)
            results[joint.dof], steps = sessions[joint.bus].calibration(joint, results[joint.dof])
            if steps:
                writes.append((sessions[joint.bus], joint, steps))
        for dof, values in results.items():
            patch.set_joint(dof, **values)
        ask = _devices_first(writes, confirm, say)
        if writes and not patch.changes():
            return 0 if ask("write these to the servos?") else 1
        return patch.offer(ask, say)


def _devices_first(writes: list, confirm, say):
    """`confirm`, which shows the calibration's writes to the devices with its question and, on a
    yes, makes them before the configuration is written (a device that refuses stops the command
    with the file untouched)."""
    if not writes:
        return confirm

    def ask(question: str) -> bool:
        say("and to the servos' EEPROM:")
        for _, joint, steps in writes:
            for step in steps:
                say(f"  joint '{joint.dof}' (id {joint.id}): {step.line()}")
        if not confirm(question):
            return False
        for here, joint, steps in writes:
            say(here.apply_calibration(joint, steps))
        return True
    return ask


def _horn(joint, here) -> Callable[[], float]:
    """The joint's horn (motor output) angle now, rad; a device that fails is named."""
    def horn() -> float:
        try:
            return here.horn(joint)
        except ServoError as err:
            if isinstance(err, PortLost) or f"joint '{joint.dof}'" in str(err):
                raise
            raise ServoOperationError(f"joint '{joint.dof}': {err}") from None
    return horn


def _calibrate_joint(joint, horn: Callable[[], float], config, margin: float, say) -> dict:
    name = f"joint '{joint.dof}' (id {joint.id})"
    for _ in range(3):
        before = horn()
        wait_enter(f"{name}: move it a little (10-30°) in its + direction ({joint.dof} increasing)", say)
        travel = horn() - before
        if abs(travel) >= MIN_TRAVEL:
            break
        say(f"  it turned {math.degrees(travel):.1f}°, less than {math.degrees(MIN_TRAVEL):g}°: again")
    else:
        raise BadRequest(f"{name} did not move: is it the servo at id {joint.id}? (`servodyn monitor` shows them live)")
    direction = 1 if travel > 0 else -1
    wait_enter(f"{name}: put it in its zero pose, coming from the - side", say)
    low_side = horn()
    wait_enter(f"{name}: move it away, then back to its zero pose from the + side", say)
    high_side = horn()
    zero = (low_side + high_side) / 2
    backlash = abs(high_side - low_side)
    wait_enter(f"{name}: move it to its - stop", say)
    stop_a = horn()
    wait_enter(f"{name}: move it to its + stop", say)
    stop_b = horn()
    scale = direction * joint.gear_ratio
    q_stops = sorted(((stop_a - zero) / scale, (stop_b - zero) / scale))
    lower, upper = q_stops[0] + margin, q_stops[1] - margin
    model_lower, model_upper = (config.model.lower[config.model.dof_names.index(joint.dof)],
                                config.model.upper[config.model.dof_names.index(joint.dof)])
    clipped = lower < model_lower or upper > model_upper
    lower, upper = max(lower, model_lower), min(upper, model_upper)
    if not lower < upper:
        raise BadRequest(f"{name}: its stops ({math.degrees(q_stops[0]):.1f}° .. {math.degrees(q_stops[1]):.1f}°) "
                         f"leave no range inside a {math.degrees(margin):g}° margin and the model's limits")
    say(f"  direction {direction:+d}, zero at horn {math.degrees(zero):.2f}° (approaches {math.degrees(backlash):.2f}° "
        f"apart), stops {math.degrees(q_stops[0]):.1f}° .. {math.degrees(q_stops[1]):.1f}°"
        + (" (limited to the model's range)" if clipped else ""))
    zero = math.remainder(zero, 2 * math.pi) if abs(zero) > 2 * math.pi else zero
    return {"direction": direction, "zero_offset": zero, "position_limits": (lower, upper)}


# ---------------------------------------------------------------------------- from LeRobot's calibration

LEROBOT_KEYS = ("id", "drive_mode", "homing_offset", "range_min", "range_max")


def from_lerobot(config_name: str, calibration: str, joints: list[str] | None, confirm, write_to: str | None,
                 say=print) -> int:
    """A LeRobot calibration (lerobot-calibrate's JSON: per motor id, drive_mode, homing_offset,
    range_min, range_max, in the servo's steps) written into the configuration's joints, nothing
    moved: `zero_offset` the recorded range's middle (LeRobot's zero, which its degrees are about;
    the servo keeps LeRobot's Homing_Offset, so Present Position is already relative to it), the
    gripper's recorded range laid on the model's instead (LeRobot records it 0..100 over its range),
    `position_limits` the recorded stops (within the model's limits). The sign: LeRobot's drive_mode 1
    negates a joint's reading; the configuration's `direction` is the model's sign for the servo as
    mounted (the SO-101's URDF turns positive with every horn: direction +1). A calibration whose
    drive_mode disagrees with it would play every recording of that joint mirrored: refused."""
    config = load_config(config_name)
    data = _read_lerobot_calibration(calibration)
    step = 2 * math.pi / RESOLUTION
    chosen = [j for j in config.joints if joints is None or j.dof in joints]
    unknown = sorted(set(joints or ()) - {j.dof for j in config.joints})
    if unknown:
        raise BadRequest(f"'{config.name}' has no joint '{unknown[0]}'")
    extra = sorted(set(data) - {j.dof for j in config.joints})
    if extra:
        raise BadRequest(f"{calibration}: motor '{extra[0]}' names no joint of '{config.name}' "
                         f"(its joints: {', '.join(config.model.dof_names)})")
    try:
        patch = ConfigPatch.of(config, write_to)
    except OSError as err:
        raise BadRequest(str(err)) from None
    for joint in chosen:
        entry = data.get(joint.dof)
        if entry is None:
            raise BadRequest(f"{calibration}: no motor '{joint.dof}' for joint '{joint.dof}' of '{config.name}'")
        name = f"{calibration}: '{joint.dof}'"
        if not backend(config.buses[joint.bus].kind).lerobot_calibration:
            raise BadRequest(f"joint '{joint.dof}' is on a {config.buses[joint.bus].kind} bus: --from-lerobot reads "
                             "LeRobot's Feetech calibrations (on its Dynamixel buses the drive mode is written into "
                             "the servo, which servodyn's setup clears); calibrate it with servodyn calibrate")
        if entry["id"] != joint.id:
            raise BadRequest(f"{name} is servo id {entry['id']}, the configuration's is {joint.id}")
        sign = -1 if entry["drive_mode"] else 1
        if sign != joint.direction:
            raise BadRequest(f"{name} has drive_mode {entry['drive_mode']} (LeRobot {'negates' if sign < 0 else 'keeps'} "
                             f"its reading), but the model turns it {'with' if joint.direction > 0 else 'against'} "
                             f"the servo (direction {joint.direction:+d}): a flipped calibration, which would play "
                             f"every recording of it mirrored; recalibrate it (nothing written)")
        j = config.model.dof_names.index(joint.dof)
        lower, upper = float(config.model.lower[j]), float(config.model.upper[j])
        scale = joint.direction * joint.gear_ratio
        middle = (entry["range_min"] + entry["range_max"]) / 2
        centre = (lower + upper) / 2 if joint.dof in GRIPPERS else 0.0   # q where the range's middle lies
        zero = middle * step - scale * centre
        stops = sorted(((entry["range_min"] - middle) * step / scale + centre,
                        (entry["range_max"] - middle) * step / scale + centre))
        limits = (max(stops[0], lower), min(stops[1], upper))
        clipped = limits != (stops[0], stops[1])
        say(f"  {joint.dof}: zero at step {middle:g} (horn {math.degrees(zero):.2f}°), stops "
            f"{math.degrees(stops[0]):.1f}° .. {math.degrees(stops[1]):.1f}°"
            + (f" (limited to the model's {math.degrees(lower):.1f}° .. {math.degrees(upper):.1f}°)" if clipped else "")
            + f", direction {joint.direction:+d} as the model's")
        patch.set_joint(joint.dof, zero_offset=zero, position_limits=limits)
    return patch.offer(confirm, say)


def _read_lerobot_calibration(path: str) -> dict:
    """{motor: {id, drive_mode, homing_offset, range_min, range_max}} of a LeRobot calibration file,
    one line for anything else."""
    import json
    try:
        data = json.loads(open(path, encoding="utf-8").read())
    except FileNotFoundError:
        raise BadRequest(f"{path}: no such LeRobot calibration file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise BadRequest(f"{path}: not a LeRobot calibration (JSON): {err}") from None
    if not isinstance(data, dict) or not data:
        raise BadRequest(f"{path}: not a LeRobot calibration: expected {{motor: {{{', '.join(LEROBOT_KEYS)}}}}}")
    for motor, entry in data.items():
        if not isinstance(entry, dict):
            raise BadRequest(f"{path}: '{motor}' is not a table of {', '.join(LEROBOT_KEYS)}")
        for key in LEROBOT_KEYS:
            value = entry.get(key)
            if isinstance(value, bool) or not isinstance(value, int):
                raise BadRequest(f"{path}: '{motor}'.{key} must be a whole number, got {value!r}")
        if abs(entry["homing_offset"]) > RESOLUTION // 2 - 1:      # 11 bits and a sign bit in the servo
            raise BadRequest(f"{path}: '{motor}'.homing_offset {entry['homing_offset']} is beyond the servo's "
                             f"±{RESOLUTION // 2 - 1} steps")
        if entry["drive_mode"] not in (0, 1):
            raise BadRequest(f"{path}: '{motor}'.drive_mode must be 0 or 1, got {entry['drive_mode']}")
        if not 0 <= entry["range_min"] < entry["range_max"] < RESOLUTION:
            raise BadRequest(f"{path}: '{motor}' range_min {entry['range_min']} .. range_max {entry['range_max']} is "
                             "no range of steps")
    return data
