"""scripts/stackpath.py: the worst stack path from GCC's -fcallgraph-info files.

A small program is cross-compiled with arm-none-eabi-gcc at -O0 (no inlining, so every function
keeps its own frame) with -fstack-usage -fcallgraph-info=su; the tool's figures are checked
against the frames of GCC's own .su files. `make test` installs the toolchain before the Python
tests, so a missing compiler is a failure here, not a skip.
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "scripts" / "stackpath.py"
CC = "arm-none-eabi-gcc"
ARCH = ["-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-mthumb"]

# two units; each has a static `helper` of a different size, so merging by bare name would
# be wrong. main > work > filter > dsp.c:helper is the deepest chain; dispatch calls through a
# pointer; wave calls libm's sinf (no .ci node); vla has a frame of unbounded size; fault is a
# static handler found only through the vector table; SysTick_Handler is found by its name.
APP_C = r"""
#include <math.h>
typedef int (*op_t)(int);
int filter(int x);
int main(void);
extern unsigned stack_top[];

static int helper(int x) { volatile int buf[16]; buf[0] = x; return buf[0] * 2; }
int work(int x) { volatile char buf[100]; buf[0] = (char)x; return filter(x) + helper(buf[0]); }
op_t hook = filter;
int dispatch(int x) { volatile char buf[8]; buf[0] = (char)x; return hook(buf[0]); }
float wave(float t) { volatile float buf[4]; buf[0] = t; return sinf(buf[0]); }
int vla(int n) { volatile char buf[n]; buf[0] = 1; return buf[0]; }
void SysTick_Handler(void) { volatile char buf[32]; buf[0] = (char)dispatch(1); }
static void fault(void) { volatile char buf[200]; buf[0] = 1; for (;;) {} }
void reset_handler(void) { main(); for (;;) {} }
int main(void) { return work(1) + dispatch(2) + (int)wave(1.0f) + vla(3); }

__attribute__((section(".vectors"), used))
static void (*const vectors[16])(void) = {
  (void (*)(void))stack_top, reset_handler, fault, fault, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
  SysTick_Handler,
};
"""
DSP_C = r"""
static int helper(int x) { volatile int taps[64]; taps[0] = x; return taps[0]; }
int filter(int x) { volatile int acc[8]; acc[0] = helper(x); return acc[0]; }
"""
RECURSIVE_C = r"""
int pong(int n);
int ping(int n) { volatile char buf[16]; buf[0] = (char)n; return n ? pong(n - 1) : buf[0]; }
int pong(int n) { volatile char buf[24]; buf[0] = (char)n; return n ? ping(n - 1) : buf[0]; }
int main(void) { return ping(5); }
"""


def compiler() -> str:
    path = shutil.which(CC)
    if path is None:
        pytest.fail(f"{CC} not found: run scripts/install/install-toolchain.sh (make test installs it)")
    return path


def build(directory: Path, sources: dict[str, str], flags=("-O0",), cwd: Path | None = None):
    """Compile each source into directory/NAME.o with .su and .ci files next to it."""
    cc = compiler()
    cwd = cwd or directory
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in sources.items():
        src = cwd / name
        src.write_text(text)
        obj = directory / Path(name).with_suffix(".o").name
        done = subprocess.run([cc, *ARCH, *flags, "-fstack-usage", "-fcallgraph-info=su",
                               "-c", "-o", str(obj), name], cwd=cwd, capture_output=True, text=True)
        assert done.returncode == 0, f"{cc} {name}: {done.stderr}"
        assert obj.with_suffix(".ci").exists(), f"{cc} wrote no .ci file (GCC >= 10 needed)"


def su_frames(directory: Path) -> dict[str, int]:
    """Frames from GCC's .su files, by `name` or `unit.c:name` for static functions."""
    frames = {}
    for su in directory.rglob("*.su"):
        for line in su.read_text().splitlines():
            where, size, _ = line.split("\t")
            unit, name = where.split(":")[0], where.split(":")[-1]
            frames.setdefault(name, {})[unit] = int(size)
    return frames


def run(*args):
    return subprocess.run([sys.executable, str(TOOL), *map(str, args)],
                          capture_output=True, text=True, timeout=60)


def path_line(stdout: str, entry: str) -> tuple[int, list[tuple[str, int]]]:
    """(total, [(function, bytes), ...]) of the line of one entry."""
    match = re.search(rf"^stack: worst path from {re.escape(entry)} (\d+) B[^:]*: (.*)$",
                      stdout, re.M)
    assert match, f"no line for {entry} in:\n{stdout}"
    frames = [(m.group(1), int(m.group(2)))
              for m in re.finditer(r"(\S+) \((\d+)[^)]*\)", match.group(2))]
    return int(match.group(1)), frames


@pytest.fixture(scope="module")
def program(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("stackpath") / "obj"
    build(directory, {"app.c": APP_C, "dsp.c": DSP_C}, cwd=directory.parent)
    return directory


def test_worst_path_is_the_deepest_chain_and_sums_the_su_frames(program):
    done = run(program)
    assert done.returncode == 0, done.stdout + done.stderr
    su = su_frames(program)
    total, frames = path_line(done.stdout, "main")
    assert [f for f, _ in frames] == ["main", "work", "filter", "dsp.c:helper"], \
        "the deepest chain, through dsp.c's static helper"
    # the static helper of dsp.c, not the smaller one of app.c
    expected = [su["main"]["app.c"], su["work"]["app.c"], su["filter"]["dsp.c"],
                su["helper"]["dsp.c"]]
    assert su["helper"]["dsp.c"] > su["helper"]["app.c"], "64 taps against 16: merging by bare name would be wrong"
    assert [b for _, b in frames] == expected, "each frame as GCC's .su file gives it"
    assert total == sum(expected), "the path's total is the sum of its frames"


def test_unknown_indirect_and_dynamic_frames_are_listed(program):
    out = run(program).stdout
    unknown = re.search(r"^stack: worst path from main .*\n  unknown frames[^:]*: (.*)$", out, re.M)
    assert unknown, out
    assert "sinf" in unknown.group(1) and "indirect call in dispatch" in unknown.group(1), \
        f"libm's sinf has no .ci node and dispatch calls through a pointer: {unknown.group(1)}"
    assert re.search(r"^  dynamic frames: vla \(unbounded", out, re.M), out


def test_assume_counts_a_library_frame(program):
    su = su_frames(program)
    total, frames = path_line(run("--assume", "sinf=4096", program).stdout, "main")
    assert frames == [("main", su["main"]["app.c"]), ("wave", su["wave"]["app.c"]), ("sinf", 4096)], \
        "sinf at the assumed 4096 B makes main > wave > sinf the worst path"
    assert total == su["main"]["app.c"] + su["wave"]["app.c"] + 4096, "the sum of its frames"


def test_indirect_targets_join_the_graph(program):
    su = su_frames(program)
    base, _ = path_line(run("--entry", "SysTick_Handler", program).stdout, "SysTick_Handler")
    assert base == su["SysTick_Handler"]["app.c"] + su["dispatch"]["app.c"], \
        "without --indirect the pointer call counts 0 B"
    done = run("--entry", "SysTick_Handler", "--indirect", "dispatch=filter", program)
    total, frames = path_line(done.stdout, "SysTick_Handler")
    assert [f for f, _ in frames] == ["SysTick_Handler", "dispatch", "filter", "dsp.c:helper"], \
        "dispatch=filter: the pointer call continues into filter"
    assert total == base + su["filter"]["dsp.c"] + su["helper"]["dsp.c"], "filter's chain added to the handler's"
    assert "indirect call" not in done.stdout, "a named target leaves no unknown indirect call"


def test_handlers_nest_on_the_thread_worst_path(program):
    out = run(program).stdout
    su = su_frames(program)
    # reset from the vector table, a static handler from the vector table, one by its name
    reset, _ = path_line(out, "reset_handler")
    main, _ = path_line(out, "main")
    assert reset == su["reset_handler"]["app.c"] + main, "reset_handler calls main: its frame on main's worst path"
    fault, frames = path_line(out, "app.c:fault")
    assert frames == [("app.c:fault", su["fault"]["app.c"])], "the static fault handler, found in the vector table"
    assert re.search(r"^stack: worst path from app\.c:fault \d+ B \(ISR, \+104 B", out, re.M), \
        "a handler is an ISR with the 104 B exception entry of an FP context (the default)"
    assert re.search(r"^stack: worst path from SysTick_Handler \d+ B \(ISR", out, re.M), \
        "SysTick_Handler is an ISR by its name"
    nested = re.search(r"^stack: reset_handler \+ deepest ISR (\d+) B: .*app\.c:fault", out, re.M)
    assert nested, out
    assert int(nested.group(1)) == reset + 104 + fault, "the thread's worst path, the exception entry, the handler"
    out32 = run("--exception-frame", "32", program).stdout
    assert f"deepest ISR {reset + 32 + fault} B" in out32, "with 32 B, the 8 core registers alone, as the entry"


def test_limit(program):
    out = run(program).stdout
    need = int(re.search(r"deepest ISR (\d+) B", out).group(1))
    done = run("--limit", need - 1, program)
    assert done.returncode == 1, f"a byte over the limit fails with status 1: {done.stdout}"
    assert re.search(rf"^stackpath: FAIL: .*{need} B, over the limit of {need - 1} B", done.stdout, re.M), \
        done.stdout
    done = run("--limit", need, program)
    assert done.returncode == 0 and "stackpath: ok:" in done.stdout, f"exactly at the limit passes: {done.stdout}"
    # only thread entries: the limit is on the worst single path
    main, _ = path_line(out, "main")
    assert run("--entry", "main", "--limit", main, program).returncode == 0, "main's worst path at the limit"
    assert run("--entry", "main", "--limit", main - 1, program).returncode == 1, "main's worst path a byte over"


def test_recursion_fails_naming_the_cycle(tmp_path):
    build(tmp_path, {"rec.c": RECURSIVE_C})
    done = run(tmp_path)
    assert done.returncode == 1, "recursion reachable from an entry fails with status 1"
    assert "stackpath: FAIL: recursion: ping > pong > ping" in done.stdout, done.stdout


def test_bad_usage(tmp_path, program):
    done = run(tmp_path)
    assert done.returncode == 2 and "no .ci file" in done.stderr, f"bad usage is status 2: {done.stderr}"
    done = run("--entry", "nowhere", program)
    assert done.returncode == 2 and "no function nowhere" in done.stderr, done.stderr
    done = run("--entry", "helper", program)
    assert done.returncode == 2 and "ambiguous" in done.stderr, \
        f"two static helpers, app.c's and dsp.c's: {done.stderr}"


def test_importable(program):
    spec = importlib.util.spec_from_file_location("stackpath", TOOL)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module   # dataclasses look their module up there
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[spec.name]
    graph = module.load(program)
    worst = module.Analysis(graph).path("main")
    assert [t for t, _, _ in worst.frames] == ["main", "work", "filter", "dsp.c:helper"], \
        "the module gives the command line's deepest chain"
    assert worst.total == sum(b for _, b, _ in worst.frames), "the total is the sum of the frames"


@pytest.mark.slow
def test_the_core_has_no_recursion(tmp_path):
    """The firmware core, built with the Cortex-M4F flags of firmware/mcu/rules.mk."""
    compiler()
    flags = subprocess.run(["make", "-s", "--no-print-directory", "--eval",
                            "print-mcu-cflags: ; @echo $(MCU_CFLAGS)", "print-mcu-cflags"],
                           cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    assert "-mcpu=cortex-m4" in flags, f"rules.mk's MCU_CFLAGS target the Cortex-M4F: {flags}"
    for src in sorted((ROOT / "firmware" / "core").glob("*.c")):
        obj = tmp_path / src.relative_to(ROOT).with_suffix(".o")
        obj.parent.mkdir(parents=True, exist_ok=True)
        done = subprocess.run([CC, *flags, "-fcallgraph-info=su", "-c", "-o", str(obj),
                               str(src.relative_to(ROOT))], cwd=ROOT, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
    done = run("--entry", "sd_step", "--entry", "sd_rnea", "--entry", "sd_control_step", tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    for entry in ("sd_step", "sd_rnea", "sd_control_step"):
        assert path_line(done.stdout, entry)[0] > 0, f"{entry}: its worst path counts no frame"
    assert "dynamic frames" not in done.stdout, "no VLA or alloca in the core: every frame has a fixed size"


def test_bounded_and_dynamic_frames_are_flagged(tmp_path):
    """A hand-written .ci: frames GCC marks "dynamic,bounded" and "dynamic"."""
    (tmp_path / "x.ci").write_text(
        'graph: { title: "x.c"\n'
        'node: { title: "main" label: "main\\nx.c:9:5\\n16 bytes (static)" }\n'
        'node: { title: "x.c:grow" label: "grow\\nx.c:3:12\\n64 bytes (dynamic,bounded)" }\n'
        'node: { title: "vla" label: "vla\\nx.c:5:5\\n8 bytes (dynamic)" }\n'
        'edge: { sourcename: "main" targetname: "x.c:grow" label: "x.c:9:20" }\n'
        'edge: { sourcename: "main" targetname: "vla" label: "x.c:9:30" }\n'
        '}\n')
    done = run(tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "stack: worst path from main 80 B: main (16) > x.c:grow (64, bounded)" in done.stdout, \
        "a bounded frame counted at its 64 B bound; vla's 8 B fixed part is the lighter branch"
    assert ("  dynamic frames: vla (unbounded: only its fixed part counted), "
            "x.c:grow (bounded: counted at its bound)") in done.stdout
