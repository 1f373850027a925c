"""rt2 train: targets from boxes, patches that match inference, a tiny run that learns, determinism, bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from harness.cli import main
from harness.experiments.detector.coco import LabelledImage, read_coco
from harness.experiments.detector.train import (
    TrainOptions,
    _pad,
    _patches,
    ball_colour,
    load_image,
    pixel_targets,
    select_ball_colour,
    split_groups,
    train,
)
from tracker import BallDetector, BallSegmentationModel, DetectorOptions
from tracker.detection.synthetic import ORANGE_RGB, WHITE_RGB, draw_disk, synthetic_scene

QUICK = TrainOptions(epochs=2, lbfgs_iters=25, random_negatives_per_image=200, hard_negatives_per_image=40, threshold_choice="split")


@pytest.fixture(scope="module")
def trained(synthetic_ball_coco):
    model, info = train(read_coco(synthetic_ball_coco(30, 0)), QUICK, progress=False, log=lambda s: None)
    return model, info


# -- smoke -------------------------------------------------------------------------------------------
def test_linear_input_also_learns(synthetic_ball_coco):
    model, info = train(read_coco(synthetic_ball_coco(30, 0)), TrainOptions(**{**QUICK.__dict__, "input_transform": "linear"}),
                        progress=False, log=lambda s: None)
    assert model.input_transform == "linear"
    assert info["val_ours"].recall >= 0.9 and info["val_ours"].outlier_rate <= 0.1


def test_smoke_tiny_run_learns_the_ball(trained):
    model, info = trained
    assert isinstance(model, BallSegmentationModel)
    assert info["n_train"] + info["n_val"] == 30 and len(info["history"]) == QUICK.epochs
    assert 0 < model.t_low < model.t_high < 1
    # fresh scenes the model never saw: the ball wins the argmax
    rng = np.random.default_rng(123)
    det = BallDetector(model, DetectorOptions(method="paper"))
    hits = 0
    for _ in range(20):
        image, centers, _ = synthetic_scene(rng, size_hw=(96, 128), diameter_px=(6, 14))
        res = det.detect(image)
        hits += len(res) == 1 and np.linalg.norm(res.uv_px[0] - centers[0]) < 1.0
    assert hits >= 19
    # and pixels of the ball colour score far above skin and white
    p = model.probability(np.array([[[245, 120, 20]] * 5] * 5, np.uint8))[2, 2]
    q = model.probability(np.array([[[205, 150, 120]] * 5] * 5, np.uint8))[2, 2]
    assert p > 0.9 and q < 0.1


# -- shapes: training sees what inference computes ---------------------------------------------------
def test_patches_times_kernel_equal_inference_logits():
    rng = np.random.default_rng(1)
    model = BallSegmentationModel(kernel=rng.normal(size=(5, 5, 3)), bias=0.3, input_scale=np.full(3, 0.01), input_offset=np.full(3, -1.0))
    image = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    rows = np.array([0, 0, 29, 15, 3, 29])
    cols = np.array([0, 39, 0, 20, 1, 39])  # corners and edges exercise the reflected border
    x = _patches(_pad(image), rows, cols).astype(np.float64) * np.tile(model.input_scale, 25) + np.tile(model.input_offset, 25)
    want = x @ model.kernel.reshape(75).astype(np.float64) + model.bias
    np.testing.assert_allclose(model.logits(image)[rows, cols], want, atol=1e-4)


def test_pixel_targets_disk_ring_background(tmp_path):
    li = LabelledImage(tmp_path / "x.png", 40, 30, np.array([[10.0, 8.0, 10.0, 10.0]]), np.array([[14.5, 12.5]]))
    t = pixel_targets(li, ring_px=1.5)
    assert t.shape == (30, 40) and t.dtype == np.int8
    assert t[12, 14] == 1 and t[13, 15] == 1  # centre of the disk (pixel (14, 12) spans [14, 15] x [12, 13])
    assert t[8, 10] == -1  # box corner: outside the inscribed disk, ignored
    assert t[12, 20] == -1  # ring just outside the box
    assert t[0, 0] == 0 and t[12, 25] == 0
    assert 60 <= (t == 1).sum() <= 80  # about pi * 4.5^2


def test_pixel_targets_core_fraction(tmp_path):
    li = LabelledImage(tmp_path / "x.png", 40, 30, np.array([[10.0, 8.0, 10.0, 10.0]]), np.array([[14.5, 12.5]]))
    full, core = pixel_targets(li, 1.5, 1.0), pixel_targets(li, 1.5, 0.6)
    assert (core == 1).sum() < (full == 1).sum() and np.all(full[core == 1] == 1)
    assert np.array_equal(core != 0, full != 0)  # the rest of the disk is ignored, not background


def test_ball_colour_and_selection(tmp_path):
    image = np.full((60, 80, 3), 60, np.uint8)
    draw_disk(image, (20.0, 30.0), 10.0, ORANGE_RGB)
    draw_disk(image, (60.0, 30.0), 10.0, WHITE_RGB)
    boxes = np.array([[15.5, 25.5, 10.0, 10.0], [55.5, 25.5, 10.0, 10.0]])
    assert [ball_colour(image, b) for b in boxes] == ["orange", "white"]
    path = tmp_path / "f000000_cam0.png"
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    li = LabelledImage(path, 80, 60, boxes, np.array([[20.0, 30.0], [60.0, 30.0]]))
    (orange,) = select_ball_colour([li], "orange")
    (white,) = select_ball_colour([li], "white")
    np.testing.assert_array_equal(orange.boxes_xywh, boxes[:1])
    np.testing.assert_array_equal(white.centers_px, [[60.0, 30.0]])
    assert select_ball_colour([li], "any")[0] is li
    with pytest.raises(ValueError, match="ball colour must be one of"):
        select_ball_colour([li], "pink")


def test_split_keeps_frame_sets_together(tmp_path):
    ims = [LabelledImage(tmp_path / f"f{f:06d}_cam{c}.png", 8, 8, np.zeros((0, 4)), np.zeros((0, 2))) for f in range(10) for c in range(4)]
    train_set, val_set = split_groups(ims, 0.2, np.random.default_rng(0))
    assert len(val_set) == 8 and len(train_set) == 32
    frames = lambda s: {p.path.stem.split("_")[0] for p in s}  # noqa: E731
    assert not frames(train_set) & frames(val_set)


# -- statistics: seeded determinism ------------------------------------------------------------------
def test_same_seed_same_model(synthetic_ball_coco, trained):
    model, _ = trained
    again, _ = train(read_coco(synthetic_ball_coco(30, 0)), QUICK, progress=False, log=lambda s: None)
    np.testing.assert_array_equal(again.kernel, model.kernel)
    assert again.bias == model.bias and again.t_high == model.t_high and again.t_low == model.t_low
    other, _ = train(read_coco(synthetic_ball_coco(30, 0)), TrainOptions(**{**QUICK.__dict__, "seed": 5}), progress=False, log=lambda s: None)
    assert not np.array_equal(other.kernel, model.kernel)


# -- command line ------------------------------------------------------------------------------------
def test_cli_writes_a_loadable_model(synthetic_ball_coco, tmp_path, capsys):
    out = tmp_path / "m.npz"
    code = main(["train", "--data", str(synthetic_ball_coco(30, 0)), "--out", str(out), "--epochs", "1", "--from", "none", "--thresholds", "split", "--learned", "off"])
    assert code == 0
    model = BallSegmentationModel.load(out)
    assert "rt2 train" in model.description and "val images" in model.description
    assert "epoch 1/1" in capsys.readouterr().out


# -- bad input ---------------------------------------------------------------------------------------
def test_cli_bad_inputs(synthetic_ball_coco, tmp_path, capsys):
    good = synthetic_ball_coco(30, 0)
    assert main(["train", "--data", str(good), "--out", str(tmp_path / "m.pt")]) == 2
    assert "--out must end in .npz" in capsys.readouterr().err
    # a COCO file naming an image that does not exist
    doc = json.loads((good / "annotations.json").read_text())
    doc["images"][0]["file_name"] = "missing.png"
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    assert main(["train", "--data", str(tmp_path / "bad.json"), "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and "missing.png" in err
    # a box outside the image
    doc = json.loads((good / "annotations.json").read_text())
    doc["annotations"][0]["bbox"] = [120.0, 90.0, 20.0, 20.0]
    for im in doc["images"]:  # file names stay inside the data folder (absolute ones are refused)
        (tmp_path / im["file_name"]).symlink_to(good / im["file_name"])
    (tmp_path / "outside.json").write_text(json.dumps(doc))
    assert main(["train", "--data", str(tmp_path / "outside.json"), "--out", str(tmp_path / "m.npz")]) == 2
    assert "bbox" in capsys.readouterr().err


def test_image_size_mismatch_and_unreadable(tmp_path):
    path = tmp_path / "a.png"
    cv2.imwrite(str(path), np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(ValueError, match=r"a\.png: image is 12x10 but its COCO entry says width=20, height=10"):
        load_image(LabelledImage(path, 20, 10, np.zeros((0, 4)), np.zeros((0, 2))))
    bad = tmp_path / "b.png"
    bad.write_bytes(b"garbage")
    with pytest.raises(ValueError, match=r"b\.png: cannot read the image"):
        load_image(LabelledImage(bad, 20, 10, np.zeros((0, 4)), np.zeros((0, 2))))


def test_no_balls_refused(tmp_path):
    ims = []
    for f in range(4):
        path = tmp_path / f"f{f:06d}_cam0.png"
        cv2.imwrite(str(path), np.zeros((8, 8, 3), np.uint8))
        ims.append(LabelledImage(path, 8, 8, np.zeros((0, 4)), np.zeros((0, 2))))
    with pytest.raises(ValueError, match="no ball boxes among the 3 training images"):
        train(ims, QUICK, progress=False)
    with pytest.raises(ValueError, match="val_fraction"):
        TrainOptions(val_fraction=1.5)
    with pytest.raises(ValueError, match="ball_colour must be one of"):
        TrainOptions(ball_colour="pink")
    with pytest.raises(ValueError, match="input_transform must be one of"):
        TrainOptions(input_transform="sqrt")
    with pytest.raises(ValueError, match="hard_weight"):
        TrainOptions(hard_weight=1.0)
