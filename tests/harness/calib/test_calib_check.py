"""`rt2 calib check`: calibration from rendered data against the true rig (minutes: slow)."""

from __future__ import annotations

import json

import pytest

from harness.cli import main


@pytest.mark.slow
def test_rendered_lab4_vga_check(tmp_path):
    """A small run (40 board views per camera, 120 wand frame sets; the README's run has 60 and 300): focal length
    within 0.3 %, principal point within 3 px, camera centres within 15 mm and rotations within 0.2 deg of the truth
    (with 20 views a principal point was 6 px off: narrow lenses need many views)."""
    code = main(["calib", "check", "--rig", "lab4_vga", "--board-views", "40", "--wand-frames", "120", "--out", str(tmp_path)])
    assert code == 0
    res = json.loads((tmp_path / "check.json").read_text())
    wi, we = res["intrinsics"]["vs_truth"]["worst"], res["extrinsics_vs_truth"]["worst"]
    assert wi["focal_pct"] < 0.3 and wi["principal_px"] < 3.0
    assert we["centre_mm"] < 15 and we["rotation_deg"] < 0.2


def test_check_refuses_tiny_runs(tmp_path, capsys):
    code = main(["calib", "check", "--board-views", "3", "--out", str(tmp_path / "x")])
    assert code == 2 and "--board-views must be >= 10" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
