"""The full loop: the accuracy experiment's trackers get a self-made calibration (`rt2 calib loop`,
`CalibrationErrorOptions.rig_file`)."""

from __future__ import annotations

import numpy as np
import pytest

from harness.experiments.accuracy.rig_error import CalibrationErrorOptions, estimated_rig
from harness.cli import main
from tracker.rig_files import resolve_rig, rig_path
from tracker import Camera, Rig


def test_rig_file_is_given_to_the_trackers_and_its_error_measured(tmp_path):
    truth = resolve_rig("lab4_vga")
    est, info = estimated_rig(truth, CalibrationErrorOptions(rig_file=str(rig_path("lab4_vga"))), seed=0)
    assert est.names == truth.names and info["rig_file"].endswith("lab4_vga.yaml")
    assert info["reprojection_px"]["max"] < 1e-6 and info["triangulation_mm"]["max"] < 1e-6
    # a rig whose first camera is turned by 0.1 deg about its own centre: its error shows
    c = truth[0]
    turn = np.array([[1, 0, 0], [0, np.cos(0.00175), -np.sin(0.00175)], [0, np.sin(0.00175), np.cos(0.00175)]])
    turned = Camera(c.name, c.K, c.distortion, turn @ c.R_world_to_cam, turn @ c.t_world_to_cam_m, c.image_size)  # same centre
    moved = Rig([turned, *truth.cameras[1:]], workspace_m=truth.workspace_m)
    moved.save(tmp_path / "moved.yaml")
    _, info = estimated_rig(truth, CalibrationErrorOptions(rig_file=str(tmp_path / "moved.yaml")), seed=0)
    assert info["projection_shift_px"]["max"] > 1.5 and info["reprojection_px"]["mean"] > 0.05  # cam0 shifts ~2 px


def test_mismatched_rig_file_is_refused(tmp_path, capsys):
    truth = resolve_rig("lab4_vga")
    truth.subset(truth.names[:3]).save(tmp_path / "three.yaml")
    with pytest.raises(ValueError, match="do not match the true rig"):
        estimated_rig(truth, CalibrationErrorOptions(rig_file=str(tmp_path / "three.yaml")), seed=0)
    code = main(["calib", "loop", "--calibrated", str(tmp_path / "three.yaml"), "--out", str(tmp_path / "o")])
    assert code == 2 and "differ from --rig lab4_vga" in capsys.readouterr().err


@pytest.mark.slow
def test_loop_with_the_true_rig_file_gives_equal_figures(tmp_path):
    code = main(["calib", "loop", "--calibrated", str(rig_path("lab4_vga")), "--frames", "150", "--out", str(tmp_path)])
    assert code == 0
    import json

    rep = json.loads((tmp_path / "loop.json").read_text())
    assert rep["met"] and all(abs(r["ratio"] - 1) < 1e-9 for r in rep["figures"])
