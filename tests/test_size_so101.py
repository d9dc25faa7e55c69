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
    """The SO-101's 5 V supply (--supply-voltage 5): shoulder_lift is the joint nothing passes at, its
    STS3215-C001 over its torque-speed envelope (1.34 measured, with the 20 % reserve: validate's 1.14
    at margin 1 on the built-in configuration, whose URDF masses hold the servos already); exit 1."""
    done, report = _size(tmp_path, "--supply-voltage", "5")
    assert done.returncode == 1 and not report["passed"]
    assert report["failure"]["dof"] == "shoulder_lift" and report["joints"]["shoulder_lift"]["servo"] is None
    lift = {c["servo"]: c for c in report["joints"]["shoulder_lift"]["candidates"]}
    assert lift["STS3215-C001"]["worst_check"] == "torque_speed"
    assert lift["STS3215-C001"]["worst_ratio"] == pytest.approx(1.34, abs=0.05)


@pytest.fixture(scope="module")
def sized(tmp_path_factory):
    out = tmp_path_factory.mktemp("size")
    done = run_cli("size", "so101", "--motion", "so101_pick", "--out", out, "--yes", timeout=600)
    return out, done, json.loads((out / "size.json").read_text())


def test_the_default_sizing_names_the_5_v_overload(sized):
    """Without --supply-voltage the configuration's 5 V is tried beside the family's 7.4 and 12 V:
    the printout names the shoulder_lift overload there, and the 7.4 V set of other gearings."""
    _, done, report = sized
    at = {v["voltage"]: v for v in report["by_voltage"]}
    assert set(at) == {5.0, 7.4, 12.0}
    assert not at[5.0]["passed"] and at[5.0]["failed_dof"] == "shoulder_lift"
    assert all(c["worst_ratio"] > 1.0 for c in at[5.0]["candidates"])
    assert at[7.4]["passed"] and sorted(at[7.4]["choice"].values()) == ["STS3215-C044"] * 3 + ["STS3215-C046"] * 3
    assert "at 5 V none passes: shoulder_lift" in done.stdout and "STS3215-C001 τ-ω 1.34" in done.stdout


def test_sized_set_passes_with_its_bill(sized, tmp_path):
    """At its best supply (12 V: the 5-7.4 V gearings cannot run there) a set passes, one supply and
    one Feetech bus; its bill is six servos of 55 g; `servodyn validate` passes the written files."""
    out, done, report = sized
    assert done.returncode == 0 and report["passed"], done.stderr
    assert report["family"] == "feetech" and report["supply_voltage"] == 12.0
    assert set(report["bill"]) <= {"STS3215-C018", "STS3250"} and sum(report["bill"].values()) == 6
    assert report["servo_mass_kg"] == pytest.approx(sum(part_mass(j["servo"]) for j in report["joints"].values()),
                                                    abs=1e-9)
    assert report["servo_mass_kg"] == pytest.approx(6 * 0.055, abs=1e-9)   # parts.toml: 55 g a servo
    lift = {c["servo"]: c["worst_ratio"] for c in report["joints"]["shoulder_lift"]["candidates"]}
    assert lift["STS3250"] == pytest.approx(0.44, abs=0.02)                # within the default margin, 0.8
    assert lift["STS3215-C018"] == pytest.approx(0.75, abs=0.02)           # passes too, less reserve
    config = tomllib.loads((out / "config.toml").read_text())
    assert {b["kind"] for b in config["bus"].values()} == {"feetech"} and config["supply"]["voltage"] == 12.0
    check = run_cli("validate", out / "config.toml", "so101_pick", "--out", tmp_path / "validate", timeout=600)
    assert check.returncode == 0, check.stdout[-2000:]
