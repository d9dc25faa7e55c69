"""Regenerate (or, with --check, verify) the figures the documents quote from the commands.

    python scripts/docs/docs.py            # rewrite every document's cog blocks and the view's
                                           # pictures (make docs; scripts/docs/screenshots.py)
    python scripts/docs/docs.py --check    # fail, with a diff, where a document is out of date

The documents are every tracked Markdown (and TOML: a configuration's comments) file with a cog
block; one cog process runs them all, so
each command behind them runs once (scripts/docs/figures.py).
"""

import subprocess
import sys
from pathlib import Path

from cogapp import Cog

ROOT = Path(__file__).resolve().parents[2]


def documents() -> list[str]:
    try:
        files = subprocess.run(["git", "ls-files", "*.md", "*.toml"], cwd=ROOT, capture_output=True, text=True,
                               check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):      # not a git checkout: the tree as it is
        files = [str(f.relative_to(ROOT)) for pattern in ("*.md", "*.toml") for f in ROOT.rglob(pattern)
                 if not any(part.startswith(".") or part in ("build", "out") for part in f.relative_to(ROOT).parts)]
    return [f for f in files if "[[[cog" in (ROOT / f).read_text(encoding="utf-8")]


def main(argv: list[str]) -> int:
    check = "--check" in argv
    args = ["cog", "-P", "-I", str(ROOT / "scripts" / "docs"), "-p", "import figures as F",
            "--markers=[[[cog ]]] [[[end]]]"]
    args += ["--check", "--diff", "--check-fail-msg=make docs rewrites them"] if check else ["-r"]
    status = Cog().main(args + [str(ROOT / f) for f in documents()])
    if check or status:
        return status
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "docs" / "screenshots.py")]).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
