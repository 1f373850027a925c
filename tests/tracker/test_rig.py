"""Rig: our YAML format, OpenCV FileStorage import (real ewand files), bad input naming file and field."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from tests.tracker.test_camera import make_camera
from tracker import Rig


def small_rig():
    cams = [make_camera(name="a"), make_camera(name="b", dist=(0.1, -0.05, 0.0, 0.0, 0.01, 0.2, 0.0, 0.0))]
    return Rig(cams, workspace_m=[[-1, -1, 0.5], [1, 1, 2]], description="test rig")


# -- our format -------------------------------------------------------------------------------------
def test_save_load_roundtrip(tmp_path):
    rig = small_rig()
    rig.save(tmp_path / "rig.yaml")
    back = Rig.load(tmp_path / "rig.yaml")
    assert back.names == ["a", "b"]
    assert back.description == "test rig"
    assert np.array_equal(back.workspace_m, rig.workspace_m)
    for k, v in rig.stacked().items():
        assert np.array_equal(back.stacked()[k], v), k
    assert back["b"].distortion_model == "rational_polynomial"


def test_indexing_and_unknown_camera():
    rig = small_rig()
    assert rig["b"] is rig[1]
    assert rig.index("a") == 0
    with pytest.raises(ValueError, match=r"unknown camera 'zz'; this rig has \['a', 'b'\]"):
        rig["zz"]
    assert rig.subset(["b"]).names == ["b"]


def test_project_shapes():
    rig = small_rig()
    X = np.array([[0.1, 0.2, 1.0], [0.0, 0.0, 1.2]])
    assert rig.project(X).shape == (2, 2, 2)
    assert rig.project(X[0]).shape == (2, 2)
    assert np.allclose(rig.project(X)[1], rig["b"].project(X))


def test_duplicate_names_rejected():
    with pytest.raises(ValueError, match=r"repeated: \['a'\]"):
        Rig([make_camera(name="a"), make_camera(name="a")])


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda d: d.pop("format"), "field 'format' must be 'rt2.rig'"),
        (lambda d: d.update(version=7), "field 'version' must be 1"),
        (lambda d: d.update(cameras=[]), "field 'cameras' must be a non-empty list"),
        (lambda d: d["cameras"][1].pop("K"), r"cameras\[1\]: missing field 'K'"),
        (lambda d: d["cameras"][0].update(K=[[0, 0, 1], [0, 600, 1], [0, 0, 1]]), r"cameras\[0\]: camera 'a': focal lengths"),
        (lambda d: d["cameras"][0].update(K=[[600, 0, 1], [0, 600, 1]]), r"cameras\[0\]: camera 'a': K must have shape \(3, 3\)"),
        (lambda d: d["cameras"][0]["distortion"].update(model="fisheye"), "unknown distortion model 'fisheye'"),
        (lambda d: d["cameras"][0].update(R_world_to_cam=[[1, 0, 0], [0, 2, 0], [0, 0, 1]]), "not orthonormal"),
        (lambda d: d.update(workspace_m={"min": [0, 0, 0]}), "field 'workspace_m' must be"),
        (lambda d: d.update(workspace_m={"min": [0, 0, 0], "max": [1, -1, 1]}), "min < max"),
    ],
)
def test_bad_rig_files_name_file_and_field(tmp_path, mutate, match):
    data = small_rig().to_dict()
    mutate(data)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ValueError, match=match) as err:
        Rig.load(path)
    assert str(path) in str(err.value)


def test_unreadable_and_invalid_yaml(tmp_path):
    with pytest.raises(ValueError, match="cannot read rig file"):
        Rig.load(tmp_path / "missing.yaml")
    (tmp_path / "broken.yaml").write_text("cameras: [unclosed\n")
    with pytest.raises(ValueError, match="broken.yaml: not valid YAML"):
        Rig.load(tmp_path / "broken.yaml")


# -- OpenCV FileStorage import on the real ewand calibration ------------------------------------------
def test_real_ewand_files_import(ewand_rig, ewand_dir):
    assert len(ewand_rig) == 4
    cam0 = ewand_rig[0]
    assert cam0.image_size == (1280, 1024)
    assert cam0.distortion_model == "plumb_bob"
    assert np.allclose(cam0.center_world, 0.0)  # camera 0 is the world frame
    # millimetres became metres: camera 1's centre lies a few metres away, as in the file.
    ext = yaml.safe_load("\n".join((ewand_dir / "frame_1.yaml").read_text().splitlines()[1:]).replace("!!opencv-matrix", ""))
    t_mm = np.array(ext["extrinsics"]["data"]).reshape(3, 4)[:, 3]
    assert np.allclose(ewand_rig[1].t_world_to_cam_m, t_mm / 1000.0)
    assert 1.0 < np.linalg.norm(ewand_rig[1].center_world) < 10.0


def test_real_ewand_rig_saves_and_reloads(ewand_rig, tmp_path):
    ewand_rig.save(tmp_path / "ewand.yaml")
    back = Rig.load(tmp_path / "ewand.yaml")
    X = np.array([[0.1, -0.2, 3.0]])
    assert np.allclose(back.project(X), ewand_rig.project(X), atol=1e-9)


def test_opencv_import_with_explicit_names_and_units(ewand_dir):
    paths = sorted(ewand_dir.glob("frame_*.yaml"))
    mm = Rig.from_opencv_files(paths, names=["c0", "c1", "c2", "c3"])
    m = Rig.from_opencv_files(paths, length_unit_m=1.0, names=["c0", "c1", "c2", "c3"])
    assert mm.names == ["c0", "c1", "c2", "c3"]
    assert np.allclose(m["c2"].t_world_to_cam_m, mm["c2"].t_world_to_cam_m * 1000.0)


OPENCV_TEMPLATE = """%YAML:1.0
---
camera_name: camX
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
  rows: 3
  cols: 3
  dt: d
  data: [600, 0, 320, 0, 600, 240, 0, 0, 1]
distortion_coefficients: !!opencv-matrix
  rows: 1
  cols: 5
  dt: d
  data: [-0.1, 0.01, 0, 0, 0]
extrinsics:
  rows: 3
  cols: 4
  data: [1, 0, 0, 10, 0, 1, 0, 20, 0, 0, 1, 30]
"""


def test_opencv_template_parses(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(OPENCV_TEMPLATE)
    rig = Rig.from_opencv_files([p])
    assert rig.names == ["camX"]
    assert np.allclose(rig[0].t_world_to_cam_m, [0.01, 0.02, 0.03])


@pytest.mark.parametrize(
    "old, new, match",
    [
        ("camera_matrix: !!opencv-matrix", "camera_matrixx: !!opencv-matrix", "missing field 'camera_matrix'"),
        ("  data: [600, 0, 320, 0, 600, 240, 0, 0, 1]", "  data: [600, 0, 320, 0, 600, 240]", "'camera_matrix' declares 3x3 but holds 6 values"),
        ("rows: 3\n  cols: 4", "rows: 4\n  cols: 3", "'extrinsics' must be 3x4, got 4x3"),
        ("data: [600, 0, 320, 0, 600, 240, 0, 0, 1]", "data: [-600, 0, 320, 0, 600, 240, 0, 0, 1]", "focal lengths must be positive"),
        ("data: [1, 0, 0, 10, 0, 1, 0, 20, 0, 0, 1, 30]", "data: [1, 0, 0, 10, 0, 1.5, 0, 20, 0, 0, 1, 30]", "not orthonormal"),
        ("image_height: 480\n", "", "missing field 'image_width' or 'image_height'"),
        ("  data: [-0.1, 0.01, 0, 0, 0]", "  data: [-0.1, oops, 0, 0, 0]", "'distortion_coefficients' has non-numeric data"),
        ("rows: 1\n  cols: 5", "rows: 1\n  cols: 3", "declares 1x3 but holds 5 values"),
        ("extrinsics:\n  rows: 3\n  cols: 4\n  data: [1, 0, 0, 10, 0, 1, 0, 20, 0, 0, 1, 30]\n", "extrinsics: 5\n", "'extrinsics' must be a matrix"),
    ],
)
def test_bad_opencv_files_name_file_and_field(tmp_path, old, new, match):
    assert old in OPENCV_TEMPLATE
    p = tmp_path / "cam.yaml"
    p.write_text(OPENCV_TEMPLATE.replace(old, new))
    with pytest.raises(ValueError, match=match) as err:
        Rig.from_opencv_files([p])
    assert "cam.yaml" in str(err.value)


def test_opencv_import_argument_errors(tmp_path):
    with pytest.raises(ValueError, match="at least one file"):
        Rig.from_opencv_files([])
    with pytest.raises(ValueError, match="length_unit_m must be a positive number"):
        Rig.from_opencv_files([tmp_path / "x.yaml"], length_unit_m=0)
    with pytest.raises(ValueError, match="cannot read calibration file"):
        Rig.from_opencv_files([tmp_path / "x.yaml"])
    (tmp_path / "list.yaml").write_text("%YAML:1.0\n- 1\n- 2\n")
    with pytest.raises(ValueError, match="list.yaml: expected a mapping"):
        Rig.from_opencv_files([tmp_path / "list.yaml"])
