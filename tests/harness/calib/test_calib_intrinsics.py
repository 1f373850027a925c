"""ChArUco intrinsics (tracker.calibration, `rt2 calib intrinsics`): rendered boards with exact truth, the
real caliscope videos (github.com/mprib/caliscope, BSD-2-Clause), bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from harness.calib.inputs import load_board
from harness.calib.rendered import random_board_poses, render_board_view
from harness.cli import main
from tracker import Camera, Rig
from tracker.calibration import BoardSpec, IntrinsicsOptions, board_from_dict, calibrate_intrinsics, detect_charuco

SPEC = BoardSpec(9, 7, 0.03, 0.022, "DICT_4X4_50")
CAM = Camera("wide", [[600.0, 0, 318.0], [0, 602.0, 243.0], [0, 0, 1]], [-0.2, 0.06, 0.0005, -0.0003, 0.0],
             np.eye(3), np.zeros(3), (640, 480))


def rendered_views(n_views, seed, camera=CAM):
    rng = np.random.default_rng(seed)
    bg = np.full((camera.image_size[1], camera.image_size[0], 3), 110, np.uint8)
    poses = random_board_poses(camera, SPEC, n_views, rng)
    return [render_board_view(camera, bg, SPEC, R, t, rng) for R, t in poses]


@pytest.fixture(scope="module")
def board_images(tmp_path_factory):
    folder = tmp_path_factory.mktemp("board")
    for k, img in enumerate(rendered_views(16, seed=0)):
        cv2.imwrite(str(folder / f"view_{k:03d}.png"), img[..., ::-1])
    (folder.parent / "board.yaml").write_text("columns: 9\nrows: 7\nsquare_m: 0.03\nmarker_m: 0.022\ndictionary: DICT_4X4_50\n")
    return folder


# -- rendered boards: exact truth --------------------------------------------------------------------
def test_rendered_corners_are_the_projected_board_corners():
    rng = np.random.default_rng(1)
    bg = np.full((480, 640, 3), 110, np.uint8)
    R, t = random_board_poses(CAM, SPEC, 5, rng, width_frac=(0.5, 0.6))[4]  # the centre cell's view
    found = detect_charuco(render_board_view(CAM, bg, SPEC, R, t, rng), SPEC)
    err = np.linalg.norm(found.uv - CAM.project(SPEC.corners_board_m[found.ids] @ R.T + t), axis=1)
    assert len(found) >= 40
    assert np.median(err) < 0.1 and err.max() < 0.3


def test_cli_recovers_rendered_camera(board_images, tmp_path, capsys):
    out = tmp_path / "cam.yaml"
    code = main(["calib", "intrinsics", "--images", str(board_images), "--board", str(board_images.parent / "board.yaml"),
                 "--out", str(out), "--fix-k3", "--name", "wide"])
    text = capsys.readouterr().out
    assert code == 0 and "coverage" in text
    cam = Rig.load(out)["wide"]
    assert abs(cam.K[0, 0] / CAM.K[0, 0] - 1) < 0.003 and abs(cam.K[1, 1] / CAM.K[1, 1] - 1) < 0.003
    assert np.hypot(*(cam.K[:2, 2] - CAM.K[:2, 2])) < 1.0
    rep = json.loads(out.with_suffix(".report.json").read_text())
    assert rep["rms_px"] < 0.3 and rep["views_used"] == 16 and rep["std"]["fx"] > 0


def test_rational_model_and_rejection_of_a_bad_view():
    views = [detect_charuco(img, SPEC) for img in rendered_views(12, seed=2)]
    bad = views[3]
    views[3] = type(bad)(bad.ids, bad.uv + np.random.default_rng(0).normal(0, 4.0, bad.uv.shape), bad.n_markers)
    res = calibrate_intrinsics(views, SPEC, (640, 480), IntrinsicsOptions(model="rational_polynomial"))
    assert len(res.distortion) == 8
    assert not res.kept[3] and "RMS" in res.rejected[3]
    assert abs(res.K[0, 0] / CAM.K[0, 0] - 1) < 0.01


# -- bad input ----------------------------------------------------------------------------------------
def test_wrong_board_spec_is_named_and_nothing_written(board_images, tmp_path, capsys):
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("columns: 9\nrows: 7\nsquare_m: 0.03\nmarker_m: 0.022\ndictionary: DICT_5X5_100\n")
    out = tmp_path / "cam.yaml"
    code = main(["calib", "intrinsics", "--images", str(board_images), "--board", str(wrong), "--out", str(out), "--mirror", "no"])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert "0 usable board views of 16 images" in err and "view_000" not in err


@pytest.mark.parametrize("damage", ["truncated_jpeg", "jpeg_cut_in_header", "not_an_image", "empty"])
def test_a_damaged_image_is_named_and_nothing_written(board_images, tmp_path, capsys, damage):
    """A JPEG cut short decodes in OpenCV with its missing part grey and only a warning: it is named, never used."""
    import shutil

    folder = tmp_path / "imgs"
    shutil.copytree(board_images, folder)
    img = cv2.imread(str(folder / "view_003.png"))
    ok, jpg = cv2.imencode(".jpg", img)
    data = jpg.tobytes()
    bad = folder / "view_003b.jpg"
    bad.write_bytes({"truncated_jpeg": data[: len(data) * 2 // 3], "jpeg_cut_in_header": data[:300],
                     "not_an_image": b"hello", "empty": b""}[damage])
    out = tmp_path / "cam.yaml"
    code = main(["calib", "intrinsics", "--images", str(folder), "--board", str(board_images.parent / "board.yaml"),
                 "--out", str(out), "--fix-k3"])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists(), err
    assert "view_003b.jpg" in err and len(err.strip().splitlines()) == 1, err
    if damage.startswith("truncated"):
        assert "truncated JPEG" in err


def test_an_intact_jpeg_is_read(board_images, tmp_path):
    from harness.calib.inputs import read_image

    img = cv2.imread(str(board_images / "view_003.png"))
    ok, jpg = cv2.imencode(".jpg", img)
    (tmp_path / "a.jpg").write_bytes(jpg.tobytes() + b"\x00\x00")  # some cameras pad after the end marker
    assert read_image(tmp_path / "a.jpg").shape == img.shape


def test_too_few_views_and_bad_specs():
    views = [detect_charuco(img, SPEC) for img in rendered_views(3, seed=3)]
    with pytest.raises(ValueError, match="camera7: 3 usable board views of 3 images, need >= 5"):
        calibrate_intrinsics(views, SPEC, (640, 480), camera="camera7")
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        BoardSpec(5, 5, 0.03, 0.02, "DICT_9X9_1")
    with pytest.raises(ValueError, match="marker_m"):
        BoardSpec(5, 5, 0.03, 0.04)
    with pytest.raises(ValueError, match="missing field 'rows'"):
        board_from_dict({"columns": 4})


# -- real data: caliscope ----------------------------------------------------------------------------
def test_caliscope_board_spec(real_data):
    spec = load_board(real_data / "caliscope_4cam" / "charuco.toml")
    assert spec.columns == 4 and spec.rows == 5 and spec.inverted
    assert spec.square_m == pytest.approx(0.054) and spec.marker_m == pytest.approx(0.0405)


def test_caliscope_real_video_cam0(real_data, tmp_path, capsys):
    """Every 2nd frame of the real cam_0 video: sub-pixel RMS, and K near caliscope's own result."""
    import tomllib

    root = real_data / "caliscope_4cam"
    out = tmp_path / "cam_0.yaml"
    code = main(["calib", "intrinsics", "--images", str(root / "calibration" / "extrinsic" / "cam_0.mp4"),
                 "--board", str(root / "charuco.toml"), "--out", str(out), "--every", "2", "--fix-k3"])
    assert code == 0, capsys.readouterr().err
    rep = json.loads(out.with_suffix(".report.json").read_text())
    assert rep["rms_px"] < 0.5 and rep["views_used"] >= 15 and not rep["mirrored"]
    ref = np.array(tomllib.loads((root / "camera_array.toml").read_text())["cameras"]["0"]["matrix"])
    K = np.array(rep["K"])
    assert abs(K[0, 0] / ref[0, 0] - 1) < 0.03 and np.hypot(*(K[:2, 2] - ref[:2, 2])) < 25
