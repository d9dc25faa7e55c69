"""A Dynamixel bus that stalls in the middle of a swing (issue 22: a real bus is imperfect): the
simulator, in a process of its own, freezes for 2.5 or 5 s (PtyServer.pause). The servos' Bus
Watchdog (BUS_WATCHDOG, 100 ms) trips on a silence that long, so on real servos the torque is off
by then: the run must stop as a stall of the bus (exit 10), with one line that says how long the
bus was silent, summary.json written and the log kept. It used to complete with exit 0, the retry
taking the reply to the request sent before the stall (reads_retried 1, one tick of 2.5 s)."""

import json
import re
import subprocess
import time

import pytest

from servodyn.control.timing import BUS_WATCHDOG
from servodyn.hal.config import load_config
from servodyn.hal.ports import PTY_REPLY_TIMEOUT
from servodyn.sim.serve import SimProcess

from helpers import csv_rows, start_cli, wait_for_rows

CONFIG = load_config("replica")
TIME_SCALE = 3           # a long swing, so the pause surely lands in it; the stall ends the run anyway


@pytest.mark.slow
@pytest.mark.serial
@pytest.mark.parametrize("pause", [2.5, 5.0])
def test_a_stall_longer_than_the_watchdog_stops_the_swing(tmp_path, pause):
    out = tmp_path / "out"
    with SimProcess(CONFIG.path, "lockstep") as sim:
        swing = start_cli("swing", "--port", sim.path, "--time-scale", TIME_SCALE, "--out", out,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            ran = wait_for_rows(out / "swing_log.csv", 200, proc=swing)   # homing is not logged
            assert swing.poll() is None and ran >= 200, f"the swing is under way before the stall: {swing.stderr.read()}"
            paused = time.monotonic()
            sim.pause(pause)
            _, stderr = swing.communicate(timeout=180)
            took = time.monotonic() - paused
        finally:
            if swing.poll() is None:
                swing.kill()
                swing.wait(timeout=30)
    assert swing.returncode == 10, f"exit {swing.returncode}, expected 10 (a stall of the bus): {stderr}"
    lines = stderr.strip().splitlines()         # the swing's messages, then its one stop line, last
    stops = [line for line in lines if line.startswith("servodyn: ")]
    assert stops == lines[-1:] and "Traceback" not in stderr and "bus 'arm' stalled" in stops[0], stderr
    silent = re.search(r"silent for (\d+) ms", stops[0])
    assert silent, f"the reason names how long the bus was silent: {stops[0]}"
    # the host waits out its whole reply timeout before it calls anything a failure, and it cannot
    # have heard silence for longer than it waited (plus the tick in flight when the pause began)
    silent_ms = int(silent.group(1))
    assert PTY_REPLY_TIMEOUT["dynamixel"] * 1e3 <= silent_ms <= (took + 0.1) * 1e3, (silent_ms, took)
    assert silent_ms > BUS_WATCHDOG * 1e3, "longer than the servos' Bus Watchdog: the reason for the stop"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["error_class"] == "BusStallError" and summary["exit_code"] == 10, summary
    assert not summary["completed"], "the stall ended the swing"
    assert summary["bus"]["reads_retried"] <= 1, \
        f"stopped at the first failed try after the silence, no late reply taken: {summary['bus']}"
    assert len(csv_rows(out / "swing_log.csv")) - 1 == summary["ticks"] >= ran, \
        "the log holds every tick to the stop, those before the pause included"
