"""The firmware budget's plan against the wall clock (tools/bench/fw_budget.py, run by `make bench`): it
times a short and a longer run, and measures the whole swing only when it fits its budget, else
the ticks that fit; a board whose run fails is one line, never a traceback. The runs are replaced
here by stand-ins whose wall times are given (no time is measured in the test suite)."""

import pytest

from servodyn.tools.bench import fw_budget
from servodyn.hil import FirmwareError


def _fake_runs(monkeypatch, start, per_tick):
    calls = []

    def timed_run(board, ticks, timeout):
        calls.append(ticks)
        return {}, None, start + ticks * per_tick
    monkeypatch.setattr(fw_budget, "timed_run", timed_run)
    return calls


def test_the_whole_swing_when_it_fits_the_budget(monkeypatch):
    calls = _fake_runs(monkeypatch, start=1.0, per_tick=0.005)       # 9,202 ticks: ~47 s
    said = []
    assert fw_budget.plan_ticks("an386", 9202, 300.0, say=said.append) is None, "47 s x 1.3 fits 300 s"
    assert calls == list(fw_budget.CALIBRATION), "two timing runs of the calibration's sizes"
    assert "5.00 ms of wall clock a tick" in said[0] and "1.0 s to start" in said[0], said


def test_a_loaded_machine_measures_the_ticks_that_fit(monkeypatch):
    _fake_runs(monkeypatch, start=2.0, per_tick=0.05)               # 9,202 ticks: ~462 s
    said = []
    ticks = fw_budget.plan_ticks("an386", 9202, 300.0, say=said.append)
    assert ticks == int((300.0 / fw_budget.MARGIN - 2.0) / 0.05), f"the ticks that fit: {ticks}"
    assert f"{ticks:,} ticks are measured" in said[0], said
    _fake_runs(monkeypatch, start=2.0, per_tick=5.0)                # absurdly slow: still the calibration's
    assert fw_budget.plan_ticks("an386", 9202, 300.0, say=said.append) == fw_budget.CALIBRATION[1]


def test_a_board_that_fails_is_one_line_and_exit_1(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(fw_budget, "ROOT", tmp_path)       # its out/bench here, not in the checkout

    def broken(*args, **kwargs):
        raise FirmwareError("QEMU did not open its serial port: no such machine\nsecond line")
    monkeypatch.setattr(fw_budget, "timed_run", broken)
    monkeypatch.setattr(fw_budget, "planned_ticks", lambda: 9202)
    assert fw_budget.main([]) == 1, "nothing measured"
    out = capsys.readouterr().out
    assert "an386: not measured: QEMU did not open its serial port: no such machine" in out, out
    assert "second line" not in out and "Traceback" not in out, out
    with pytest.raises(SystemExit):
        fw_budget.main(["--budget", "x"])


def test_every_section_the_firmware_times_has_a_row():
    """The budget's table names each section fw_main.c times (the observer's included), in its order."""
    import re
    from pathlib import Path
    source = (Path(__file__).resolve().parent.parent / "firmware/app/fw_main.c").read_text()
    names = re.search(r"g_section_name\[NSEC\] = \{([^}]*)\}", source).group(1)
    assert re.findall(r'"(\w+)"', names) == [key for key, _ in fw_budget.ROWS], names
