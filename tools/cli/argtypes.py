"""argparse types that refuse a value that makes no sense before the command starts: argparse
prints the one line `PROG: error: argument --repeat: ...` and exits 2."""

from __future__ import annotations

import argparse
import math


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


def number(low: float | None = None, high: float | None = None, what: str = "", above: bool = False):
    """A finite float type from `low` (excluded when `above`) to `high` (None: no bound); `what`
    names the unit or the reason. nan and inf are refused: no option means them."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
        too_low = low is not None and (value <= low if above else value < low)
        if not math.isfinite(value) or too_low or (high is not None and value > high):
            if low == 0 and above and high is None:
                span = "a positive number"
            elif high is None:
                span = f"a number {'above' if above else 'of at least'} {low:g}"
            elif low is None:
                span = f"a number up to {high:g}"
            else:
                span = f"a number from {low:g}{' (excluded)' if above else ''} to {high:g}"
            raise argparse.ArgumentTypeError(f"must be {span}{f' ({what})' if what else ''}, got {text}")
        return value
    parse.__name__ = "number"
    return parse


positive = number(0, above=True)

tcp_port = count(0, 65535, "a TCP port")


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose refusal is one line, `servodyn: error: ...` (where to read the
    usage at its end), exit status 2: argparse's own prints the whole usage first."""

    def error(self, message: str):
        root = self.prog.split()[0]
        self.exit(2, f"{root}: error: {message} (usage: {self.prog} --help)\n")
