"""What the verbs share: the one `say` (messages on stderr), the command line's own error, the
bus options of the bring-up verbs, and how a verb's help states its exit statuses and example."""

from __future__ import annotations

import argparse
import sys
from typing import Callable, NamedTuple

from ...errors import ExitCode, ServodynError


class CliError(ServodynError):
    """A command line that makes no sense (two options that exclude each other, a missing one)."""

    def __init__(self, message: str, exit_code: int = ExitCode.BAD_INPUT):
        super().__init__(message)
        self.exit_code = exit_code


class Verb(NamedTuple):
    """One verb of a family module (a lone verb's module has these two as functions)."""
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def say(*args, **kwargs) -> None:
    """A message or a progress line: on stderr, at once (stdout carries a command's data alone)."""
    kwargs.setdefault("flush", True)
    print(*args, file=sys.stderr, **kwargs)


def describe(parser: argparse.ArgumentParser, description: str, *examples: str, exits: str | None = None) -> None:
    """A verb's help: what it does, its exit statuses (`exits`: the statuses other than bad input,
    e.g. "0 pass, 1 fail"; ExitCode.BAD_INPUT is added) and one or more examples."""
    if exits is not None:
        description += f" Exit status {exits}, {int(ExitCode.BAD_INPUT)} bad input."
    parser.description = description
    parser.epilog = "example" + ("s" if len(examples) > 1 else "") + ":\n" + "".join(f"  {e}\n" for e in examples)


def out_folder(parser: argparse.ArgumentParser, default: str | None, what: str = "output folder") -> None:
    """-o/--out DIR: the folder a verb writes into."""
    shown = f"(default {default})" if default else "(required)"
    parser.add_argument("-o", "--out", default=default, required=default is None, metavar="DIR",
                        help=f"{what} {shown}")


PORT_HELP = ("the bus's serial port or CAN channel (default: the configuration's); a configuration with several "
             "buses names each: --port shoulder=can0 --port wrist=/dev/ttyUSB0")


def port_option(parser: argparse.ArgumentParser, help: str = PORT_HELP) -> None:
    parser.add_argument("--port", action="append", default=None, metavar="PATH|BUS=PATH", help=help)


def bus_options(parser: argparse.ArgumentParser) -> None:
    """--config and --port, as every bring-up verb on a configuration's buses takes them."""
    parser.add_argument("--config", required=True, help="robot configuration")
    port_option(parser)
