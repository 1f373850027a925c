"""Multi-camera ChArUco extrinsics (`rt2 calib board`, tracker.calibration.board_rig) on the real caliscope
session (github.com/mprib/caliscope, BSD-2-Clause): the square size triangulated without the board model,
and caliscope's own camera_array.toml as an independent reference."""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.calib.exports import read_anipose_toml
from harness.cli import main
from tracker import Rig


def run_board(real_data, tmp_path, every):
    root = real_data / "caliscope_4cam"
    videos = [str(root / "calibration" / "extrinsic" / f"cam_{i}.mp4") for i in range(4)]
    out = tmp_path / "rig.yaml"
    code = main(["calib", "board", "--videos", *videos, "--board", str(root / "charuco.toml"), "--fix-k3", "--every", str(every),
                 "--holdout-every", "4", "--out", str(out), "--reference", str(root / "camera_array.toml"),
                 "--anipose-toml", str(tmp_path / "calibration.toml")])
    assert code == 0
    return out, json.loads(out.with_suffix(".report.json").read_text())


def test_caliscope_board_extrinsics_fast(real_data, tmp_path):
    """Every 3rd frame set (16 views per camera): the square size within 1 mm of 54 mm, poses within 5 deg of caliscope's."""
    out, rep = run_board(real_data, tmp_path, every=3)
    assert rep["mirrored"]["cam_1"] and not rep["mirrored"]["cam_0"]
    assert abs(rep["square_mm"]["median"] - 54.0) < 1.0
    for d in rep["reference"]["pairs"].values():
        assert d["rotation_deg"] < 5.0 and abs(d["baseline_m"] / d["baseline_ref_m"] - 1) < 0.08
    rig = Rig.load(out)
    back = read_anipose_toml(tmp_path / "calibration.toml")
    assert np.allclose(back.stacked()["P"], rig.stacked()["P"], atol=1e-9)


@pytest.mark.slow
def test_caliscope_board_extrinsics_all_frames(real_data, tmp_path):
    out, rep = run_board(real_data, tmp_path, every=1)
    assert abs(rep["square_mm"]["median"] - 54.0) < 0.5 and rep["square_mm"]["iqr"] < 1.0
    for d in rep["reference"]["pairs"].values():
        assert d["rotation_deg"] < 2.0 and abs(d["baseline_m"] / d["baseline_ref_m"] - 1) < 0.04


def test_board_not_seen_by_a_camera_is_named(real_data, tmp_path, capsys):
    root = real_data / "caliscope_4cam"
    wrong = tmp_path / "board.yaml"  # a board of another dictionary: no camera finds it
    wrong.write_text("columns: 4\nrows: 5\nsquare_m: 0.054\nmarker_m: 0.0405\ndictionary: DICT_6X6_250\ninverted: true\n")
    videos = [str(root / "calibration" / "extrinsic" / f"cam_{i}.mp4") for i in range(2)]
    out = tmp_path / "rig.yaml"
    code = main(["calib", "board", "--videos", *videos, "--board", str(wrong), "--every", "6", "--out", str(out)])
    assert code == 2 and not out.exists()
    assert "cam_0: 0 usable board views" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["intrinsics", "--images", "VIDEO0", "--board", "BOARD", "--out", "OUT", "--max-frames", "0"], "--max-frames must be >= 1, got 0"),
    (["intrinsics", "--images", "VIDEO0", "--board", "BOARD", "--out", "OUT", "--every", "0"], "--every must be >= 1, got 0"),
    (["board", "--videos", "VIDEO0", "VIDEO1", "--board", "BOARD", "--out", "OUT", "--holdout-every", "-1"],
     "--holdout-every must be >= 0 (0: none held out), got -1"),
    (["wand", "--recording", "VIDEO0", "--intrinsics", "BOARD", "--wand", "0.13,0.26", "--out", "OUT", "--holdout-every", "-2"],
     "--holdout-every must be >= 0 (0: none held out), got -2"),
])
def test_calib_option_values_are_one_line_and_write_nothing(real_data, tmp_path, capsys, argv, message):
    """A bad count is named by its option before a frame is calibrated: --max-frames 0 read one frame and then said it
    had too few board views, --holdout-every below 0 was taken as none held out."""
    root = real_data / "caliscope_4cam"
    names = {"VIDEO0": root / "calibration" / "extrinsic" / "cam_0.mp4", "VIDEO1": root / "calibration" / "extrinsic" / "cam_1.mp4",
             "BOARD": root / "charuco.toml", "OUT": tmp_path / "out.toml"}
    assert main(["calib", *[str(names.get(a, a)) for a in argv]]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []
