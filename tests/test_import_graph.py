"""servodyn's Python modules import each other without a cycle, and at the top of each module:
an import placed inside a function hides a dependency (and, so placed, a cycle) from every reader
and from import-linter. The layers themselves are import-linter's contracts (pyproject.toml)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = {"host": "servodyn", "hal": "servodyn.hal", "sim": "servodyn.sim", "tools": "servodyn.tools"}
# none: a command's module is loaded when that command runs because the CLI finds its verb by
# name (servodyn.tools.cli.VERBS, importlib), so `servodyn --help` loads no application
LAZY_ALLOWED: set[str] = set()


def modules() -> dict[str, Path]:
    found = {}
    for folder, package in PACKAGES.items():
        for path in (ROOT / folder).rglob("*.py"):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((package, *parts))] = path
    return found


def extensions() -> set[str]:
    """The C extensions setup.py builds (servodyn._core, ...): modules that import nothing of ours."""
    text = (ROOT / "setup.py").read_text()
    return set(re.findall(r'Extension\("([\w.]+)"', text)) | {f"servodyn.{n}" for n in re.findall(r'core_module\("(\w+)"', text)}


def _type_checking(node) -> bool:
    test = getattr(node, "test", None)
    return isinstance(test, ast.Name) and test.id == "TYPE_CHECKING" or \
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"


def imports(name: str, path: Path, known: set[str]):
    """(imported servodyn module, line, inside a function?) of every import the module runs."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                continue                      # for annotations only: never run
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                for alias in child.names:
                    if alias.name.startswith("servodyn"):
                        yield alias.name, child.lineno, inside
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.rsplit(".", child.level - 1)[0] if child.level > 1 else package
                    target = f"{base}.{child.module}" if child.module else base
                else:
                    target = child.module or ""
                if not target.startswith("servodyn"):
                    continue
                for alias in child.names:
                    sub = f"{target}.{alias.name}"
                    yield (sub if sub in known else target), child.lineno, inside
            yield from visit(child, inside)
    yield from visit(tree, False)


def graph():
    found = modules()
    known = set(found) | extensions()
    edges, lazy = {}, []
    for name, path in found.items():
        edges[name] = set()
        for target, line, inside in imports(name, path, known):
            if target in known and target != name:
                edges[name].add(target)
            if inside and name not in LAZY_ALLOWED:
                lazy.append(f"{path.relative_to(ROOT)}:{line} imports {target} inside a function")
    return edges, lazy


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), and self-loops."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))
    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


def test_no_import_cycles_among_servodyn_modules():
    edges, _ = graph()
    assert len(edges) > 60, f"the walk found servodyn's modules ({len(edges)})"
    assert {"servodyn._core", "servodyn.hal.dynamixel._dxl"} <= extensions(), extensions()
    assert sum(map(len, edges.values())) > 150, "and their imports"
    found = cycles(edges)
    assert not found, "modules that import each other in a loop: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_cycle_finder_finds_a_cycle():
    """The check can fail: a loop of three, and one hidden in a function, are found."""
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    source = "def f():\n    from servodyn.hal import bus\n"
    hidden = ROOT / "build" / "import_graph_probe.py"
    hidden.parent.mkdir(exist_ok=True)
    hidden.write_text(source)
    assert list(imports("servodyn.probe", hidden, {"servodyn.hal.bus"})) == [("servodyn.hal.bus", 2, True)]


def test_no_servodyn_import_inside_a_function():
    _, lazy = graph()
    assert not lazy, "imports placed inside functions (move them to the top of the module):\n" + "\n".join(lazy)


def test_the_command_line_loads_no_heavy_library_before_a_command_runs():
    """`servodyn --help`, and every command's start, pays only for what the dispatcher needs: a
    heavy library imported at the top of a module the parser reaches (scipy.optimize alone is half
    a second) slowed every command's start, `servodyn doctor` among them, from 0.4 s to 1.0 s."""
    import subprocess
    import sys
    heavy = ("scipy", "matplotlib", "pinocchio", "toppra", "viser", "rich", "can", "dynamixel_sdk")
    probe = ("import sys, servodyn.tools.cli; "
             f"print(' '.join(m for m in {heavy!r} if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split()
    assert loaded == [], f"loaded before any command runs: {loaded}"
