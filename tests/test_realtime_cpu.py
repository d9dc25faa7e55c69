"""The real-time path on one CPU (hal.realtime.one_cpu): the process pinned and the kernel's
work queues steered for the block, each put back after, and left alone — with one line — whenever
they cannot or should not be touched. A file stands in for the sysfs mask here (the real one is
steered by the real-time swings of other tests, and put back by them)."""

from __future__ import annotations

import os

import pytest

from servodyn.hal import realtime

from helpers import quiet

ALLOWED = sorted(os.sched_getaffinity(0))
ONLINE = sum(1 << c for c in range(os.cpu_count() or 1))
needs_two = pytest.mark.skipif(len(ALLOWED) < 2, reason="one CPU: nothing to place")


def _mask_file(tmp_path, mask: int):
    path = tmp_path / "cpumask"
    path.write_text(f"{mask:x}\n")
    return path


@needs_two
def test_the_path_is_placed_on_the_last_cpu_and_given_back(tmp_path):
    path, said = _mask_file(tmp_path, ONLINE), []
    with realtime.one_cpu(say=said.append, mask_file=path) as cpu:
        assert cpu == ALLOWED[-1], "the last CPU the process may use"
        assert os.sched_getaffinity(0) == {cpu}, "this process (and what it starts) pinned there"
        assert realtime._cpu_mask(path.read_text()) == 1 << cpu, "the work queues steered there"
    assert sorted(os.sched_getaffinity(0)) == ALLOWED, "the affinity given back"
    assert realtime._cpu_mask(path.read_text()) == ONLINE, "the work queues given back"
    assert len(said) == 1 and f"CPU {cpu}" in said[0], said


@needs_two
def test_a_mask_already_kept_is_left_alone(tmp_path):
    """An administrator's mask, or another run's steering: nothing is touched or pinned (pinned
    without the workers the loop misses more deadlines, not fewer)."""
    path, said = _mask_file(tmp_path, 1), []
    with realtime.one_cpu(say=said.append, mask_file=path) as cpu:
        assert cpu is None and sorted(os.sched_getaffinity(0)) == ALLOWED, "not pinned"
    assert path.read_text() == "1\n", "the mask as it was"
    assert len(said) == 1 and "left unplaced" in said[0], said


@needs_two
def test_unwritable_work_queues_leave_the_path_unplaced(tmp_path):
    path, said = tmp_path / "absent" / "cpumask", []
    with realtime.one_cpu(say=said.append, mask_file=path) as cpu:
        assert cpu is None and sorted(os.sched_getaffinity(0)) == ALLOWED
    assert len(said) == 1 and "cannot steer" in said[0] and "\n" not in said[0], said


@needs_two
def test_a_mask_someone_changed_meanwhile_is_not_overwritten(tmp_path):
    path = _mask_file(tmp_path, ONLINE)
    with realtime.one_cpu(say=quiet, mask_file=path):
        path.write_text("1\n")                 # another hand steered it during the run
    assert path.read_text() == "1\n", "theirs stays"


@needs_two
def test_a_cpu_the_process_may_not_use_is_refused(tmp_path):
    with pytest.raises(ValueError, match="not one this process may use"):
        with realtime.one_cpu(cpu=max(ALLOWED) + 1, say=quiet, mask_file=_mask_file(tmp_path, ONLINE)):
            pass


def test_masks_read_and_write_as_sysfs_has_them():
    assert realtime._cpu_mask("3\n") == 3 and realtime._cpu_mask("ff,ffffffff") == (1 << 40) - 1
    assert realtime._cpu_mask_text(2) == "00000002"
    assert realtime._cpu_mask(realtime._cpu_mask_text(1 << 40)) == 1 << 40, "32-bit groups, comma-separated"
