"""rt2 train: targets from boxes, patches that match inference, a tiny run that learns, determinism, bad input."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest

from harness.cli import main
from harness.experiments.detector.coco import LabelledImage, read_coco
from harness.experiments.detector.scores import DetectorScores
from harness.experiments.detector.train import (
    T_HIGH_GRID,
    NoBallFoundError,
    TrainOptions,
    _Fitter,
    _net_gain,
    _pad,
    _patches,
    ball_colour,
    choose_thresholds,
    load_image,
    pixel_targets,
    colour_note,
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
    # a label that says what its ball is wins over the measure: the orange-looking first ball is white (a white ball
    # under warm light), the second is unknown and measured
    said = dataclasses.replace(li, ball_colours=("white", None))
    (white,) = select_ball_colour([said], "white")
    np.testing.assert_array_equal(white.boxes_xywh, boxes)
    assert white.ball_colours == ("white", None)
    assert select_ball_colour([said], "orange")[0].n_balls == 0
    # what was left out for its measured colour is said in one line (rt2 train logs it, rt2 eval detector prints it);
    # what a label left out is not news
    assert colour_note([li], [orange], "orange", "trained as background").startswith(
        "1 of the 2 labelled balls measure as not orange (docs/detector.md, \"Ball colour\"): trained as background;")
    assert colour_note([said], select_ball_colour([said], "orange"), "orange", "x").startswith("1 of the 2 labelled balls measure")
    assert colour_note([said], [white], "white", "x") is None
    assert colour_note([li], [li], "any", "x") is None


def test_split_keeps_frame_sets_together(tmp_path):
    ims = [LabelledImage(tmp_path / f"f{f:06d}_cam{c}.png", 8, 8, np.zeros((0, 4)), np.zeros((0, 2))) for f in range(10) for c in range(4)]
    train_set, val_set = split_groups(ims, 0.2, np.random.default_rng(0))
    assert len(val_set) == 8 and len(train_set) == 32
    frames = lambda s: {p.path.stem.split("_")[0] for p in s}  # noqa: E731
    assert not frames(train_set) & frames(val_set)


# -- the threshold choice: a choice that reports nothing is no choice -------------------------------
def _logit_images(n: int, *, ball_logit: float, distractor_in=lambda i: False, distractor_logit: float = 6.0):
    """``n`` (60, 80) validation logits: -8 everywhere, the ball (diameter 10 px) at a place that moves with the image,
    and in the images ``i`` where ``distractor_in(i)`` a disk of the ball's size at a fixed place (a static object of
    the ball's colour). Returns (logits, (centres, diameters))."""
    yy, xx = np.mgrid[0:60, 0:80] + 0.5
    logits, centres = [], []
    for i in range(n):
        c = np.array([20.0 + 3 * (i % 10), 20.0 + 2 * (i % 7)])
        lg = np.full((60, 80), -8.0, np.float32)
        lg[np.hypot(xx - c[0], yy - c[1]) <= 5] = ball_logit
        if distractor_in(i):
            lg[np.hypot(xx - 68.0, yy - 48.0) <= 5] = distractor_logit
        logits.append(lg)
        centres.append(c[None])
    return logits, (centres, [np.array([10.0])] * n)


def test_threshold_choice_finds_the_ball_when_a_static_object_outranks_it():
    # 2 images in 3 show the static object above the ball: every T_h that finds the ball has more wrong reports than
    # hits (recall 1/3, outliers 2/3), and the T_h above the object's peak reports nothing: recall - outliers = 0 - 0,
    # the best net score, the grid's end; the model written there found no ball (rt2 eval autolabel --train-held-out)
    logits, truth = _logit_images(30, ball_logit=3.0, distractor_in=lambda i: i % 3 != 0)
    t_high, t_low, area, s_ours, s_paper = choose_thresholds(logits, truth, (2.0, 400.0), QUICK)
    assert t_high < 1.0 / (1.0 + np.exp(-3.0)) and t_high < max(T_HIGH_GRID)  # below the ball's peak, not the grid's end
    assert s_ours.recall == pytest.approx(10 / 30) and s_ours.outlier_rate == pytest.approx(20 / 30)
    assert area[0] <= np.pi * 25 <= area[1]


def test_threshold_choice_without_a_static_object_is_unchanged():
    logits, truth = _logit_images(20, ball_logit=3.0)
    t_high, _, _, s_ours, _ = choose_thresholds(logits, truth, (2.0, 400.0), QUICK)
    assert s_ours.recall == 1.0 and s_ours.outlier_rate == 0.0 and t_high < 1.0 / (1.0 + np.exp(-3.0))


def test_threshold_choice_that_finds_no_ball_says_so():
    logits, truth = _logit_images(12, ball_logit=-8.0, distractor_in=lambda i: True)  # the ball is invisible to this filter
    with pytest.raises(NoBallFoundError, match=r"no threshold finds a ball: at every T_h \(0\.5-0\.999\) and T_l \(0\.02-0\.5\) "
                       r"the detector's best candidate misses all 12 held-out balls of 12 images"):
        choose_thresholds(logits, truth, (2.0, 400.0), QUICK)


def test_net_gain_ranks_finding_nothing_last():
    def scores(recall, outliers):
        return DetectorScores("ours", recall, outliers, 1.0, 1.0, n_images=50, n_balls=50)

    nothing, poor = scores(0.0, 0.0), scores(0.4, 0.45)
    assert _net_gain(poor, nothing) == np.inf and _net_gain(nothing, poor) == -np.inf
    assert _net_gain(scores(0.6, 0.1), poor) == pytest.approx(0.55)
    no_ball = DetectorScores("ours", float("nan"), 0.0, float("nan"), float("nan"), n_images=5, n_balls=0)  # nothing to find
    assert _net_gain(no_ball, no_ball) == 0.0


def test_split_training_whose_filter_finds_no_validation_ball_refuses(synthetic_ball_coco, tmp_path):
    import torch

    items = [(load_image(li), li) for li in read_coco(synthetic_ball_coco(30, 0))]
    val = []
    for i in range(4):  # validation "balls" labelled on a plain grey image: no threshold finds one
        image = np.full((96, 128, 3), (100, 100, 110), np.uint8)
        val.append((image, LabelledImage(tmp_path / f"f{100 + i:06d}_cam0.png", 128, 96, np.array([[40.0, 30.0, 10.0, 10.0]]),
                                         np.array([[45.0, 35.0]]))))
    lines = []
    fitter = _Fitter(torch, QUICK, None, np.random.default_rng(0), False)
    with pytest.raises(NoBallFoundError, match=r"misses all 4 held-out balls of 4 images \(validation split, after each of the 2 epochs\)$"):
        fitter.fit(items, val, log=lines.append)
    assert len(lines) == 2 and all("val: no threshold finds a ball" in line for line in lines)


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
@pytest.mark.parametrize("option, message", [
    (["--epochs", "0"], "--epochs must be >= 1, got 0"),
    (["--augment", "-1"], "--augment must be an integer >= 0, got -1"),
    (["--val-fraction", "1.5"], "--val-fraction must be in (0, 1), got 1.5"),
    (["--core-fraction", "0"], "--core-fraction must be in (0, 1], got 0.0"),
    (["--cv-folds", "1"], "--cv-folds must be an integer >= 2, got 1"),
    (["--learned-steps", "0", "--learned", "on"], "--learned-steps must be a positive integer, got 0"),
    (["--max-images", "0"], "--max-images must be a positive number of images, got 0"),
])
def test_cli_option_values_are_named_by_their_option_before_any_image_is_read(synthetic_ball_coco, tmp_path, capsys, option, message):
    """A wrong value is named by the option the user typed (not the TrainOptions field it fills) and before the
    images are read: a set whose images cannot be read shows which comes first."""
    import shutil

    data = tmp_path / "unreadable"
    shutil.copytree(synthetic_ball_coco(12, 3), data)
    for image in data.glob("*.png"):
        image.write_bytes(b"not a png")
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "m.npz"), *option]) == 2
    err = capsys.readouterr().err
    assert message in err and "TrainOptions" not in err and "Traceback" not in err
    assert not (tmp_path / "m.npz").exists()


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


def test_a_training_that_cannot_fit_in_memory_is_refused_before_reading_an_image(synthetic_ball_coco, tmp_path, capsys, monkeypatch):
    """The images and their augmented copies are held at once: more than the memory available is one line, exit 2,
    nothing written, before the first image is read (not a machine out of memory that kills a tracker beside it)."""
    import harness.experiments.detector.train as train_module

    data = synthetic_ball_coco(30, 0)
    per_copy = sum(li.width * li.height * 3 for li in read_coco(data))
    monkeypatch.setattr(train_module, "available_memory_bytes", lambda: 4 * per_copy)  # room for two copies' training, not four
    read = []
    monkeypatch.setattr(train_module, "load_image", lambda li: read.append(li) or pytest.fail("an image was read"))
    out = tmp_path / "m.npz"
    assert main(["train", "--data", str(data), "--out", str(out), "--augment", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "30 images" in err[0] and "3 augmented copies each need about" in err[0] and "--max-images" in err[0], err
    assert not out.exists() and not read
    train_module.check_memory(read_coco(data), 1, available=4 * per_copy)  # two copies fit: no error
    train_module.check_memory(read_coco(data), 0, available=2 * per_copy)  # the filter kept: no copies held, the images fit
    monkeypatch.setattr(train_module, "available_memory_bytes", lambda: None)
    train_module.check_memory(read_coco(data), 9)  # unknown memory (not Linux): no check


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


def test_a_colour_that_no_labelled_ball_has_is_refused_naming_it(synthetic_ball_coco, tmp_path, capsys):
    """Orange balls trained as --ball-colour white: every ball measures orange and would be background; rt2 train says
    so (it used to end in "no ball boxes among the 12 images", with 10 balls labelled)."""
    folder = synthetic_ball_coco(12, 4)
    assert main(["train", "--data", str(folder), "--ball-colour", "white", "--epochs", "1", "--out", str(tmp_path / "m.npz")]) == 2
    out, err = capsys.readouterr()
    assert "10 of the 10 labelled balls measure as not white" in out
    assert err.strip().splitlines()[-1] == ('rt2 train: error: --ball-colour white: none of the 10 labelled balls is white (by its label\'s ball_colour '
                           'or its measured colour, docs/detector.md "Ball colour"): is the ball of another colour? '
                           '(--ball-colour any keeps every ball)')
    assert not (tmp_path / "m.npz").exists()
