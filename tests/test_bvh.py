"""BVH files (servodyn.mocap.bvh) and `servodyn mocap info`: every rotation order read as intrinsic
in channel order, 6-channel joints, End Sites, CRLF, a header's frame count that lies, and bad
input as one line with exit status 2. The real clips are Debian's assimp-testmodels (make test
installs it)."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from servodyn.mocap.bvh import BvhError, format_bvh, parse_bvh, read_bvh
from servodyn.mocap.export import ORDERS
from servodyn.tools.cli import main

CLIPS = Path("/usr/share/assimp/models/BVH")
needs_clips = pytest.mark.skipif(not (CLIPS / "01_01.bvh").exists(),
                                 reason="assimp-testmodels not installed (make test installs it)")


def small_bvh(order="ZXY", root_channels=6, frames=((1, 2, 3, 10, -20, 30, 5, 6, 7, 40, -50, 60),), declared=None,
              end_site=True, mid_six=True, newline="\n", frame_time="0.0083333"):
    """A root with `root_channels`, a child with 6 channels (when mid_six) or 3, an End Site."""
    rot = " ".join(f"{a}rotation" for a in order)
    root = f"CHANNELS 6 Xposition Yposition Zposition {rot}" if root_channels == 6 else f"CHANNELS 3 {rot}"
    child = f"CHANNELS 6 Xposition Yposition Zposition {rot}" if mid_six else f"CHANNELS 3 {rot}"
    lines = ["HIERARCHY", "ROOT Hips", "{", "\tOFFSET 0 0 0", f"\t{root}", "\tJOINT Arm", "\t{",
             "\t\tOFFSET 0.5 -1.25 2", f"\t\t{child}"]
    if end_site:
        lines += ["\t\tEnd Site", "\t\t{", "\t\t\tOFFSET 0 -3 0", "\t\t}"]
    lines += ["\t}", "}", "MOTION", f"Frames: {len(frames) if declared is None else declared}",
              f"Frame Time: {frame_time}"]
    lines += [" ".join(str(v) for v in row) for row in frames]
    return newline.join(lines) + newline


@pytest.mark.parametrize("order", ORDERS)
def test_every_rotation_order_is_intrinsic_in_channel_order(order):
    """The joint's rotation from its channels equals scipy's intrinsic rotation in that order (an
    independent implementation) to 1e-12, and differs from the extrinsic one by far more: a reader
    that ignored the order or composed it the other way would fail."""
    angles = {"X": 37.0, "Y": -52.0, "Z": 71.0}
    row = [0, 0, 0] + [angles[a] for a in order] + [0, 0, 0] + [angles[a] for a in order]
    clip = parse_bvh(small_bvh(order, frames=(row,)))
    expected = Rotation.from_euler(order, [angles[a] for a in order], degrees=True).as_matrix()
    for joint in (0, 1):
        R = clip.local_rotations(joint)[0]
        assert np.abs(R - expected).max() < 1e-12, f"{order}: intrinsic in channel order"
    extrinsic = Rotation.from_euler(order.lower(), [angles[a] for a in order], degrees=True).as_matrix()
    assert np.abs(extrinsic - expected).max() > 0.1, "the two conventions differ for these angles"


def test_six_channel_joints_and_end_sites_are_read_and_written_back():
    """A 6-channel child joint: its rotation comes from its rotation columns, not its position
    columns; the End Site's offset is kept; writing and reading again gives the same numbers at
    6 decimals (1e-6)."""
    row = (1.5, 2, 3, 10, -20, 30, 5, 6, 7, 40, -50, 60)
    clip = parse_bvh(small_bvh("YXZ", frames=(row, row)))
    assert [len(j.channels) for j in clip.joints] == [6, 6], "both joints have 6 channels"
    assert clip.joints[1].column == 6, "the child's channels start after the root's 6"
    expected = Rotation.from_euler("YXZ", [40, -50, 60], degrees=True).as_matrix()
    assert np.abs(clip.local_rotations(1)[0] - expected).max() < 1e-12, "rotation columns 9-11"
    assert np.allclose(clip.joints[1].end_site, [0, -3, 0], atol=0), "End Site offset as written"
    again = parse_bvh(format_bvh(clip, 6))
    assert np.abs(again.motion - clip.motion).max() < 1e-6, "6 decimals"
    assert np.abs(again.joints[1].offset - [0.5, -1.25, 2]).max() < 1e-6, "offsets at 6 decimals"
    assert [j.order for j in again.joints] == ["YXZ", "YXZ"] and again.joints[1].end_site is not None
    assert abs(again.frame_time - 0.0083333) < 1e-9, "frame time kept"


def test_crlf_and_lf_files_read_the_same():
    rows = [(0, 0, 0, i, 2 * i, 3 * i, 0, 0, 0, -i, i, 0) for i in range(4)]
    lf = parse_bvh(small_bvh(frames=rows))
    crlf = parse_bvh(small_bvh(frames=rows, newline="\r\n"))
    assert np.array_equal(lf.motion, crlf.motion) and lf.frames == crlf.frames == 4, "CRLF line ends"
    assert lf.warnings == crlf.warnings == [], "no warnings for a well-formed file"


def test_a_header_that_declares_one_frame_too_few_reads_all_with_a_warning():
    """Boxing_Toes declares 3069 frames above 3070: all read, one warning."""
    rows = [(0, 0, 0, i, 0, 0, 0, 0, 0, 0, 0, 0) for i in range(5)]
    clip = parse_bvh(small_bvh(frames=rows, declared=4))
    assert clip.frames == 5, "the five present"
    assert len(clip.warnings) == 1 and "declares 4" in clip.warnings[0] and "holds 5" in clip.warnings[0]


def test_a_header_that_declares_more_frames_than_present_reads_those_with_a_warning():
    rows = [(0, 0, 0, i, 0, 0, 0, 0, 0, 0, 0, 0) for i in range(3)]
    clip = parse_bvh(small_bvh(frames=rows, declared=10))
    assert clip.frames == 3, "the three present"
    assert len(clip.warnings) == 1 and "declares 10" in clip.warnings[0] and "cut short" in clip.warnings[0]


BAD = {
    "nan": (lambda: small_bvh(frames=[(0, 0, 0, 1, 2, 3, 0, 0, 0, 1, 2, 3), (0, 0, 0, 1, "nan", 3, 0, 0, 0, 1, 2, 3)]),
            ["line 20", "frame 2", "not a finite number"]),
    "inf": (lambda: small_bvh(frames=[(0, 0, 0, 1, 2, 3, 0, 0, 0, 1, 2, "inf")]), ["line 19", "not a finite"]),
    "short row": (lambda: small_bvh(frames=[(0, 0, 0, 1, 2, 3, 0, 0, 0, 1, 2)]), ["line 19", "11 values", "12 channels"]),
    "word in a row": (lambda: small_bvh(frames=[(0, 0, 0, 1, "x", 3, 0, 0, 0, 1, 2, 3)]), ["line 19", "'x' is not a number"]),
    "unknown channel": (lambda: small_bvh().replace("Yrotation", "Wrotation", 1), ["line 5", "unknown channel 'Wrotation'"]),
    "bad offset": (lambda: small_bvh().replace("OFFSET 0.5 -1.25 2", "OFFSET 0.5 -1.25"), ["line 8", "OFFSET x y z"]),
    "nan offset": (lambda: small_bvh().replace("OFFSET 0.5 -1.25 2", "OFFSET 0.5 nan 2"), ["line 8", "finite"]),
    "channel count": (lambda: small_bvh().replace("CHANNELS 6 X", "CHANNELS 5 X", 1), ["line 5", "CHANNELS 5"]),
    "zero frame time": (lambda: small_bvh(frame_time="0"), ["line 18", "positive number of seconds"]),
    "no frames": (lambda: small_bvh(frames=[]), ["Frames: 0"]),
    "ends in hierarchy": (lambda: small_bvh().split("MOTION")[0].rsplit("}", 1)[0], ["ends inside the hierarchy"]),
    "not bvh": (lambda: "hello\n", ["line 1", "expected 'HIERARCHY'"]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_one_line_naming_the_line_and_exit_status_2(tmp_path, capsys, case):
    make, words = BAD[case]
    path = tmp_path / "bad.bvh"
    path.write_text(make())
    assert main(["mocap", "info", str(path)]) == 2, "bad input: exit status 2"
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("servodyn: error: "), f"one line, got {err!r}"
    for word in words:
        assert word in err, f"{word!r} in {err!r}"
    with pytest.raises(BvhError):
        read_bvh(path)


def test_a_missing_file_is_one_line(tmp_path, capsys):
    assert main(["mocap", "info", str(tmp_path / "none.bvh")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot read" in err


@needs_clips
def test_info_on_the_cmu_clip(capsys):
    """01_01 (cgspeed): 31 joints all ZYX, 2752 frames at 120 Hz, the CMU unit from its height
    (25.65 units = 1.45 m), Y up and Z forward, frame 0 a T-pose, both arms by the CMU table."""
    assert main(["mocap", "info", str(CLIPS / "01_01.bvh"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["frames"] == 2752 and abs(d["rate_hz"] - 120) < 1e-2, "120 Hz (Frame Time .0083333)"
    assert abs(d["duration_s"] - 2751 / 120) < 0.01, "22.9 s"
    assert {j["order"] for j in d["joints"] if j["order"]} == {"ZYX"}, "CMU: ZYX everywhere"
    assert [j["name"] for j in d["joints"] if j["channels"] == 6] == ["Hips"], "the root has 6 channels"
    assert d["unit"]["guessed"] == "cmu" and abs(d["unit"]["height_m"] - 1.45) < 0.01, "25.65 x 0.056444 m"
    assert (d["up"], d["forward"]) == ("+Y", "+Z")
    assert d["rest_frame"]["frame0_is_rest"] and d["rest_frame"]["first_step_deg"] > 20, "frame 0 is a T-pose"
    assert d["arms"]["right"]["upper_arm"] == "RightArm" and d["arms"]["right"]["clavicle"] == "RightShoulder"
    assert d["arms"]["left"]["source"] == "CMU (cgspeed)" and d["warnings"] == []


@needs_clips
def test_info_on_the_boxing_clip_warns_of_its_frame_count(capsys):
    """Boxing_Toes: ZXY, cm (173 units tall), 'RightShoulder' is its humerus (the Xsens table),
    and it declares 3069 frames above 3070."""
    assert main(["mocap", "info", str(CLIPS / "Boxing_Toes.bvh")]) == 0
    printed = capsys.readouterr()
    out = printed.out
    assert "3070 frames at 100 Hz" in out and "unit: cm" in out and "ZXY" in out
    assert "upper arm RightShoulder, forearm RightElbow, hand RightWrist" in out, "Xsens names"
    # a warning: on whichever stream the command puts its warnings
    assert "the header declares 3069 frames, the file holds 3070" in printed.out + printed.err


def test_a_name_map_finds_an_arm_the_tables_do_not(tmp_path, capsys):
    """Joints named otherwise: no table matches (exit 2, the hint names --map); a map does."""
    text = small_bvh(frames=[(0,) * 12]).replace("Hips", "Torso").replace("JOINT Arm", "JOINT Humerus")
    text = text.replace("\t\tEnd Site", "\t\tJOINT Radius\n\t\t{\n\t\t\tOFFSET 0 -3 0\n\t\t\tCHANNELS 3 Zrotation "
                        "Xrotation Yrotation\n\t\t\tJOINT Carpus\n\t\t\t{\n\t\t\t\tOFFSET 0 -2 0\n\t\t\t\tCHANNELS 3 "
                        "Zrotation Xrotation Yrotation\n\t\t\t\tEnd Site\n\t\t\t\t{\n\t\t\t\t\tOFFSET 0 -1 0\n\t\t\t\t}"
                        "\n\t\t\t}\n\t\t}\n\t\tEnd Site", 1)
    text = text.replace("\n0 0 0 0 0 0 0 0 0 0 0 0\n", "\n" + " ".join(["0"] * 18) + "\n")
    path = tmp_path / "odd.bvh"
    path.write_text(text)
    assert main(["mocap", "info", str(path)]) == 2
    assert "--map" in capsys.readouterr().err, "the error says how to name the joints"
    names = tmp_path / "map.toml"
    names.write_text('[right]\nthorax = "Torso"\nupper_arm = "Humerus"\nforearm = "Radius"\nhand = "Carpus"\n')
    assert main(["mocap", "info", str(path), "--map", str(names), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["arms"]["right"]["forearm"] == "Radius" and d["arms"]["right"]["clavicle"] is None
