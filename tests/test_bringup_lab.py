"""From a box of factory-fresh servos to a swing, the way a user does it, every step through the
command line against `servodyn sim` on a simulated bench (sim/lab.py): seven new servos, all at
ID 1 and 57600 baud, their horns mounted where the configuration does not say (zeros hundreds of
ticks off, one joint reversed), their EEPROM kept in a store file from one power-up of the
simulator to the next.

    scan (collisions at ID 1) -> setup, one servo connected at a time -> scan (as configured)
    -> doctor (clean) -> calibrate (a person at the arm, through standard input) -> swing
"""

from __future__ import annotations

import json
import math
import subprocess
from contextlib import contextmanager
from pathlib import Path

import pytest
import tomlkit

from servodyn.hal.config import load_config
from servodyn.sim.lab import Lab
from servodyn.sim.serve import serve

from helpers import PTY, answer_prompts, run_cli, sim_process, start_cli

pytestmark = [pytest.mark.slow, pytest.mark.serial]      # whole bring-ups; the simulated servos answer within wall-clock timeouts

CONFIG = load_config("replica")
DOFS = CONFIG.model.dof_names


@contextmanager
def sim(store: Path, *extra):
    """`servodyn sim --config replica` on the bench in `store`: a power-up of the servos connected."""
    with sim_of("replica", store, *extra) as port:
        yield port


@pytest.fixture(scope="module")
def bench_store(tmp_path_factory):
    """The bench after the set-up of every servo (each step asserted in test_setup_one_by_one)."""
    return tmp_path_factory.mktemp("bench") / "bench.json"


def test_1_fresh_servos_collide_at_id_1(bench_store):
    with sim(bench_store, "--factory") as port:
        result = run_cli("scan", "--port", port, "--config", "replica")
    # seven servos at ID 1 answer a ping at once: their replies collide, and scan says what to do
    said = result.stdout + result.stderr
    assert result.returncode == 1, said
    assert "several servos answer at ID 1 at 57600 baud" in said, said
    assert "connect one servo at a time" in said


def test_2_setup_one_by_one(bench_store):
    for k, dof in enumerate(DOFS):
        with sim(bench_store, "--factory", "--connect", dof) as port:
            result = run_cli("setup", "--config", "replica", "--joint", dof, "--port", port, "--yes")
        said = result.stdout + result.stderr
        assert result.returncode == 0, (dof, said)
        assert "found XM" in said and "at ID 1, 57600 baud" in said, said
        assert f"answers at ID {k + 1}, 4000000 baud" in said, said
    # every servo now at its ID and the bus's rate, as the configuration says
    with sim(bench_store) as port:
        scan = run_cli("scan", "--port", port, "--config", "replica", "--json")
        doctor = run_cli("doctor", "--config", "replica", "--port", port, "--json")
    found = json.loads(scan.stdout)
    assert scan.returncode == 0, scan.stderr
    assert sorted((f["id"], f["baud"]) for f in found) == [(k, 4_000_000) for k in range(1, 8)]
    assert doctor.returncode == 0, doctor.stdout
    assert [f for f in json.loads(doctor.stdout)["findings"] if f["severity"] == "error"] == []


def test_3_calibrate_finds_the_mounting_then_the_swing_plays(bench_store, tmp_path):
    """The bench's horns are not where the configuration says: calibrate finds each one's direction
    and zero (the store holds the truth), and the swing then plays on the calibrated copy."""
    truth = json.loads(bench_store.read_text())
    served = serve(CONFIG, "lockstep", process=False, lab=Lab(store=bench_store))
    target = tmp_path / "replica.toml"
    try:
        port = served.buses["arm"]["port"]
        robot = served.robot

        def by_hand(dof, angle):
            with robot.lock:
                robot.plant.q[DOFS.index(dof)] = angle
                robot.plant.publish()

        steps = []
        for k, dof in enumerate(DOFS):
            lower, upper = CONFIG.model.lower[k], CONFIG.model.upper[k]
            steps += [(dof, 0.25), (dof, -0.003), (dof, 0.003), (dof, lower - 0.05), (dof, upper + 0.05)]
        moves = iter(steps)
        # the prompts read from stdout and stderr together: whichever stream carries them
        proc = start_cli("calibrate", "--config", "replica", "--port", port, "--write", target, "--margin", "1",
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            text = answer_prompts(proc, lambda: by_hand(*next(moves)))
            code = proc.wait(timeout=120)
        finally:
            proc.kill()
        assert code == 0, text
    finally:
        served.stop()
    joints = {j["dof"]: j for j in tomlkit.parse(target.read_text())["joint"]}
    for dof in DOFS:
        mounted = truth["mounting"][dof]
        assert joints[dof]["direction"] == mounted["direction"], dof
        # the mean of two approaches 0.006 rad apart: the mounting's zero within two ticks
        assert joints[dof]["zero_offset"] == pytest.approx(mounted["zero_offset"], abs=2 * 2 * math.pi / 4096), dof
    # the swing, on the calibrated copy (stops past the model's: its limits stay the model's),
    # against the same bench: completes and tracks
    with sim(bench_store, "--lockstep") as port:
        result = run_cli("swing", "--config", str(target), "--port", port, "--out", str(tmp_path / "swing"), "--yes")
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr
    summary = json.loads((tmp_path / "swing" / "summary.json").read_text())
    # the replica's swing tracks within 0.2 degrees on a plant its configuration describes (README);
    # here the zeros are the calibration's, within two ticks (0.18 degrees) of the truth
    assert math.degrees(summary["tracking_max_rad"]) < 1.0, summary["tracking_max_rad"]


@contextmanager
def sim_can(store: Path, *extra):
    """`servodyn sim --config replica_can` on the bench in `store`, lock-step, behind its SLCAN adapter."""
    with sim_of("replica_can", store, "--lockstep", *extra) as port:
        yield port


@contextmanager
def sim_of(config: str, store: Path, *extra):
    """`servodyn sim` of `config` on the bench in `store`, in its own process; its pseudo-terminal."""
    with sim_process("--config", config, "--bench", store, *extra) as (_, banner):
        yield PTY.search("".join(banner)).group(0)


def test_fresh_damiao_motors_found_on_master_id_0_then_set_up(tmp_path):
    """Fresh Damiao motors all answer at CAN ID 1 on Master ID 0, which looks like no motor to a
    host listening on the configured ids: scan reports them with the fix; setup gives one its ids,
    MIT mode and ranges, saved to flash after a yes; after a power-up from the store it answers
    where the configuration says."""
    store = tmp_path / "bench.json"
    with sim_can(store, "--factory") as port:
        scan = run_cli("scan", "--config", "replica_can", "--port", port)
    assert scan.returncode == 1, scan.stdout + scan.stderr
    said = scan.stdout + scan.stderr
    assert "Master ID 0" in said and "servodyn setup" in said, said
    with sim_can(store, "--factory", "--connect", "r_elbow_flexion") as port:
        setup = run_cli("setup", "--config", "replica_can", "--joint", "r_elbow_flexion", "--port", port, "--yes")
    assert setup.returncode == 0, setup.stdout + setup.stderr
    with sim_can(store, "--connect", "r_elbow_flexion") as port:        # a power-up: flash only
        scan = run_cli("scan", "--config", "replica_can", "--port", port, "--json")
    found = json.loads(scan.stdout)
    assert [(f["id"], f["master_id"], f["model"]) for f in found] == [(4, 0x14, "DM-J4340")], found
