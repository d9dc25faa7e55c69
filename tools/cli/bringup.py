"""The bring-up verbs, from a box of servos to an arm that moves (tools/bringup/): scan, setup,
doctor, monitor, calibrate, reboot, clear-errors and `torque off`. What they find or read back
(scan's servos, doctor's findings, monitor's table, each servo's state after reboot, clear-errors
and torque off) is their data, on stdout; the steps and questions of setup and calibrate, which
write to the servos and the configuration, on stderr."""

from __future__ import annotations

from .. import bringup
from ..bringup.calibrate import from_lerobot
from .argtypes import count, number
from .common import CliError, Verb, bus_options, describe, port_option, say
from .prompt import ask


def _confirm(args):
    """The question a writing verb asks before it writes (--yes answers it)."""
    return lambda question: ask(question, args.yes, say)

FINDINGS = "0 all well, 1 findings"
lerobot_calibration = bringup.command(from_lerobot)     # its HAL errors one line, as every bring-up verb's
LEROBOT_ARM = "so101"          # the configuration a LeRobot calibration is written into unless --config names one


def _scan_arguments(p) -> None:
    describe(p, "Protocol 2.0 broadcast ping at each baud rate (57600 first, a new servo's rate, then 4.5M down to "
             "9600): each servo's ID, model, firmware and rate; on a Feetech bus an STS broadcast ping at each of its 8 rates "
             "(1000000 first). With --config, what differs from it, each with its fix.", "servodyn scan --port /dev/ttyUSB0 --baud 57600,4000000",
             exits="0 found (and as configured), 1 nothing found or findings")
    port_option(p)
    p.add_argument("--baud", default="all", metavar="all|RATE,...", help="the rates to try (default all)")
    p.add_argument("--config", default=None, help="robot configuration to compare with (and its ports)")
    p.add_argument("--json", action="store_true",
                   help="print a list of objects with id, model_number, model, firmware, baud")


def _setup_arguments(p) -> None:
    describe(p, "With only that servo connected: find it at any ID and baud rate, check its model, show what it will "
             "write (ID, Return Delay Time 0, Drive Mode reverse bit clear, Homing Offset 0, Current Limit, the bus's "
             "baud rate last), ask, write it to the EEPROM with torque off and find it again at its new ID and rate. A "
             "Feetech servo: through its EEPROM lock, read back after a restart.",
             "servodyn setup --config my_arm.toml --joint r_elbow_flexion --port /dev/ttyUSB0")
    bus_options(p)
    p.add_argument("--joint", required=True, metavar="DOF", help="the joint this servo drives")
    p.add_argument("--yes", action="store_true", help="write without asking")


def _doctor_arguments(p) -> None:
    describe(p, "Read only. The port (exists, permission, not held by another program, latency timer) and every "
             "servo: present at its ID and rate, model, firmware >= 45, Drive Mode, Homing Offset, Status Return "
             "Level, Current Limit against the configuration, input voltage against [supply], Hardware Error Status, "
             "the Bus Watchdog. One line per finding with its fix.",
             "servodyn doctor --config replica --port /dev/ttyUSB0 --json", exits=FINDINGS)
    bus_options(p)
    p.add_argument("--json", action="store_true",
                   help='print {"findings": [{"joint", "id", "check", "found", "expected", "fix"}, ...]}')


def _monitor_arguments(p) -> None:
    describe(p, "Switch torque off on every servo, then show every joint's position, speed, current, temperature, "
             "voltage and error, in SI and in register units, refreshed in place until Ctrl-C.",
             "servodyn monitor --config replica --rate 5")
    bus_options(p)
    p.add_argument("--rate", type=number(0.1, 100, "refreshes per second"), default=10.0, metavar="HZ",
                   help="refreshes per second (default 10)")
    p.add_argument("--count", type=count(1, what="refreshes"), default=None, metavar="N",
                   help="stop after N refreshes (default: until Ctrl-C)")


def _calibrate_arguments(p) -> None:
    describe(p, "Torque off; for each joint you move it in its + direction (its `direction`), put it in its zero pose "
             "from both sides (`zero_offset`, their mean) and move it to both stops (`position_limits`, a margin "
             "inside). The configuration is then patched, its comments and layout kept, after the change is shown "
             "and confirmed; a built-in configuration's patched copy goes to ./NAME.toml.",
             "servodyn calibrate --config my_arm.toml --joint r_elbow_flexion",
             "servodyn calibrate --config so101 --from-lerobot ~/.cache/huggingface/lerobot/calibration/robots/"
             "so101_follower/my_arm.json --write my_so101.toml")
    p.add_argument("--config", default=None,
                   help="robot configuration (required; with --from-lerobot the default is so101, LeRobot's SO-101 "
                        "follower)")
    port_option(p)
    p.add_argument("--from-lerobot", default=None, metavar="CALIBRATION.json",
                   help="move nothing: write a LeRobot calibration (lerobot-calibrate's file: per motor id, drive_mode, "
                        "homing_offset, range_min, range_max) into the joints' zero_offset and position_limits, each "
                        "joint's sign checked against the model (a flipped one refused); docs/lerobot.md")
    p.add_argument("--joint", action="append", default=None, metavar="DOF", help="only this joint (repeatable)")
    p.add_argument("--margin", type=number(0, what="degrees"), default=3.0, metavar="DEG",
                   help="how far inside the stops the limits go (default 3 degrees)")
    p.add_argument("--write", default=None, metavar="FILE",
                   help="write the patched configuration here (default: the configuration itself)")
    p.add_argument("--yes", action="store_true", help="write without asking")


def _reboot_arguments(p) -> None:
    describe(p, "REBOOT every servo of the configuration (a latched hardware error, such as an overload, is cleared "
             "only so or by a power cycle), then read each one's error back.", "servodyn reboot --config replica")
    bus_options(p)
    p.add_argument("--yes", action="store_true", help="reboot without asking")


def _clear_errors_arguments(p) -> None:
    describe(p, "Clear a tripped Bus Watchdog on every servo (a CAN motor's error), then read each one's error back; "
             "a latched hardware error needs `servodyn reboot`.", "servodyn clear-errors --config replica")
    bus_options(p)


def _torque_arguments(p) -> None:
    describe(p, "Torque off on every servo of every bus of the configuration (a broadcast, so a servo at an "
             "unexpected ID too), then read each one back.", "servodyn torque off --config replica")
    p.add_argument("state", choices=["off"], help="off")
    bus_options(p)


scan = Verb(_scan_arguments, lambda a: bringup.scan(a.port, a.baud, a.config, a.json))
setup = Verb(_setup_arguments, lambda a: bringup.setup(a.config, a.joint, a.port, _confirm(a), say=say))
doctor = Verb(_doctor_arguments, lambda a: bringup.doctor(a.config, a.port, a.json))
monitor = Verb(_monitor_arguments, lambda a: bringup.monitor(a.config, a.port, a.count, a.rate))
def _calibrate(a) -> int:
    if a.from_lerobot is not None:
        return lerobot_calibration(a.config or LEROBOT_ARM, a.from_lerobot, a.joint, _confirm(a), a.write, say=say)
    if a.config is None:
        raise CliError("calibrate moves the joints of a configuration: give --config CONFIG")
    return bringup.calibrate(a.config, a.port, a.joint, a.margin, _confirm(a), a.write, say=say)


calibrate = Verb(_calibrate_arguments, _calibrate)
reboot = Verb(_reboot_arguments, lambda a: bringup.reboot(a.config, a.port, _confirm(a)))
clear_errors = Verb(_clear_errors_arguments, lambda a: bringup.clear_errors(a.config, a.port))
torque = Verb(_torque_arguments, lambda a: bringup.torque_off(a.config, a.port))
