#!/usr/bin/env python3
"""stackpath.py: the worst stack path of a firmware image, from GCC's call-graph files.

Build every object with `-fstack-usage -fcallgraph-info=su` (GCC >= 10): next to each object
GCC writes a .ci file (VCG graph) whose nodes are the functions of that unit with their frame
("N bytes (static)") and whose edges are the calls left after inlining, to functions of other
units too (listed there as nodes without a frame) and to `__indirect_call` for a call through a
pointer. This tool reads every .ci under DIR, merges the nodes by name (GCC itself names a
static function `unit.c:name`, so two statics of the same name stay apart) and, for each entry,
finds the call chain of the largest sum of frames.

    scripts/stackpath.py [--entry NAME ...] [--isr NAME ...] [--limit BYTES]
                         [--assume NAME=BYTES ...] [--indirect CALLER=CALLEE[,CALLEE...] ...]
                         [--exception-frame BYTES] DIR

Entries: by default `main`, the reset handler and every interrupt handler found, either in the
vector table of an object next to a .ci (relocations of a section named .vectors, .isr_vector,
...: slot 1 is the reset handler, slots 2 and up are exception handlers) or by name (*_Handler,
*_IRQHandler, *_isr, isr_*). --entry and --isr replace that list (--isr names an interrupt
handler the detection misses; a static function may be named `name` when unique, or
`unit.c:name`).

Output: one line per entry, then what its reach holds that is not counted, e.g. for the core
and firmware/mcu built with the flags of firmware/mcu/rules.mk:
    stack: worst path from main 1352 B: main (472) > sd_step (112) > sd_forward (280) > ag.c:inbound_body (488)
      unknown frames (counted 0 B; set with --assume NAME=BYTES): cosf, memcpy, memset, sinf
    stack: worst path from startup.c:mcu_fault 16 B (ISR, +104 B exception entry = 120 B): ...
then the overall worst, then, when there are interrupt handlers and a thread entry (main, the
reset handler), the total with the deepest handler on top of the thread's worst path: an
exception entry stacks 8 core registers (32 B) or, with an FP context, also S0-S15 and FPSCR
(104 B; lazy stacking reserves that room even when it defers the store). --exception-frame
sets it (default 104, the Cortex-M4F case; 32 for a core without FPU use). When the stack
pointer is not 8-byte aligned at the exception, the core also pads 4 B; handlers of different
priorities can preempt each other, which the single-level figure does not cover.

Not counted, and listed as "unknown frames" (0 B unless --assume NAME=BYTES): functions with no
.ci node (libgcc, libm's sinf, memset, ...) and calls through pointers (`__indirect_call`;
--assume __indirect_call=BYTES sets them all, --indirect CALLER=A,B names the possible targets of
CALLER's pointer calls). Frames GCC marks "dynamic" (a VLA, alloca) have no bound: the figure
counts their fixed part and says so; "dynamic,bounded" frames are counted at their bound.

Exit status: 0; 1 with a line "stackpath: FAIL: ..." on recursion reachable from an entry or a
worst figure above --limit; 2 on bad usage (no .ci file, an entry that is not in the graph).
"""

from __future__ import annotations

import argparse
import os
import re
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path

INDIRECT = "__indirect_call"
DEFAULT_EXCEPTION_FRAME = 104
ISR_NAME = re.compile(r"(IRQHandler|_Handler|_isr|_ISR)$|^isr_")
VECTOR_SECTION = re.compile(r"^\.(isr_vectors?|vectors?|vector_table|intvecs?|interrupt_vector)(\..*)?$")

_GRAPH = re.compile(r'\bgraph\s*:\s*\{\s*title\s*:\s*"((?:[^"\\]|\\.)*)"')
_BLOCK = re.compile(r'\b(node|edge)\s*:\s*\{((?:[^"{}]|"(?:[^"\\]|\\.)*")*)')
_ATTR = re.compile(r'(\w+)\s*:\s*"((?:[^"\\]|\\.)*)"')
_USAGE = re.compile(r"(\d+) bytes \(([^)]*)\)")


class StackPathError(Exception):
    """Bad input (exit status 2)."""


@dataclass
class Function:
    title: str                          # GCC's node title: `name`, or `unit.c:name` when static
    name: str                           # the first line of the label
    where: str                          # file:line:column of the definition
    frame: int
    usage: str                          # "static", "dynamic" or "dynamic,bounded"
    ci: str                             # the .ci file that defines it
    callees: list[str] = field(default_factory=list)
    indirect: bool = False              # calls through a pointer

    @property
    def unbounded(self) -> bool:
        return "dynamic" in self.usage and "bounded" not in self.usage


@dataclass
class Graph:
    functions: dict[str, Function] = field(default_factory=dict)
    declared: dict[str, str] = field(default_factory=dict)   # nodes without a frame: title -> label
    resets: list[str] = field(default_factory=list)          # from vector tables
    handlers: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    files: int = 0


def _unescape(text: str) -> str:
    return text.replace("\\n", "\n").replace('\\"', '"').replace("\\\\", "\\")


def parse_ci(text: str, ci: str = "") -> tuple[str, list[Function], dict[str, str], list[tuple[str, str]]]:
    """One .ci file: (unit title, functions with a frame, other nodes, edges)."""
    graph = _GRAPH.search(text)
    unit, functions, declared, edges = _unescape(graph.group(1)) if graph else "", [], {}, []
    for kind, body in _BLOCK.findall(text):
        attrs = {k: _unescape(v) for k, v in _ATTR.findall(body)}
        if kind == "node":
            title, label = attrs.get("title", ""), attrs.get("label", "")
            lines = label.split("\n")
            usage = _USAGE.search(label)
            if usage:
                functions.append(Function(title, lines[0], lines[1] if len(lines) > 1 else "",
                                          int(usage.group(1)), usage.group(2), ci))
            else:
                declared[title] = label
        elif attrs.get("sourcename") and attrs.get("targetname"):
            edges.append((attrs["sourcename"], attrs["targetname"]))
    return unit, functions, declared, edges


# ------------------------------------------------------------------------------------------------
# vector tables: the relocations of a .vectors section in the object next to a .ci

def _elf_vector_slots(path: Path) -> list[tuple[int, str, bool]]:
    """(slot, symbol, is_local) of each function a vector-table section of the ELF object points
    to; [] when the file is not a readable ELF relocatable object."""
    try:
        data = path.read_bytes()
    except OSError:
        return []
    if len(data) < 52 or data[:4] != b"\x7fELF":
        return []
    wide, order = data[4] == 2, "<" if data[5] == 1 else ">"
    try:
        if wide:
            shoff, = struct.unpack_from(order + "Q", data, 0x28)
            shentsize, shnum, shstrndx = struct.unpack_from(order + "HHH", data, 0x3A)
        else:
            shoff, = struct.unpack_from(order + "I", data, 0x20)
            shentsize, shnum, shstrndx = struct.unpack_from(order + "HHH", data, 0x2E)
        sections = []
        for i in range(shnum):
            at = shoff + i * shentsize
            if wide:
                name, kind, _, _, offset, size, link, info, _, entsize = struct.unpack_from(
                    order + "IIQQQQIIQQ", data, at)
            else:
                name, kind, _, _, offset, size, link, info, _, entsize = struct.unpack_from(
                    order + "IIIIIIIIII", data, at)
            sections.append((name, kind, offset, size, link, info, entsize))

        def cstr(table: int, index: int) -> str:
            start = sections[table][2] + index
            return data[start:data.index(b"\0", start)].decode("utf-8", "replace")

        names = [cstr(shstrndx, s[0]) for s in sections]
        symtab = next((i for i, s in enumerate(sections) if s[1] == 2), None)   # SHT_SYMTAB
        if symtab is None:
            return []
        _, _, sym_off, sym_size, strtab, _, sym_ent = sections[symtab]
        symbols = []   # (name, bind, type, shndx, value)
        for at in range(sym_off, sym_off + sym_size, sym_ent):
            if wide:
                st_name, st_info, _, shndx, value, _ = struct.unpack_from(order + "IBBHQQ", data, at)
            else:
                st_name, value, _, st_info, _, shndx = struct.unpack_from(order + "IIIBBH", data, at)
            symbols.append((cstr(strtab, st_name), st_info >> 4, st_info & 0xF, shndx, value))

        slots = []
        for name, kind, offset, size, link, info, entsize in sections:
            if kind not in (4, 9) or not VECTOR_SECTION.match(names[info]):   # SHT_RELA, SHT_REL
                continue
            target = sections[info]
            for at in range(offset, offset + size, entsize):
                if wide:
                    r_offset, r_info = struct.unpack_from(order + "QQ", data, at)
                    sym, addend = r_info >> 32, (struct.unpack_from(order + "q", data, at + 16)[0]
                                                 if kind == 4 else None)
                else:
                    r_offset, r_info = struct.unpack_from(order + "II", data, at)
                    sym, addend = r_info >> 8, (struct.unpack_from(order + "i", data, at + 8)[0]
                                                if kind == 4 else None)
                if addend is None and target[1] != 8:   # REL: the addend is in the section
                    addend, = struct.unpack_from(order + ("q" if wide else "i"), data,
                                                 target[2] + r_offset)
                sname, bind, stype, shndx, value = symbols[sym]
                if stype == 3:   # STT_SECTION: the function at that offset of the section
                    match = [s for s in symbols if s[2] == 2 and s[3] == shndx
                             and s[4] & ~1 == (addend or 0) & ~1]
                    if not match:
                        continue
                    sname, bind, stype, shndx, value = match[0]
                if stype == 3 or not sname:
                    continue
                slots.append((r_offset // (8 if wide else 4), sname, bind == 0))
        return slots
    except (struct.error, IndexError, ValueError):
        return []


# ------------------------------------------------------------------------------------------------
# the graph

def load(directory: str | os.PathLike) -> Graph:
    """Every .ci under directory, merged into one graph."""
    paths = sorted(Path(directory).rglob("*.ci"))
    if not paths:
        raise StackPathError(f"no .ci file under {directory} (build with -fstack-usage "
                             "-fcallgraph-info=su, GCC >= 10)")
    graph = Graph(files=len(paths))
    edges: list[tuple[str, str]] = []
    units: dict[str, str] = {}
    for path in paths:
        unit, functions, declared, file_edges = parse_ci(path.read_text(errors="replace"), str(path))
        units[str(path)] = unit
        for fn in functions:
            old = graph.functions.get(fn.title)
            if old is not None:
                graph.warnings.append(f"{fn.title} defined in {old.ci} and {fn.ci}: "
                                      "counting the larger frame")
                if old.frame >= fn.frame:
                    continue
            graph.functions[fn.title] = fn
        for title, label in declared.items():
            graph.declared.setdefault(title, label)
        edges += file_edges
    for source, target in edges:
        fn = graph.functions.get(source)
        if fn is None:
            continue
        if target == INDIRECT:
            fn.indirect = True
        elif target not in fn.callees:
            fn.callees.append(target)
    # vector tables of the objects next to the .ci files
    for path in paths:
        for slot, symbol, local in _elf_vector_slots(path.with_suffix(".o")):
            title = f"{units[str(path)]}:{symbol}" if local else symbol
            if title not in graph.functions or slot < 1:
                continue
            bucket = graph.resets if slot == 1 else graph.handlers
            if title not in bucket:
                bucket.append(title)
    return graph


def display(title: str) -> str:
    """`firmware/core/ag.c:inbound_body` -> `ag.c:inbound_body`."""
    unit, sep, name = title.rpartition(":")
    return f"{os.path.basename(unit)}:{name}" if sep and unit and not unit.endswith(":") else title


def resolve(graph: Graph, name: str) -> str:
    """The title of a function given by title, display name, or bare name of a unique static."""
    if name in graph.functions:
        return name
    hits = [t for t in graph.functions if display(t) == name or t.rpartition(":")[2] == name]
    if len(hits) == 1:
        return hits[0]
    if hits:
        raise StackPathError(f"{name} is ambiguous: {', '.join(sorted(hits))}")
    if name in graph.declared:
        raise StackPathError(f"{name} is called but defined in no .ci file under the directory")
    raise StackPathError(f"no function {name} in the .ci files")


def default_entries(graph: Graph) -> tuple[list[str], set[str]]:
    """main, the reset handlers and the interrupt handlers found; the latter as a set."""
    isrs = list(graph.handlers)
    isrs += sorted(t for t in graph.functions
                   if ISR_NAME.search(t.rpartition(":")[2]) and t not in isrs)
    threads = [t for t in graph.resets if t not in isrs]
    if "main" in graph.functions and "main" not in threads:
        threads.insert(0, "main")
    return threads + isrs, set(isrs)


@dataclass
class Worst:
    entry: str
    total: int | None                   # None: recursion
    frames: list[tuple[str, int, str]]  # (title, bytes, note) along the worst path
    unknown: list[str]                  # unknown frames reachable from the entry
    dynamic: list[str]                  # dynamic frames reachable from the entry
    cycle: list[str] | None = None


class Analysis:
    def __init__(self, graph: Graph, assume: dict[str, int] | None = None,
                 indirect: dict[str, list[str]] | None = None):
        self.graph = graph
        self.assume = dict(assume or {})
        self.indirect = {resolve(graph, caller): [self._target(t) for t in targets]
                         for caller, targets in (indirect or {}).items()}
        self._memo: dict[str, tuple[int, str | None]] = {}

    def _target(self, name: str) -> str:
        try:
            return resolve(self.graph, name)
        except StackPathError:
            if name in self.graph.declared:   # a library function: an unknown frame
                return name
            raise

    def callees(self, title: str) -> list[str]:
        """Calls of a function; an unresolved pointer call is `__indirect_call@caller`."""
        fn = self.graph.functions[title]
        out = list(fn.callees)
        if fn.indirect:
            if title in self.indirect:
                out += [t for t in self.indirect[title] if t not in out]
            else:
                out.append(f"{INDIRECT}@{title}")
        return out

    def leaf(self, callee: str) -> int:
        """Assumed bytes of a callee with no frame."""
        name = callee.partition("@")[0]
        return self.assume.get(callee, self.assume.get(name, 0))

    def find_cycle(self, entry: str) -> list[str] | None:
        """A call cycle reachable from entry, as a closed list of titles, or None."""
        state: dict[str, int] = {}
        stack: list[str] = []

        def visit(title: str) -> list[str] | None:
            state[title] = 1
            stack.append(title)
            for callee in self.callees(title):
                if callee not in self.graph.functions:
                    continue
                if state.get(callee) == 1:
                    return stack[stack.index(callee):] + [callee]
                if callee not in state:
                    found = visit(callee)
                    if found:
                        return found
            state[title] = 2
            stack.pop()
            return None

        limit = sys.getrecursionlimit()
        sys.setrecursionlimit(max(limit, 4 * len(self.graph.functions) + 1000))
        try:
            return visit(entry)
        finally:
            sys.setrecursionlimit(limit)

    def worst(self, title: str) -> int:
        """Largest sum of frames from title down (the graph below it has no cycle)."""
        if title not in self.graph.functions:
            return self.leaf(title)
        if title in self._memo:
            return self._memo[title][0]
        best, via = 0, None
        for callee in self.callees(title):
            depth = self.worst(callee)
            if depth > best:
                best, via = depth, callee
        total = self.graph.functions[title].frame + best
        self._memo[title] = (total, via if best > 0 else None)
        return total

    def reachable(self, entry: str) -> list[str]:
        seen, todo = {entry}, [entry]
        while todo:
            title = todo.pop()
            if title in self.graph.functions:
                for callee in self.callees(title):
                    if callee not in seen:
                        seen.add(callee)
                        todo.append(callee)
        return sorted(seen)

    def path(self, entry: str) -> Worst:
        reach = self.reachable(entry)
        unknown = [t for t in reach if t not in self.graph.functions]
        dynamic = [t for t in reach
                   if t in self.graph.functions and "dynamic" in self.graph.functions[t].usage]
        cycle = self.find_cycle(entry)
        if cycle:
            return Worst(entry, None, [], unknown, dynamic, cycle)
        limit = sys.getrecursionlimit()
        sys.setrecursionlimit(max(limit, 4 * len(self.graph.functions) + 1000))
        try:
            total = self.worst(entry)
        finally:
            sys.setrecursionlimit(limit)
        frames, title = [], entry
        while title is not None:
            if title in self.graph.functions:
                fn = self.graph.functions[title]
                note = "dynamic" if fn.unbounded else "bounded" if "bounded" in fn.usage else ""
                frames.append((title, fn.frame, note))
                title = self._memo[title][1]
            else:
                frames.append((title, self.leaf(title), "assumed"))
                title = None
        return Worst(entry, total, frames, unknown, dynamic)


def unknown_name(title: str) -> str:
    if title.startswith(INDIRECT + "@"):
        return f"indirect call in {display(title.partition('@')[2])}"
    return display(title)


def format_path(p: Worst) -> str:
    parts = []
    for title, size, note in p.frames:
        name = unknown_name(title) if title.startswith(INDIRECT + "@") else display(title)
        parts.append(f"{name} ({size}{', ' + note if note else ''})")
    return " > ".join(parts)


def run(argv: list[str] | None = None, out=None) -> int:
    """The command line; returns the exit status. Prints to out (default sys.stdout)."""
    ap = argparse.ArgumentParser(prog="stackpath", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("directory", metavar="DIR", help="where the .ci files are (searched recursively)")
    ap.add_argument("--entry", action="append", default=[], metavar="NAME",
                    help="an entry point (repeatable); default: main, reset and interrupt handlers")
    ap.add_argument("--isr", action="append", default=[], metavar="NAME",
                    help="an entry that is an interrupt handler (repeatable)")
    ap.add_argument("--limit", type=int, metavar="BYTES",
                    help="fail when the worst figure (with the deepest handler) exceeds BYTES")
    ap.add_argument("--assume", action="append", default=[], metavar="NAME=BYTES",
                    help="stack of a function with no .ci node (__indirect_call: pointer calls)")
    ap.add_argument("--indirect", action="append", default=[], metavar="CALLER=CALLEE[,CALLEE]",
                    help="the possible targets of CALLER's calls through pointers")
    ap.add_argument("--exception-frame", type=int, default=DEFAULT_EXCEPTION_FRAME, metavar="BYTES",
                    help="bytes an exception entry stacks: 104 with FP context (default), 32 without")
    args = ap.parse_args(argv)

    def say(line: str) -> None:
        print(line, file=out or sys.stdout)

    try:
        assume = {}
        for item in args.assume:
            name, sep, value = item.partition("=")
            if not sep or not value.strip().isdigit():
                raise StackPathError(f"--assume {item}: expected NAME=BYTES")
            assume[name.strip()] = int(value)
        indirect: dict[str, list[str]] = {}
        for item in args.indirect:
            caller, sep, targets = item.partition("=")
            if not sep or not targets:
                raise StackPathError(f"--indirect {item}: expected CALLER=CALLEE[,CALLEE...]")
            indirect.setdefault(caller.strip(), []).extend(t.strip() for t in targets.split(","))

        graph = load(args.directory)
        for warning in graph.warnings:
            say(f"stackpath: warning: {warning}")
        entries, isrs = default_entries(graph)
        if args.entry or args.isr:
            entries = [resolve(graph, e) for e in args.entry]
            isrs = {resolve(graph, e) for e in args.isr}
            isrs |= {e for e in entries if e in default_entries(graph)[1]}
            entries += [e for e in sorted(isrs) if e not in entries]
        if not entries:
            raise StackPathError("no main and no interrupt handler found: name entries with --entry")
        # resolve assumptions given by display name to titles
        for name in list(assume):
            if name not in graph.functions and name != INDIRECT and name not in graph.declared:
                try:
                    assume[resolve(graph, name)] = assume.pop(name)
                except StackPathError:
                    pass
        analysis = Analysis(graph, assume, indirect)
        paths = [analysis.path(e) for e in dict.fromkeys(entries)]
    except StackPathError as error:
        print(f"stackpath: error: {error}", file=sys.stderr)
        return 2

    failures = []
    frame = args.exception_frame
    for p in paths:
        kind = " (ISR)" if p.entry in isrs else ""
        if p.total is None:
            cycle = " > ".join(display(t) for t in p.cycle)
            say(f"stack: worst path from {display(p.entry)}{kind}: unbounded, recursion: {cycle}")
            failures.append(f"recursion: {cycle} (reached from {display(p.entry)})")
            continue
        extra = f" (ISR, +{frame} B exception entry = {p.total + frame} B)" if kind else ""
        say(f"stack: worst path from {display(p.entry)} {p.total} B{extra}: {format_path(p)}")
        if p.unknown:
            names = ", ".join(f"{unknown_name(t)} ({analysis.leaf(t)} B assumed)"
                              if analysis.leaf(t) else unknown_name(t) for t in p.unknown)
            say(f"  unknown frames (counted 0 B; set with --assume NAME=BYTES): {names}")
        if p.dynamic:
            say("  dynamic frames: " + ", ".join(
                f"{display(t)} (unbounded: only its fixed part counted)"
                if graph.functions[t].unbounded else f"{display(t)} (bounded: counted at its bound)"
                for t in p.dynamic))
    if failures:
        for failure in dict.fromkeys(failures):
            say(f"stackpath: FAIL: {failure}")
        return 1

    worst = max(paths, key=lambda p: (p.total + (frame if p.entry in isrs else 0), p.entry))
    worst_total = worst.total + (frame if worst.entry in isrs else 0)
    say(f"stack: overall worst: {display(worst.entry)} {worst_total} B"
        + (f" (with the {frame} B exception entry)" if worst.entry in isrs else ""))
    figure, what = worst_total, f"worst path from {display(worst.entry)}"
    threads = [p for p in paths if p.entry not in isrs]
    handlers = [p for p in paths if p.entry in isrs]
    if threads and handlers:
        base = max(threads, key=lambda p: (p.total, p.entry))
        deep = max(handlers, key=lambda p: (p.total, p.entry))
        nested = base.total + frame + deep.total
        say(f"stack: {display(base.entry)} + deepest ISR {nested} B: {display(base.entry)} "
            f"{base.total} B + {frame} B exception entry ("
            + ("8 registers and the FP context, reserved by lazy stacking; 32 B without FP"
               if frame == 104 else "as --exception-frame")
            + f") + {display(deep.entry)} {deep.total} B")
        if nested > figure:
            figure, what = nested, f"{display(base.entry)} + deepest ISR"
    if args.limit is not None:
        if figure > args.limit:
            say(f"stackpath: FAIL: {what} needs {figure} B, over the limit of {args.limit} B")
            return 1
        say(f"stackpath: ok: {what} needs {figure} B, within the limit of {args.limit} B")
    return 0


def main() -> None:
    try:
        status = run()
        sys.stdout.flush()
    except BrokenPipeError:   # `stackpath.py DIR | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        status = 1
    sys.exit(status)


if __name__ == "__main__":
    main()
