"""The STM32F405's bxCAN driver (firmware/boards/stm32f405/can.c) against a register-level test
double (tests/f405/can_double.c): no QEMU machine models a CAN controller, so the driver's own
register code is compiled for the host with CAN1's and GPIOB's registers in the double's memory
and its bounded waits stepping the double's model of the controller (RM0090 32)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BOARD = ROOT / "firmware" / "boards" / "stm32f405"
DOUBLE = ROOT / "tests" / "f405"
CHECKS = 46        # the CHECKs in can_double.c's main


@pytest.fixture(scope="module")
def double(tmp_path_factory):
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no host C compiler")
    exe = tmp_path_factory.mktemp("can") / "can_double"
    build = subprocess.run(
        [cc, "-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", "-fsanitize=address,undefined",
         "-fno-sanitize-recover=all", f"-I{BOARD}", f"-I{DOUBLE}", "-include", str(DOUBLE / "can_double.h"),
         "-DF405_CAN1_BASE=((uintptr_t)g_can_regs)", "-DGPIOB_BASE=((uintptr_t)g_gpiob_regs)",
         "-DF405_POLL()=can_model_step()", "-o", str(exe), str(BOARD / "can.c"), str(DOUBLE / "can_double.c")],
        capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    return exe


def test_bxcan_driver_against_the_register_double(double):
    """Timing words for 1 Mbit/s .. 125 kbit/s, initialisation from reset with every wait bounded
    (a dead controller: 100,000 polls then a timeout), pins on AF9, standard and extended frames
    out with their TIxR words, three mailboxes then 'full', the filter's mask, FIFO order, the
    overrun counted once, loopback: every check passes (tolerance 0: register words are exact)."""
    run = subprocess.run([str(double)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    found = re.search(r"f405 can: (\d+) checks, (\d+) failed", run.stdout)
    assert found and found.groups() == (str(CHECKS), "0"), run.stdout
