"""When the controller is stopped or dies: SIGINT and SIGTERM during `servodyn swing` are a safe
stop (torque off, log and summary written, exit 128 + the signal); the log streams to disk, so a
SIGKILL loses at most its last 100 ms; and a swing killed outright against `servodyn sim` in
real time leaves the servos to the Bus Watchdog the HAL armed, which drops their Goal Current."""

import json
import signal
import subprocess
import time
from types import SimpleNamespace

import numpy as np
import pytest

from servodyn import loop
from servodyn.control.timing import BUS_WATCHDOG
from servodyn.hal.config import load_config
from servodyn.hal.dynamixel.control_table import ADDR_BUS_WATCHDOG, ADDR_GOAL_CURRENT

from helpers import PTY, csv_rows, sim_process, start_cli, wait_for_rows

CONFIG = load_config("replica")


def test_the_log_streams_to_disk_at_least_every_100_ms(tmp_path, monkeypatch):
    """Rows reach the file once 100 ms of wall-clock time have passed since the last write, with
    every line whole; close() writes the rest."""
    clock = SimpleNamespace(now=0.0)
    monkeypatch.setattr(loop.time, "monotonic", lambda: clock.now)
    log = loop.RunLog(("a", "b"))
    path = tmp_path / "log.csv"
    log.stream(path)
    state = SimpleNamespace(q=np.zeros(2), qd=np.zeros(2), current=np.zeros(2))
    on_disk = []
    for k in range(250):                 # one tick a millisecond
        clock.now = k / 1000
        log.add(k * 1e-3, np.zeros(2), state, np.zeros(2), 0.0, 0.0, 0.0, 0.0)
        on_disk.append(len(csv_rows(path)) - 1)
        assert path.read_text().endswith("\n"), "every line on disk is whole"
    lost = [k + 1 - n for k, n in enumerate(on_disk)]
    assert max(lost) <= 100, f"at most 100 ms of ticks not on disk yet, saw {max(lost)}"
    assert on_disk[100] == 101 and on_disk[99] == 0, "the first write at tick 100, once 100 ms have passed"
    log.close()
    assert len(csv_rows(path)) == 1 + 250, "close() writes every row"
    assert csv_rows(path)[0][:3] == ["t", "q_d_a", "q_d_b"], "the header first"


@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
@pytest.mark.slow
def test_a_signal_during_the_swing_is_a_safe_stop(tmp_path, sig, status):
    """SIGINT or SIGTERM mid-swing: torque off on every servo, the log complete to the stop, a
    summary naming the signal, one line on stderr, exit 128 + the signal's number. A previous
    run's summary and figure in the folder are gone before the run starts."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"completed": true, "stale": true}\n')
    (out / "swing_tracking.png").write_bytes(b"stale")
    proc = start_cli("swing", "--out", out, "--time-scale", "3", stdout=subprocess.DEVNULL,
                     stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        ran = wait_for_rows(out / "swing_log.csv", 200, proc=proc)
        assert proc.poll() is None, f"the swing ended before the signal: {proc.stderr.read()}"
        assert not (out / "summary.json").exists() and not (out / "swing_tracking.png").exists(), \
            "the previous run's summary and figure are removed at the start"
        assert ran >= 100, f"the log streams while the swing runs ({ran} ticks on disk)"
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == status, f"exit {proc.returncode}, expected {status}: {stderr}"
    lines = stderr.strip().splitlines()         # the swing's messages, then its one stop line, last
    stops = [line for line in lines if line.startswith("servodyn: ")]
    assert stops == lines[-1:] and f"interrupted by {sig.name}" in stops[0] and "Traceback" not in stderr, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["signal"] == sig.name and not summary["completed"], summary
    assert all(summary["torque_off"]), "torque off on every servo"
    rows = csv_rows(out / "swing_log.csv")
    # at least the ticks seen on disk before the signal (not more: on a busy machine the swing may
    # not run another tick between that look and the signal)
    assert len(rows) == 1 + summary["ticks"] and summary["ticks"] >= ran, \
        f"the log holds every tick to the stop: {len(rows) - 1} rows, {summary['ticks']} ticks, {ran} before"
    assert all(len(row) == len(rows[0]) for row in rows), "every line complete"


@pytest.mark.slow
@pytest.mark.serial
def test_a_killed_swing_leaves_the_servos_to_their_watchdog(tmp_path):
    """`servodyn sim` in real time in one process, `servodyn swing --port` on it in another;
    SIGKILL of the swing mid-run: the log on disk is whole lines, and every servo has tripped
    the Bus Watchdog the HAL armed and dropped its Goal Current, read back over the wire."""
    sdk = pytest.importorskip("dynamixel_sdk")
    stopped = ""
    for attempt in range(3):       # a starved host can trip the watchdog by itself: then try again,
        with sim_process() as (_, banner):      # on a fresh arm (the last one, limp, has sagged)
            port = PTY.search("".join(banner)).group(0)
            out = tmp_path / f"out{attempt}"
            swing = start_cli("swing", "--port", port, "--realtime", "--time-scale", "3", "--overrun-tolerance", "1e6",
                              "--out", out, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            try:
                ran = wait_for_rows(out / "swing_log.csv", 300, proc=swing)
                if swing.poll() is not None:
                    stopped = swing.stderr.read()
                    assert "Bus Watchdog" in stopped or "stalled" in stopped or "overrun" in stopped, \
                        f"stopped early, not by a stall or an overrun: {stopped}"
                    continue
                swing.kill()
                swing.wait(timeout=30)
                killed = time.monotonic()
                rows = csv_rows(out / "swing_log.csv")
                assert len(rows) - 1 >= ran and all(len(row) == len(rows[0]) for row in rows), \
                    "the log on disk: every tick written before the kill, whole lines"
                time.sleep(max(0.0, killed + 5 * BUS_WATCHDOG - time.monotonic()))   # the watchdog's time
                _assert_limp(sdk, port)
                return
            finally:
                if swing.poll() is None:
                    swing.kill()
                    swing.wait(timeout=30)
    pytest.skip(f"the machine is too busy to keep a real-time swing fed: {stopped}")


def _assert_limp(sdk, port: str) -> None:
    """Every servo on `port` has tripped its Bus Watchdog and dropped its Goal Current, read back
    over the wire."""
    handler, link = sdk.PacketHandler(2.0), sdk.PortHandler(port)
    assert link.openPort() and link.setBaudRate(CONFIG.buses["arm"].baud)
    try:
        for joint in CONFIG.joints:
            watchdog, result, _ = handler.read1ByteTxRx(link, joint.id, ADDR_BUS_WATCHDOG)
            goal, result2, _ = handler.read2ByteTxRx(link, joint.id, ADDR_GOAL_CURRENT)
            assert result == result2 == sdk.COMM_SUCCESS, f"servo {joint.id} answers"
            assert watchdog == 0xFF, f"servo {joint.id}: Bus Watchdog {watchdog}, not tripped (-1)"
            assert goal == 0, f"servo {joint.id}: Goal Current {goal} left applied"
    finally:
        link.closePort()
