"""The documents' figures: every figure the README and the folder READMEs quote from a command's
output is generated into the file by a cog block that runs the command (scripts/docs/figures.py).
Here the blocks run again and must give the documents' text as it is: a change that moves a figure
fails until `make docs` has rewritten the document (and the change is reviewed with it).

One cog process runs every block, so each command behind them runs once (about a minute: five
lock-step swings, the experiments, a dozen validator runs). Timings are not generated (they vary);
the documents mark them as measured on this machine, with a date."""

import contextlib
import io
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts" / "docs"))

import figures  # noqa: E402

pytestmark = pytest.mark.slow      # every figure the documents quote, from its command


@pytest.mark.timeout(900)          # about a minute and a half on a quiet machine; more under load
def test_documents_quote_what_the_commands_print():
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "docs" / "docs.py"), "--check"],
                          cwd=ROOT, capture_output=True, text=True, timeout=880)
    assert proc.returncode == 0, (
        "a document quotes figures the commands no longer print; `make docs` rewrites them "
        "(review the diff):\n" + proc.stdout[-20000:] + proc.stderr[-5000:])


def test_no_committed_document_reads_pending():
    """*pending* is for a branch whose command others are still fixing; what lands quotes real
    figures (a pending block regenerates as pending, so the check above would not catch it)."""
    files = subprocess.run(["git", "ls-files", "*.md", "*.toml"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    pending = [f for f in files if "*pending*" in (ROOT / f).read_text(encoding="utf-8")
               and not f.startswith("tests/")]
    assert pending == [], f"documents with figures still pending: {pending}"


def test_a_failing_command_leaves_its_figures_pending():
    """A command others are still fixing: its figures read *pending*, with the command and why;
    once it runs, `make docs` fills them in and the check above fails until it has."""
    def broken():
        raise figures.CommandFailed("servodyn validate replica_can tennis_forehand --simulate",
                                    "exit 1, AttributeError: ...")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        figures.fill("tracking max {tracking:.2f}°, fit {fit[scale]:.4f}", broken)
    text = out.getvalue()
    assert text.startswith("tracking max *pending*°, fit *pending*")
    assert "`servodyn validate replica_can tennis_forehand --simulate` fails today (exit 1, AttributeError" in text


def test_a_traceback_is_a_failed_command():
    with pytest.raises(figures.CommandFailed, match="no such configuration|error"):
        figures.run("validate", "no_such_configuration", "tennis_forehand")


def test_make_demo_is_read_from_the_makefile():
    recipe = figures.make_recipe("demo")
    assert recipe and all(line.startswith("servodyn") for line in recipe), recipe


def test_timings_are_masked():
    assert figures.mask_timings("2001 samples in 0.41 ms = 0.21 us per sample") == \
        "2001 samples in … ms = … us per sample"
    assert figures.mask_timings("passes the dense check (1 plan, 0.03 s); as written") == \
        "passes the dense check (1 plan, … s); as written"


DOCS = sorted((ROOT / "docs").glob("*.md"))
LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")


def test_the_docs_pages_are_documents_the_check_runs_on():
    """docs/*.md hold cog blocks moved from the README: each such page is among the documents
    `make docs` rewrites and the first test checks (tracked by git, so committed with its page)."""
    sys.path.insert(0, str(ROOT / "scripts" / "docs"))
    import docs
    checked = set(docs.documents())
    with_blocks = [p.relative_to(ROOT).as_posix() for p in DOCS if "[[[cog" in p.read_text(encoding="utf-8")]
    assert len(with_blocks) >= 4, with_blocks          # the swing, validate, method and motions pages
    assert [p for p in with_blocks if p not in checked] == []


def test_the_readme_is_short_and_lists_every_page():
    """The README starts with the person who has an arm (install, a tour, the bring-up) in under
    300 lines; the depth is in docs/, every page linked from its contents."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) < 300, len(readme.splitlines())
    linked = set(LINK.findall(readme))
    assert [p.name for p in DOCS if f"docs/{p.name}" not in linked] == []


def test_every_relative_link_in_the_documents_exists():
    broken = []
    for page in [ROOT / "README.md", ROOT / "hal" / "README.md", *DOCS]:
        for target in LINK.findall(page.read_text(encoding="utf-8")):
            if not re.match(r"[a-z]+:", target) and not (page.parent / target).exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert broken == []
