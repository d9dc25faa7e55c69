"""argparse types that refuse a value that makes no sense before the command starts: argparse
prints the one line `PROG: error: argument --repeat: ...` and exits 2."""

from __future__ import annotations

import argparse


def count(low: int = 1, high: int | None = None, what: str = ""):
    """An integer type from `low` to `high` (None: no upper bound); `what` says why the range."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
        if value < low or (high is not None and value > high):
            span = f"from {low} to {high}" if high is not None else f"{low} or more"
            raise argparse.ArgumentTypeError(f"must be {span}{f' ({what})' if what else ''}, got {value}")
        return value
    parse.__name__ = "count"        # argparse names the type in its own messages
    return parse


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose refusal is one line, `servodyn: error: ...` (where to read the
    usage at its end), exit status 2: argparse's own prints the whole usage first."""

    def error(self, message: str):
        root = self.prog.split()[0]
        self.exit(2, f"{root}: error: {message} (usage: {self.prog} --help)\n")
