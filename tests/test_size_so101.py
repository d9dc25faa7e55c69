"""`servodyn size so101 --motion so101_pick` within the Feetech family (the SO-101's bus drives no
Dynamixel): at the bill of materials' 5 V the shoulder_lift overloads the STS3215-C001 (and every
5-7.4 V gearing), and sized at its best supply a set passes, its bill and the written configuration
checked by `servodyn validate`. Every run writes into a tmp folder (never ./out)."""

from __future__ import annotations

import json
import tomllib

import pytest

from servodyn.hal.feetech.table import SERVOS as FEETECH
from servodyn.validation.sizing import catalogue, default_family, part_mass

from helpers import run_cli


def _size(out, *args):
    done = run_cli("size", "so101", "--motion", "so101_pick", *args, "--out", out, "--yes", "--json", timeout=600)
    return done, json.loads(done.stdout)


def test_the_so101_is_sized_within_feetech():
    assert default_family("so101") == "feetech"            # its configuration's bus kind
    assert default_family("replica") == "dynamixel"         # replica's configurations mix kinds: as before
    assert set(catalogue("feetech")) == set(FEETECH)
    assert not set(FEETECH) & set(catalogue("any")), "'any' never mixes a Feetech servo into a Dynamixel bus"


def test_at_5_v_the_shoulder_lift_overloads(tmp_path):
    """The SO-101's 5 V supply: shoulder_lift is the joint nothing passes at, its STS3215-C001 over
    its torque-speed envelope (1.34 measured, with the 20 % reserve: validate's 1.14 at margin 1 on
    the built-in configuration, whose URDF masses hold the servos already); exit status 1."""
    done, report = _size(tmp_path, "--supply-voltage", "5")
    assert done.returncode == 1 and not report["passed"]
    lift = {c["servo"]: c for c in report["joints"]["shoulder_lift"]["candidates"]}
    assert report["joints"]["shoulder_lift"]["servo"] is None
    assert lift["STS3215-C001"]["worst_check"] == "torque_speed" and lift["STS3215-C001"]["worst_ratio"] > 1.0
    assert "shoulder_lift" in done.stderr + run_cli("size", "so101", "--motion", "so101_pick", "--supply-voltage", "5",
                                                    "--out", tmp_path / "text", "--yes", timeout=600).stdout


def test_sized_set_passes_with_its_bill(tmp_path):
    """At its best supply (12 V: the 5-7.4 V gearings cannot run there) a set passes, one supply and
    one Feetech bus; its bill is six servos of 55 g; `servodyn validate` passes the written files."""
    done, report = _size(tmp_path)
    assert done.returncode == 0 and report["passed"], done.stderr
    assert report["family"] == "feetech" and report["supply_voltage"] == 12.0
    chosen = {j["servo"] for j in report["joints"].values()}
    assert chosen <= {"STS3215-C018", "STS3250"}, chosen
    assert report["servo_mass_kg"] == pytest.approx(sum(part_mass(j["servo"]) for j in report["joints"].values()),
                                                    abs=1e-9)
    assert report["servo_mass_kg"] == pytest.approx(6 * 0.055, abs=1e-9)   # parts.toml: 55 g a servo
    config = tomllib.loads((tmp_path / "config.toml").read_text())
    assert {b["kind"] for b in config["bus"].values()} == {"feetech"} and config["supply"]["voltage"] == 12.0
    check = run_cli("validate", tmp_path / "config.toml", "so101_pick", "--out", tmp_path / "validate", timeout=600)
    assert check.returncode == 0, check.stdout[-2000:]
