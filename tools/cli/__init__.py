"""The `servodyn` command line: one module per verb (tools/cli/<verb>.py, or a small family of
verbs in one module), found by name in `VERBS` and imported only when that verb runs, as
python-can finds its backends. A verb has `add_arguments(parser)` and `run(args) -> int`.

One error handler: a `ServodynError` is one line `servodyn: error: ...` and its exit status; an
unreadable or unwritable file one line naming it; Ctrl-C 130; anything else is a bug, and its
traceback is shown."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from importlib import metadata
from typing import NamedTuple

from ... import __version__
from ...errors import ExitCode, ServodynError
from .argtypes import OneLineParser


class Entry(NamedTuple):
    module: str       # the verb's module, or module:name for one of a family's verbs
    summary: str      # one line in `servodyn --help`


VERBS = {
    "list": Entry("servodyn.tools.cli.catalogue:list_", "list the built-in models, configurations and motions"),
    "models": Entry("servodyn.tools.cli.catalogue:models", "list the built-in models with their bodies and dofs"),
    "torques": Entry("servodyn.tools.cli.torques", "offline inverse dynamics of a trajectory CSV"),
    "export": Entry("servodyn.tools.cli.export", "write a model as URDF"),
    "experiment": Entry("servodyn.tools.cli.experiment", "run one of the paper's experiments"),
    "swing": Entry("servodyn.tools.cli.swing", "play a motion on servos (the simulated bus by default)"),
    "view": Entry("servodyn.tools.cli.view", "the arm in 3-D in a browser: play, compare, shape keyframes"),
    "sim": Entry("servodyn.tools.cli.sim", "serve the simulated bus on a pseudo-terminal"),
    "ports": Entry("servodyn.tools.cli.ports", "list serial adapters and CAN links, and what is in their way"),
    "scan": Entry("servodyn.tools.cli.bringup:scan", "find servos at every ID and baud rate (broadcast ping)"),
    "setup": Entry("servodyn.tools.cli.bringup:setup", "make one new servo a joint of the configuration"),
    "doctor": Entry("servodyn.tools.cli.bringup:doctor", "check the host, the port and every servo (read only)"),
    "monitor": Entry("servodyn.tools.cli.bringup:monitor", "torque off, every joint live in SI and raw units"),
    "calibrate": Entry("servodyn.tools.cli.bringup:calibrate", "find each joint's direction, zero and stops by hand"),
    "reboot": Entry("servodyn.tools.cli.bringup:reboot", "reboot every servo (clears a latched hardware error)"),
    "clear-errors": Entry("servodyn.tools.cli.bringup:clear_errors",
                          "clear what can be cleared without a reboot, and say the rest"),
    "torque": Entry("servodyn.tools.cli.bringup:torque", "torque off on every servo of every bus: the panic button"),
    "codegen": Entry("servodyn.tools.cli.codegen", "write a configuration and its motion as C for the firmware"),
    "firmware": Entry("servodyn.tools.cli.firmware", "run the firmware under QEMU on the simulated bus (HIL)"),
    "validate": Entry("servodyn.tools.cli.validate", "check a motion against the servos' limits before it runs"),
    "mocap": Entry("servodyn.tools.cli.mocap:mocap", "what a motion capture file (BVH) holds"),
    "retarget": Entry("servodyn.tools.cli.mocap:retarget", "a captured arm (BVH) as a motion of the model's arm"),
    "export-bvh": Entry("servodyn.tools.cli.mocap:export_bvh",
                        "a motion of a model's arm as a BVH clip (Blender, retarget)"),
    "size": Entry("servodyn.tools.cli.size", "choose each joint's servo so that the motions pass"),
    "ik": Entry("servodyn.tools.cli.ik", "joint angles that put the hand at a point (or along a path)"),
    "excite": Entry("servodyn.tools.cli.excite", "write an exciting trajectory for servodyn identify"),
    "identify": Entry("servodyn.tools.cli.identify", "friction, armature, torque constants, payload from logs"),
    "replay": Entry("servodyn.tools.cli.replay", "servo-bench logs replayed through the servo model, scored"),
    "demo": Entry("servodyn.tools.cli.demo", "torque profile of a sample reach of the built-in arm"),
    "soak": Entry("servodyn.tools.cli.soak", "swings with a random fault each: every one a safe stop"),
    "contact": Entry("servodyn.tools.cli.contact_thresholds", "calibrate the contact watch's thresholds on clean runs"),
}


def load(name: str):
    """The verb `name`: its module (or the family member it names), with add_arguments and run."""
    module, _, member = VERBS[name].module.partition(":")
    found = importlib.import_module(module)
    return getattr(found, member) if member else found


class Formatter(argparse.HelpFormatter):
    """argparse measures the subcommands' names one indent short of where it prints them, so a
    name as long as 'experiment' pushed its help to a line of its own: measured where printed. A
    text with line breaks of its own (a verb's examples) is printed as written."""

    def add_argument(self, action):
        super().add_argument(action)
        if isinstance(action, argparse._SubParsersAction) and action.choices:
            longest = max(map(len, action.choices)) + self._current_indent + self._indent_increment
            self._action_max_length = max(self._action_max_length, longest)

    def _fill_text(self, text, width, indent):
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def parser_for(verb: str | None) -> argparse.ArgumentParser:
    """The command line's parser, with the arguments of `verb` alone (the one that runs): the other
    verbs are named with their summary, and none of their modules is imported."""
    parser = OneLineParser(prog="servodyn", formatter_class=Formatter,
                           description="Closed-form inverse and direct dynamics for a servo-driven humanoid arm.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, entry in VERBS.items():
        p = sub.add_parser(name, help=entry.summary, description=entry.summary[0].upper() + entry.summary[1:] + ".",
                           formatter_class=Formatter)
        if name == verb:
            found = load(name)
            found.add_arguments(p)
            p.set_defaults(run=found.run)
    return parser


def _version() -> str:
    """The installed package's version (its metadata), or the source tree's when not installed."""
    try:
        return metadata.version("servodyn")
    except metadata.PackageNotFoundError:
        return __version__


def _file_error(err: OSError, args) -> str:
    """One line for a file the command could not read or write: the path and the reason. A
    write that fails on close (a full device) carries no file name; the command's output does."""
    path = err.filename or getattr(args, "output", None) or getattr(args, "out", None)
    if isinstance(err, IsADirectoryError):
        reason = "is a folder, not a file"
    elif isinstance(err, (FileExistsError, NotADirectoryError)):
        reason = "is a file where a folder is needed"
    else:
        reason = err.strerror or str(err)
    return f"{path}: {reason}" if path else reason


# numpy's floating-point warnings: raised as errors in a command, so a result computed from an
# overflow or a 0/0 is never printed beside a warning the user cannot act on
NUMPY_WARNINGS = r"(overflow|invalid value|divide by zero) encountered"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    verb = next((a for a in argv if not a.startswith("-")), None)
    try:
        args = parser_for(verb if verb in VERBS else None).parse_args(argv)
    except SystemExit as done:       # --help, --version, or argparse's one line: its status, returned
        return done.code if isinstance(done.code, int) else ExitCode.BAD_INPUT
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=NUMPY_WARNINGS, category=RuntimeWarning)
        return _run(args)


def _run(args) -> int:
    """The verb run, and the one place its errors become a line and an exit status."""
    def error(text: str, code: int = ExitCode.BAD_INPUT) -> int:
        print(f"servodyn: error: {text}", file=sys.stderr)
        return int(code)
    try:
        return int(args.run(args) or 0)
    except ServodynError as err:
        return error(str(err), err.exit_code)
    except RuntimeWarning as err:      # numpy's, raised (main): an input far outside double precision
        return error(f"a computation left the range of double precision ({err}): an input is far outside what "
                     "the model and the servos allow")
    except FloatingPointError as err:  # the C core's non-finite result, which names the sample
        return error(str(err))
    except BrokenPipeError:        # `servodyn list | head`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as err:
        return error(_file_error(err, args))
    except KeyboardInterrupt:
        print("servodyn: interrupted", file=sys.stderr)
        return 130
