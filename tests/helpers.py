"""The tests' tools, each written once: the command line run as a user runs it (`run_cli` to its
end, `start_cli` left running, `sim_process` for `servodyn sim`, `answer_prompts` at its prompts; the
`cli` fixture of conftest.py runs it in this process), a wait that polls a condition (`wait_until`) and one for a log that
streams to disk (`wait_for_rows`), and a `say` that prints nothing (`quiet`)."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, TypeVar

# The servodyn command, run by the interpreter that runs the tests: the same installation whatever
# virtual environment pytest was started from (the `.venv/bin/servodyn` script would assume one).
CLI = (sys.executable, "-m", "servodyn.tools.cli")

# Long enough for the longest command a test runs whole (a swing, a validation with its
# simulation, a firmware build) on a busy 2-core machine; pytest-timeout's 300 s per test is the
# cap above it.
CLI_TIMEOUT = 240.0

# How often a wait looks again: a tenth of a second is below what any condition here needs
# resolved (the log streams every 100 ms), and light on a shared CPU.
POLL = 0.05

T = TypeVar("T")


def _environ(env: dict | None) -> dict | None:
    """The test's environment with `env`'s entries over it (None: the test's own)."""
    return None if env is None else {**os.environ, **env}


def run_cli(*args, timeout: float = CLI_TIMEOUT, input: str | None = None, env: dict | None = None,
            cwd: Path | str | None = None) -> subprocess.CompletedProcess:
    """`servodyn ARGS...` in a process of its own, to the end: its exit status and its stdout and
    stderr as text. `env` adds to (does not replace) the environment."""
    return subprocess.run([*CLI, *map(str, args)], input=input, capture_output=True, text=True,
                          timeout=timeout, env=_environ(env), cwd=cwd)


def start_cli(*args, env: dict | None = None, **popen) -> subprocess.Popen:
    """`servodyn ARGS...` started and left running (a simulator, a swing to signal): the caller
    waits for it, or kills it. Keyword arguments go to subprocess.Popen (stdout, stderr, ...)."""
    return subprocess.Popen([*CLI, *map(str, args)], env=_environ(env), **popen)


# a pseudo-terminal named in `servodyn sim`'s banner
PTY = re.compile(r"/dev/pts/\d+")


@contextmanager
def sim_process(*args, ports: int = 1, **popen) -> Iterator[tuple[subprocess.Popen, list[str]]]:
    """`servodyn sim ARGS...` in a process of its own, serving: the process, and its banner's
    lines up to the one that names the `ports`-th pseudo-terminal, read from stdout and stderr
    together (so whichever stream carries them); PTY finds the paths in them. Stopped (SIGTERM)
    at the end if still running; a test that stops it itself reads the rest from proc.stdout."""
    proc = start_cli("sim", *args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **popen)
    try:
        banner: list[str] = []
        while len(PTY.findall("".join(banner))) < ports:
            line = proc.stdout.readline()
            if not line:
                raise AssertionError(f"servodyn sim ended (exit {proc.wait()}) before serving:\n" + "".join(banner))
            banner.append(line)
        yield proc, banner
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()


def answer_prompts(proc: subprocess.Popen, at_enter: Callable[[], object]) -> str:
    """A person at the keyboard of `proc` (started with stdin and stdout piped, stderr into
    stdout, as text): at each "[Enter] " prompt does `at_enter()` (moves the arm) and presses
    Enter, and answers each "[y/N] " with y; the whole transcript once `proc` closes its output."""
    transcript, buffer = [], ""
    while ch := proc.stdout.read(1):
        buffer += ch
        if buffer.endswith(("[Enter] ", "[y/N] ")):
            transcript.append(buffer)
            if buffer.endswith("[Enter] "):
                at_enter()
            proc.stdin.write("\n" if buffer.endswith("[Enter] ") else "y\n")
            proc.stdin.flush()
            buffer = ""
    return "".join(transcript) + buffer


def wait_until(condition: Callable[[], T], timeout: float, every: float = POLL) -> T:
    """Call `condition` every `every` seconds until it returns something true or `timeout` seconds
    have passed; its last value either way (the caller asserts on it, with its own words)."""
    deadline = time.monotonic() + timeout
    while not (value := condition()) and time.monotonic() < deadline:
        time.sleep(every)
    return value


def csv_rows(path: Path) -> list[list[str]]:
    """The rows of a CSV file, its header first; none before the file exists."""
    if not Path(path).exists():
        return []
    with open(path, newline="") as f:
        return list(csv.reader(f))


def wait_for_rows(path: Path, count: int, timeout: float = 120.0, proc: subprocess.Popen | None = None) -> int:
    """Until the streamed log at `path` holds `count` data rows, or `proc` (the process writing it)
    ended, or `timeout` passed; the rows there then. The log streams whole lines every 100 ms
    (loop.RunLog), so polling every POLL sees each write within half a write's interval."""
    ticks = lambda: max(len(csv_rows(path)) - 1, 0)
    wait_until(lambda: ticks() >= count or (proc is not None and proc.poll() is not None), timeout)
    return ticks()


def quiet(*args, **kwargs) -> None:
    """A `say` that says nothing."""
