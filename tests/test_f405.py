"""The firmware on the STM32F405 board layer (firmware/boards/stm32f405), end to end under
`qemu-system-arm -M netduinoplus2`: the same application, the same hardware-in-the-loop host side
(host/hil.py: -serial #0 = USART1, the Dynamixel bus; #1 = USART2, the sync line) and the same
oracle as the MPS2 image (tests/test_firmware.py): the host's double-precision controller fed
the measured states the firmware saw. What QEMU does not model (RCC, GPIO) is checked from its
register trace of unimplemented devices (-d unimp)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from servodyn.hil import default_elf, run_qemu, summarize
from servodyn.tools.bench.fw_budget import footprint

ROOT = Path(__file__).resolve().parent.parent
TICKS = 300              # 0.3 s of homing: inverse-dynamics ticks and the others, every section timed
SERVOS = 7               # the replica
SETUP_PACKETS = 8        # a servo's set-up: ping, torque off, return delay, mode, watchdog clear,
                         # Goal Current 0, torque on, watchdog (fw_main.c's setup)


@pytest.fixture(scope="module")
def images():
    build = subprocess.run(["make", "--no-print-directory", "-s", "fw"], cwd=ROOT, capture_output=True, text=True)
    assert build.returncode == 0, f"make fw failed:\n{build.stdout}\n{build.stderr}"
    return {board: default_elf(board) for board in ("an386", "f405")}


@pytest.fixture(scope="module")
def runs(images, tmp_path_factory):
    trace = tmp_path_factory.mktemp("unimp") / "unimp.log"
    f405 = run_qemu("f405", images["f405"], icount_shift=3, args=f"ticks={TICKS}",
                    extra=("-d", "unimp", "-D", str(trace)))
    an386 = run_qemu("an386", images["an386"], icount_shift=3, args=f"ticks={TICKS}")
    return {"f405": f405, "an386": an386, "trace": trace.read_text()}


def test_f405_image_fits_its_budget(images):
    """Flash <= 64 KB, RAM (data + bss + the 4 KB stack reserved) <= 32 KB, measured as the
    budget measures the MPS2 image (tools/bench/fw_budget.py's footprint); no heap, no stdio, no
    double arithmetic; the vector table at the start of flash names the board's handlers."""
    size = footprint(images["f405"])
    assert size["flash"] <= 64 * 1024, f"flash {size['flash']} B over the 64 KB goal"
    assert size["ram"] <= 32 * 1024, f"RAM {size['ram']} B over the 32 KB goal"
    nm = subprocess.run(["arm-none-eabi-nm", str(images["f405"])], capture_output=True, text=True).stdout
    symbols = {line.split()[-1]: int(line.split()[0], 16) for line in nm.splitlines() if len(line.split()) == 3}
    assert not set(symbols) & {"malloc", "_sbrk", "printf", "puts", "__aeabi_dadd", "__aeabi_f2d", "sin", "cos"}, \
        "no heap, no stdio, no double arithmetic or double libm"
    flash = subprocess.run(["arm-none-eabi-objcopy", "-O", "binary", "-j", ".text", str(images["f405"]), "/dev/stdout"],
                           capture_output=True).stdout
    vector = lambda k: int.from_bytes(flash[4 * k:4 * k + 4], "little")   # noqa: E731
    assert vector(0) == symbols["__stack_top"] <= 0x20000000 + 128 * 1024, "initial SP: the stack's top, in SRAM"
    assert vector(1) == symbols["f405_reset"] | 1, "reset: f405_reset (Thumb bit set)"
    assert vector(15) == symbols["board_systick_isr"] | 1, "SysTick"
    assert vector(16 + 37) == symbols["f405_usart1_isr"] | 1, "IRQ 37: USART1, the bus (RM0090 table 61)"
    assert vector(16 + 38) == symbols["f405_usart2_isr"] | 1, "IRQ 38: USART2, the sync line"
    assert len(flash) >= 4 * (16 + 82), "16 system vectors and the F405's 82 interrupts"


@pytest.mark.slow
def test_f405_commands_agree_with_the_host_and_the_mps2_image(runs):
    """300 ticks on netduinoplus2: every Goal Current within 1 servo unit of the host's double
    controller from the same measured states (the MPS2 run's oracle, summarize), the measured
    states identical to the MPS2 run's (lock-step: the plant moves with the commands, tolerance 0)
    and every command within 1 unit of the MPS2 image's (float on the same M4F code, another board
    layer). The stack used stays in the 2 KB goal, torque is off at the end."""
    (report, record, arm), (mps2, mps2_record, _) = runs["f405"], runs["an386"]
    assert report["result"] == "done" and report["exit_code"] == 0 and report["ticks"] == TICKS, report
    summary = summarize(report, record, "replica", 3, "f405")
    assert summary["goal_max_diff_units"] <= 1, summary["goal_diff_counts"]
    assert len(record.reads) == len(mps2_record.reads) and all(
        np.array_equal(a, b) for a, b in zip(record.reads, mps2_record.reads)), "the same measured states"
    diff = np.abs(np.array(record.goals) - np.array(mps2_record.goals)).max()
    assert diff <= 1, f"F405 and MPS2 commands {diff} units apart"
    assert report["stack"] <= 2048, f"{report['stack']} B of stack used; the goal is 2 KB"
    assert record.torque_off and not any(s.torque_enabled for s in arm.servos), "a servo left with torque on"
    assert report["missed"] == 0 and report["rx_overruns"] == 0, report


@pytest.mark.slow
def test_f405_tick_matches_the_mps2_image(runs):
    """Instructions per tick as the budget counts them (SysTick counts at 168 MHz under -icount
    shift=3: 8 ns an instruction; summarize converts with the board's clock): the same application
    code, so the computation's worst ticks (inverse dynamics, the observer) are the MPS2 image's
    within 1 % and the mean tick within 1 % (the board layers differ by a handful of instructions
    a byte on the bus: TXE against TXFULL, the direction pin). The worst of the read section is
    not compared: on a loaded machine one run in a few has one read up to ~2,300 instructions
    longer on either board (docs/boards.md), while its mean stays the same."""
    f405 = summarize(*runs["f405"][:2], "replica", 3, "f405")["instructions_per_tick"]
    mps2 = summarize(*runs["an386"][:2], "replica", 3, "an386")["instructions_per_tick"]
    for section in ("control_update", "observer"):
        assert abs(f405[section]["max"] - mps2[section]["max"]) <= 0.01 * mps2[section]["max"], \
            (section, f405[section], mps2[section])
    for section in ("tick", "read", "control_update", "observer"):
        assert abs(f405[section]["mean"] - mps2[section]["mean"]) <= 0.01 * mps2[section]["mean"], \
            (section, f405[section], mps2[section])


def _writes(trace: str, device: str, offset: int) -> list[int]:
    return [int(v, 16) for v in re.findall(
        rf"^{device}: unimplemented device write \(size 4, offset 0x{offset:03x}, value 0x([0-9a-f]+)\)", trace, re.M)]


@pytest.mark.slow
def test_f405_pin_and_clock_setup_from_the_register_trace(runs):
    """QEMU models neither RCC nor GPIO; its -d unimp trace shows what the board wrote (each
    read-modify-write from a register that reads 0 shows one pin's bits): the PLL word (HSE, M=4,
    N=168, P=2, Q=7: 0x07402A04), 5 flash wait states with prefetch and caches, APB1 /4 and APB2 /2
    on the PLL, PA9 on AF7 open drain with a pull-up, PA2/PA3 on AF7, PA8 an output, and the
    direction pin high before and low after every packet the firmware sent."""
    trace = runs["trace"]
    assert _writes(trace, "RCC", 0x004) == [0x07402A04], "PLLCFGR: the 168 MHz word, once"
    assert _writes(trace, "Flash Int", 0x000) == [0x705], "FLASH_ACR: 5 WS, PRFTEN, ICEN, DCEN"
    assert _writes(trace, "RCC", 0x008)[-1] == 0x9402, "CFGR: PPRE2 /2, PPRE1 /4, SW = PLL"
    moder = _writes(trace, "GPIOA", 0x000)
    for pin, mode in ((2, 2), (3, 2), (8, 1), (9, 2)):
        assert mode << 2 * pin in moder, f"PA{pin} mode {mode}"
    assert 7 << 8 in _writes(trace, "GPIOA", 0x020) and 7 << 12 in _writes(trace, "GPIOA", 0x020), "PA2, PA3 AF7"
    assert 7 << 4 in _writes(trace, "GPIOA", 0x024), "PA9 AF7 (AFRH)"
    assert _writes(trace, "GPIOA", 0x004) == [1 << 9] and _writes(trace, "GPIOA", 0x00c) == [1 << 18], \
        "PA9 open drain, pull-up"
    bsrr = _writes(trace, "GPIOA", 0x018)
    packets = SERVOS * SETUP_PACKETS + 1 + 2 * TICKS + 1      # set-up, the first read, read + write a tick, torque off
    assert bsrr[0] == 1 << 24, "the direction pin low (receive) before the bus is enabled"
    assert bsrr[1:] == [1 << 8, 1 << 24] * packets, f"high, then low, around each of the {packets} packets"


@pytest.mark.slow
def test_f405_build_for_silicon_has_no_semihosting(tmp_path):
    """FW_HIL=0, the image a user flashes: no semihosting call anywhere (a `bkpt` is a HardFault
    on a board with no debugger attached: the report goes to USART2 instead), no sync line, and
    the same footprint goals."""
    out = tmp_path / "fw"
    build = subprocess.run(["make", "--no-print-directory", "-s", "FW_HIL=0", f"FW_DIR={out}",
                            str(out / "f405" / "servodyn-fw.elf")], cwd=ROOT, capture_output=True, text=True)
    assert build.returncode == 0, build.stdout + build.stderr
    elf = out / "f405" / "servodyn-fw.elf"
    code = subprocess.run(["arm-none-eabi-objdump", "-d", str(elf)], capture_output=True, text=True).stdout
    assert "bkpt" not in code, "a semihosting call in the image for silicon"
    nm = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True).stdout
    assert "f405_console_write" in nm and "g_host_read" not in nm, "the console on USART2, no sync line"
    size = footprint(elf)
    assert size["flash"] <= 64 * 1024 and size["ram"] <= 32 * 1024, size


@pytest.mark.slow
def test_f405_silent_servo_stops_with_torque_off(images):
    """Servo 3 stops answering after tick 100: the F405's own reply timeout (20,000 polls, about a
    millisecond on silicon) trips at the next read, after the sync line says the bus is quiet,
    and every servo's torque is switched off: fault 10 (firmware/app/fw_app.h), servo 3, tick 101."""
    def silence(k, arm):
        if k == 100:
            arm.inject_fault(3, "silent")
    report, record, arm = run_qemu("f405", images["f405"], icount_shift=3, args="ticks=300", on_tick=silence)
    assert report["result"] == "fault" and report["fault"] == "timeout" and report["exit_code"] == 10, report
    assert report["servo"] == 3 and report["fault_tick"] == 101, report
    assert record.torque_off and not any(s.torque_enabled for s in arm.servos), "a servo left with torque on"
