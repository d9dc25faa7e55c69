"""Every error servodyn raises, in one tree, and the exit status each one stops a run with.

    ServodynError                       exit 2 unless a subclass says otherwise
    ├── InputError                      bad input a library was given (also a ValueError)
    ├── hal.errors.HalError             the HAL's tree (configurations, codecs, servos and buses)
    ├── model.ModelError                a model, a motion or a pose that cannot be used (also a ValueError)
    ├── control.trajectory.TrajectoryError, mocap's BvhError, SkeletonError, RetargetError,
    │   loop.log.RunLogError, identification's IdentificationError and SignalError,
    │   validation.sizing.SizingError: each library's bad input, in its own words (also ValueErrors)
    ├── control.ControlFault            a non-finite desired or measured state        (13)
    ├── validation.MotionRefused        the validator refused a motion before it moved (2)
    ├── loop.Overrun                    a real-time loop fell behind its schedule       (14)
    ├── loop.Interrupted                SIGINT or SIGTERM stopped a run                 (128 + signal)
    └── the commands' own (tools/): a bring-up finding, a declined move, a simulator or firmware
        that would not start, a command line that makes no sense (tools/cli)

`ExitCode` is the one table of exit statuses: the firmware's fault codes (firmware/app/fw_app.h,
enum fw_fault_: FW_FAULT_<NAME> = ExitCode.<NAME>; tests/test_soak.py compares the two), so a
run stopped by the Python loop, the native loop or the firmware under QEMU exits alike.
"""

from __future__ import annotations

from enum import IntEnum


class ExitCode(IntEnum):
    """An exit status and what it means (`meaning`, the words a command's help shows)."""

    def __new__(cls, value: int, meaning: str):
        member = int.__new__(cls, value)
        member._value_ = value
        member.meaning = meaning
        return member

    OK = 0, "completed"
    BAD_INPUT = 2, "bad input, or an error without a code of its own"
    TIMEOUT = 10, "a servo, or the whole bus, did not answer"
    STATUS = 11, "a servo reported a hardware error"
    CORRUPT = 12, "a corrupt or refused reply, a failed write"
    NONFINITE = 13, "a non-finite desired or measured state, or torque"
    OVERRUN = 14, "the loop fell behind its period past its tolerance"
    RANGE = 15, "a joint measured beyond its limits"
    SETUP = 16, "a servo refused the set-up (wrong model, a write error)"
    OVERFLOW = 17, "finite measurements, a non-finite torque (the firmware's overflow)"
    CONTACT = 18, "the arm met something: a contact was detected, and the reaction ran"
    FOLLOWING_ERROR = 19, "a joint fell further behind its command than its following-error limit"
    STALL = 20, "a joint held at its torque limit without moving (pressed on a stop)"


def exit_codes_help(*codes: ExitCode) -> str:
    """`10 a servo, or the whole bus, did not answer, 11 ...`: exit statuses as a command's help says them."""
    return "; ".join(f"{int(code)} {code.meaning}" for code in codes)


FAULT_CODES = tuple(code for code in ExitCode if code >= ExitCode.TIMEOUT)     # a run's safe stops


class ServodynError(Exception):
    """Root of every error servodyn raises; `exit_code` is the status a run stopped by it ends with."""
    exit_code: int = ExitCode.BAD_INPUT


class InputError(ServodynError, ValueError):
    """Bad input a library was given (a number out of range, a file that holds nothing usable); the
    message names the value in the library's words, a command's checks name the option."""


# errors of Python's own that a run can stop on, and their codes
_BUILTIN_CODES = ((TimeoutError, ExitCode.TIMEOUT), (FloatingPointError, ExitCode.NONFINITE))


def exit_code(error: BaseException | None) -> int:
    """The exit status of a run that `error` stopped (None: it completed)."""
    if error is None:
        return ExitCode.OK
    code = getattr(error, "exit_code", None)
    if isinstance(code, int):
        return int(code)
    return int(next((c for kind, c in _BUILTIN_CODES if isinstance(error, kind)), ExitCode.BAD_INPUT))
