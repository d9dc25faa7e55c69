"""Every repository file a comment, a docstring or a Markdown document names exists: a path that
starts with one of the repository's top-level folders (firmware/ hal/ host/ sim/ tools/ tests/
scripts/ fuzz/ docs/) and ends in a file name with an extension. Paths under build/ and out/ are
found too and allowed by name (GENERATED: what make and the commands write). Files move; the prose
that named them is the part nobody re-runs, so this test does."""

from __future__ import annotations

import ast
import io
import re
import subprocess
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("firmware", "hal", "host", "sim", "tools", "tests", "scripts", "fuzz", "docs")
# named on purpose though never in the tree: what the build and the commands write, with the reason
GENERATED = {
    "build/": "make's outputs (the firmware's images and generated C, the extension, the layer copy)",
    "out/": "the commands' default output folder (run logs, figures, reports)",
}
# the kinds of file the repository holds (so that `tools/config_patch.ask`, a function, is no file)
EXTENSIONS = ("py", "pyi", "c", "h", "md", "toml", "mk", "sh", "json", "csv", "txt", "urdf", "bvh", "png",
              "svg", "html", "ld", "yml", "yaml", "cfg", "ini", "stl", "obj", "xml", "log", "elf", "pdf")
# a path: a top-level folder, then name/…/name.ext; not inside a longer path or a module name
_TOPS = "|".join(FOLDERS + tuple(g.rstrip("/") for g in GENERATED))
PATH = re.compile(r"(?<![\w./~$-])((?:" + _TOPS + r")/[\w./-]*\.(?:" + "|".join(EXTENSIONS) + r"))(?![\w-])")
# a placeholder, a glob or a pattern, not one file
PATTERN = re.compile(r"[*?{}<>\[\]]|\bX\b|\.\.\.")


def _tracked() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [ROOT / p for p in out.decode().split("\0") if p]


def _python_prose(text: str) -> str:
    """The comments and docstrings of a Python source."""
    parts = []
    try:
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type == tokenize.COMMENT:
                parts.append(tok.string)
    except (tokenize.TokenError, SyntaxError):
        return text
    try:
        tree = ast.parse(text)
    except SyntaxError:
        return text
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                parts.append(doc)
    return "\n".join(parts)


def _c_prose(text: str) -> str:
    """The comments of a C source or header."""
    return "\n".join(m.group(0) for m in re.finditer(r"//[^\n]*|/\*.*?\*/", text, flags=re.S))


def _hash_prose(text: str) -> str:
    """The comments of a TOML, make or shell file (from '#' to the line's end)."""
    return "\n".join(m.group(1) for m in re.finditer(r"(?:^|\s)#([^\n]*)", text))


def prose(path: Path) -> str:
    text = path.read_text(errors="replace")
    if not PATH.search(text):
        return ""                      # names no path at all: no need to tokenize it
    suffix = path.suffix
    if suffix == ".py":
        return _python_prose(text)
    if suffix in (".c", ".h"):
        return _c_prose(text)
    if suffix == ".md":
        return text
    if suffix in (".toml", ".mk", ".sh", ".cfg", ".ini", ".yml", ".yaml") or path.name == "Makefile":
        return _hash_prose(text)
    return ""


def named_paths(text: str) -> set[str]:
    found = set()
    for match in PATH.finditer(text):
        name = match.group(1).rstrip(".")
        if not PATTERN.search(text[match.start():match.end() + 1]):
            found.add(name)
    return found


def test_every_file_named_in_prose_exists():
    tracked = _tracked()
    files = {p.relative_to(ROOT).as_posix() for p in tracked}
    folders = {f.rsplit("/", i)[0] for f in files for i in range(1, f.count("/") + 1)}
    missing = []
    for path in tracked:
        if path.is_relative_to(ROOT / "fuzz") and path.suffix not in (".py", ".c", ".h", ".md"):
            continue                   # the fuzzers' corpora are data
        for name in sorted(named_paths(prose(path))):
            if name in files or name in folders:
                continue
            if any(name.startswith(prefix) for prefix in GENERATED):
                continue
            missing.append(f"{path.relative_to(ROOT)}: {name}")
    assert missing == [], f"{len(missing)} named files do not exist:\n" + "\n".join(missing)


def test_the_scan_sees_comments_docstrings_and_markdown():
    """The scan itself, on a known sample: paths in comments, docstrings and prose are found, the
    same text in code, in a glob or in a longer path is not."""
    source = '"""Reads host/model/tree.py."""\nx = "hal/config.py"  # see sim/plant.py\n'
    assert named_paths(_python_prose(source)) == {"host/model/tree.py", "sim/plant.py"}, \
        "the docstring's and the comment's, not the string literal's"
    assert named_paths(_c_prose("int a; // tools/codegen.py writes it\n/* hal/x.h */")) == \
        {"tools/codegen.py", "hal/x.h"}, "both C comment forms"
    assert named_paths("see hal/configs/*.toml, a/host/x.py and tools/config_patch.ask") == set(), \
        "a glob, a path inside another and a function are not named files"
    assert named_paths("make writes build/fw/gen/servodyn_gen.h") == {"build/fw/gen/servodyn_gen.h"}, \
        "a build output is found (and then allowed, as GENERATED says)"
    assert named_paths("ends a sentence: docs/method.md.") == {"docs/method.md"}, "a full stop is not part of it"
