"""One error tree: every exception class servodyn defines is a ServodynError (with its exit
status), so the CLI's one handler turns each into one line and its status, and anything else
(a bug) is a traceback; the CLI itself catches no bare ValueError."""

from __future__ import annotations

import ast
import importlib
import inspect
import tomllib
from pathlib import Path

from servodyn.errors import ExitCode, ServodynError

ROOT = Path(__file__).resolve().parent.parent


def package_modules() -> list[str]:
    """Every module of the package, by the folders pyproject.toml maps it from (`__main__` left out:
    importing it runs the command)."""
    folders = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    names = []
    for package, folder in folders.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            if parts[-1] == "__main__":
                continue
            parts = parts[:-1] if parts[-1] == "__init__" else parts
            name = ".".join((package, *parts))
            if not any(name.startswith(f"{other}.") or name == other for other in folders
                       if other != package and other.startswith(f"{package}.")):
                names.append(name)
    return names


def test_every_exception_class_is_a_servodyn_error():
    modules = package_modules()
    assert len(modules) > 100, f"the walk found the package's modules ({len(modules)})"
    classes = {}
    for name in modules:
        module = importlib.import_module(name)
        for cls in vars(module).values():
            if inspect.isclass(cls) and issubclass(cls, BaseException) and cls.__module__ == name:
                classes[f"{name}.{cls.__qualname__}"] = cls
    assert len(classes) >= 40, f"the exception classes found ({len(classes)}): {sorted(classes)}"
    outside = sorted(name for name, cls in classes.items() if not issubclass(cls, ServodynError))
    assert outside == [], f"exception classes outside ServodynError: {outside}"
    codes = {name: cls.exit_code for name, cls in classes.items()}
    assert all(isinstance(code, int) and 0 <= code < 256 for code in codes.values()), codes
    from servodyn.model import ModelError, ik
    assert ik.OutOfReach.exit_code == 1 and ModelError.exit_code == ExitCode.BAD_INPUT, \
        "a refused target exits 1 (servodyn ik's contract), a model that cannot be built 2"


def test_the_cli_catches_no_bare_value_error():
    """`except ValueError` in the CLI turned an internal bug into one line of "bad input". The
    argument types (argtypes.py) are the exception: each wraps one int() or float() of the text
    typed, the one place a ValueError is the user's."""
    caught = []
    for path in sorted((ROOT / "tools" / "cli").glob("*.py")):
        if path.name == "argtypes.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ExceptHandler) and node.type is not None:
                names = {n.id for n in ast.walk(node.type) if isinstance(n, ast.Name)}
                if names & {"ValueError", "Exception", "BaseException", "RuntimeError"}:
                    caught.append(f"{path.name}:{node.lineno}")
    assert len(list((ROOT / "tools" / "cli").glob("*.py"))) >= 10, "the walk found the verbs' modules"
    assert caught == [], f"broad excepts in the CLI: {caught}"
