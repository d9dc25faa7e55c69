"""The shape of the package, held where a reviewer would otherwise have to look: files that fit on a
few screens, and commands that are commands — a capability another module needs is a library
below the commands (servodyn.loop, servodyn.report, servodyn.sim, servodyn.hal), not a command
imported by another."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ("host", "hal", "sim", "tools")       # the folders of the servodyn package
MAX_LINES = 500


def python_files():
    for folder in PACKAGE:
        yield from sorted((ROOT / folder).rglob("*.py"))


def test_no_python_file_over_500_lines():
    long = {str(p.relative_to(ROOT)): n for p in python_files() if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"files over {MAX_LINES} lines (split them by job): {long}"


def _tools_imports(path: Path) -> set[str]:
    """The servodyn.tools modules a file in tools/ imports (relative imports resolved)."""
    parts = list(path.relative_to(ROOT / "tools").with_suffix("").parts)
    package = ["servodyn", "tools", *parts[:-1]] if parts[-1] != "__init__" else ["servodyn", "tools", *parts[:-1]]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            name = ".".join(base + ([node.module] if node.module else []))
            names = [name] if node.module else [f"{name}.{a.name}" for a in node.names]
            found.update(n for n in names if n.startswith("servodyn.tools."))
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("servodyn.tools."))
    return found


def test_commands_import_no_other_command():
    """Only the CLI's verb table reaches the commands; a command that is a package (the
    benchmarks, the bring-up family) uses its own modules."""
    offenders = {}
    for path in sorted((ROOT / "tools").rglob("*.py")):
        rel = path.relative_to(ROOT / "tools")
        if rel.parts[0] == "cli":
            continue
        own = f"servodyn.tools.{rel.parts[0]}" if len(rel.parts) > 1 else None
        wrong = sorted(m for m in _tools_imports(path) if not (own and (m == own or m.startswith(own + "."))))
        if wrong:
            offenders[str(rel)] = wrong
    assert not offenders, f"commands imported as libraries (move what they share below the tools): {offenders}"


def test_every_package_folder_is_installed():
    """pyproject.toml lists the packages an install copies: a folder with an __init__.py missing from
    that list works in the editable checkout and is absent from a wheel (servodyn.hal.feetech was)."""
    import tomllib
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {path: name for name, path in project["package-dir"].items()}
    found = set()
    for folder, name in folders.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            found.add(".".join([name, *init.parent.relative_to(ROOT / folder).parts]))
    missing = found - set(project["packages"])
    assert not missing, f"packages pyproject.toml does not install: {sorted(missing)}"
