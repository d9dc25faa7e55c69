"""argparse types that refuse a value that makes no sense before the command starts: argparse
prints the one line `PROG: error: argument --repeat: ...` and exits 2."""

from __future__ import annotations

import argparse
import math

from ...errors import InputError
from ...hal.contact_spec import Plane, Push, Sphere


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


def _numbers(text: str, count: int, what: str) -> list[float]:
    parts = text.split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{what}: {count} finite numbers separated by commas, got {text!r}")
    return values


def contact(text: str):
    """`BODY:FX,FY,FZ@T[+D]` (N, world frame, at the body's centre of mass, from T s after the
    motion starts for D s) as a hal.contact_spec.Push; the body is checked against the model later."""
    body, colon, rest = text.partition(":")
    force, at, when = rest.partition("@")
    start, plus, duration = when.partition("+")
    if not (body and colon and at and start):
        raise argparse.ArgumentTypeError(f"a contact is BODY:FX,FY,FZ@T[+D] (e.g. r_hand:0,0,-10@1.2+0.3), "
                                         f"got {text!r}")
    fx, fy, fz = _numbers(force, 3, "a contact's force FX,FY,FZ (N)")
    (t,) = _numbers(start, 1, "a contact's start T (s after the motion starts)")
    extra = {"duration": _numbers(duration, 1, "a contact's duration D (s)")[0]} if plus else {}
    try:
        return Push(body, (fx, fy, fz), t, **extra)
    except InputError as err:
        raise argparse.ArgumentTypeError(str(err)) from None



def obstacle(text: str):
    """`plane:NX,NY,NZ,D[@K]` or `sphere:X,Y,Z,R[@K]` (m, K in N/m) as hal.contact_spec's Plane or
    Sphere."""
    kind, colon, rest = text.partition(":")
    values, at, stiffness = rest.partition("@")
    if kind not in ("plane", "sphere") or not colon:
        raise argparse.ArgumentTypeError(f"an obstacle is plane:NX,NY,NZ,D[@K] or sphere:X,Y,Z,R[@K] (m, K in N/m), "
                                         f"got {text!r}")
    what = "a plane's NX,NY,NZ,D" if kind == "plane" else "a sphere's X,Y,Z,R (m)"
    a, b, c, d = _numbers(values, 4, what)
    extra = {"stiffness": _numbers(stiffness, 1, f"a {kind}'s stiffness K (N/m)")[0]} if at else {}
    try:
        return Plane((a, b, c), d, **extra) if kind == "plane" else Sphere((a, b, c), d, **extra)
    except InputError as err:
        raise argparse.ArgumentTypeError(str(err)) from None

