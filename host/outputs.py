"""A command's output file, checked against the files it reads before anything is written: an output
that is one of its inputs (the same file under any name: another path to it, a symlink, a hard
link) would replace what the command reads, and the user's file would be lost."""

from __future__ import annotations

import os
from pathlib import Path

from .control.trajectory import TrajectoryError
from .errors import ServodynError


class OutputIsInput(TrajectoryError, ServodynError):
    """The trajectory a command would write is one of its own inputs (exit status 2)."""


def refuse_input_as_output(output: str | Path, option: str, inputs: dict[str, str | Path | None]) -> None:
    """OutputIsInput when `output` (given as `option`) is the same file as one of `inputs` (what
    names each input on the command line -> its path; None: none given). An output that does not
    exist yet is no input."""
    for named, path in inputs.items():
        if path is None:
            continue
        try:
            same = os.path.samefile(output, path)
        except (OSError, ValueError):       # either does not exist (or cannot be a path): not the same
            continue
        if same:
            raise OutputIsInput(f"{option} {output}: the same file as {named} {path}, which the command reads: "
                                "name another file for what it writes")
