"""The command line's one question: yes or no, on standard input."""

from __future__ import annotations

import sys
from typing import Callable


def ask(question: str, yes: bool, say: Callable = print) -> bool:
    """A yes/no question on standard input (`yes`: answered yes without asking); no at end of input."""
    if yes:
        say(f"{question} [y/N] yes (--yes)")
        return True
    say(f"{question} [y/N] ", end="", flush=True)
    answer = sys.stdin.readline()
    if not sys.stdin.isatty():         # a piped answer is not echoed: the transcript shows it
        say(answer.strip())
    return answer.strip().lower() in ("y", "yes")
