"""Few-label training: time-ordered subsets, augmentation, cross-validated thresholds, fine-tuning from a
model, the seed spread of ``rt2 train``, and ball-free frames for false alarms."""

from __future__ import annotations

import numpy as np
import pytest

from harness.cli import main
from harness.experiments.detector.augment import AugmentOptions, augment
from harness.experiments.detector.ballfree import ball_free, mask_balls
from harness.experiments.detector.coco import LabelledImage, read_coco
from harness.experiments.detector.subsets import parse_range, take_range, time_key, time_order
from harness.experiments.detector.train import TrainOptions, cv_folds, load_image, train
from tracker import BallSegmentationModel

QUICK_CV = TrainOptions(epochs=1, lbfgs_iters=25, random_negatives_per_image=200, hard_negatives_per_image=40,
                        threshold_choice="cv", cv_folds=3)


def _li(name, boxes=((10.0, 12.0, 8.0, 8.0),), w=64, h=48):
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    return LabelledImage(name, w, h, boxes, boxes[:, :2] + boxes[:, 2:] / 2 - 0.5)


# -- time order ----------------------------------------------------------------------------------------
def test_time_order_reads_frame_numbers_through_export_names():
    names = ["train_IMG_7_MOV-0010_jpg.rf.ab12.jpg", "test_IMG_7_MOV-0002_jpg.rf.ff00.jpg", "valid_IMG_7_MOV-0100_jpg.rf.0a.jpg",
             "train_IMG_7_MOV-0001_jpg.rf.99.jpg"]
    ordered = [li.path.name for li in time_order([_li(n) for n in names])]
    assert ordered == [names[3], names[1], names[0], names[2]]
    assert time_key("f2_cam0.png") < time_key("f10_cam0.png")
    lis = [_li(f"f{i:03d}.png") for i in (5, 1, 3, 2, 4)]
    assert [li.path.name for li in take_range(lis, "1:3")] == ["f002.png", "f003.png"]
    assert [li.path.name for li in take_range(lis, "-2:")] == ["f004.png", "f005.png"]
    assert take_range(lis, None) == lis


@pytest.mark.parametrize("text, match", [("5", "START:STOP"), ("a:b", "integer bounds"), ("1:2:3", "START:STOP"), ("", "START:STOP")])
def test_time_range_hostile(text, match):
    with pytest.raises(ValueError, match=match):
        parse_range(text)


def test_time_range_selecting_nothing_is_refused():
    with pytest.raises(ValueError, match="selects no image of the 2 given"):
        take_range([_li("a1.png"), _li("a2.png")], "5:")


# -- augmentation -------------------------------------------------------------------------------------
def _scene(rng):
    image = rng.integers(0, 60, (48, 64, 3)).astype(np.uint8)
    image[12:20, 10:18] = (250, 120, 20)
    return image, _li("x.png")


def test_augment_is_seeded_and_moves_boxes_with_the_image():
    image, li = _scene(np.random.default_rng(0))
    a1, l1 = augment(image, li, np.random.default_rng(3))
    a2, l2 = augment(image, li, np.random.default_rng(3))
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(l1.boxes_xywh, l2.boxes_xywh)
    assert (l1.width, l1.height) == (a1.shape[1], a1.shape[0])
    # geometry only (no colour change): the ball's pixels sit where the box says, after scale and flip
    geo = AugmentOptions(wb_range=(1, 1), exposure_range=(1, 1), gamma_range=(1, 1), p_lamp=0, motion_blur_px=0, defocus_sigma_px=0,
                         noise_dn=0, p_jpeg=0, p_flip=1.0, scale_range=(1.5, 1.5))
    out, lo = augment(image, li, np.random.default_rng(1), geo)
    assert out.shape == (72, 96, 3)
    x, y, w, h = lo.boxes_xywh[0]
    assert (x, y, w, h) == pytest.approx((96 - 1.5 * 18, 18.0, 12.0, 12.0))
    u, v = lo.centers_px[0]
    assert out[int(round(v)), int(round(u)), 0] > 200 and out[int(round(v)), int(round(u)), 2] < 60
    np.testing.assert_allclose(lo.centers_px[0], lo.boxes_xywh[0, :2] + lo.boxes_xywh[0, 2:] / 2 - 0.5, atol=1e-9)


@pytest.mark.parametrize("kw, match", [(dict(scale_range=(0, 1)), "scale_range"), (dict(p_flip=2.0), "p_flip"),
                                        (dict(noise_dn=-1), "noise_dn"), (dict(jpeg_quality=(90, 10)), "jpeg_quality")])
def test_augment_options_hostile(kw, match):
    with pytest.raises(ValueError, match=match):
        AugmentOptions(**kw)


# -- ball-free frames ---------------------------------------------------------------------------------
def test_mask_balls_paints_out_the_box_only():
    image, li = _scene(np.random.default_rng(0))
    out, empty = ball_free(image, li, margin_px=2)
    assert empty.n_balls == 0
    assert out[12:20, 10:18, 0].max() < 120  # the orange square is gone
    same = np.ones(image.shape[:2], bool)
    same[10:22, 8:20] = False
    np.testing.assert_array_equal(out[same], image[same])
    np.testing.assert_array_equal(mask_balls(image, np.zeros((0, 4))), image)


# -- cross-validated thresholds and fine-tuning ---------------------------------------------------------
def test_cv_folds_are_time_contiguous_frame_sets():
    lis = [_li(f"f{f:06d}_cam{c}.png") for f in range(7) for c in range(2)]
    folds = cv_folds(lis, 3)
    assert sorted(i for f in folds for i in f) == list(range(14))
    for fold in folds:  # whole frame sets, consecutive frames
        frames = sorted({int(lis[i].path.stem[1:7]) for i in fold})
        assert frames == list(range(frames[0], frames[-1] + 1))
        assert all(sum(int(lis[j].path.stem[1:7]) == f for j in fold) == 2 for f in frames)
    with pytest.raises(ValueError, match="at least 2 frame sets"):
        cv_folds([_li("f000001_cam0.png"), _li("f000001_cam1.png")], 3)


@pytest.fixture(scope="module")
def cv_trained(synthetic_ball_coco):
    return train(read_coco(synthetic_ball_coco(16, 0)), QUICK_CV, progress=False, log=lambda s: None)


def test_cv_thresholds_use_every_image_and_are_seeded(synthetic_ball_coco, cv_trained):
    model, info = cv_trained
    assert info["threshold_choice"] == "cv" and info["n_train"] == 16 and info["n_val"] == 0
    assert info["val_ours"].n_images == 16  # every image scored once, by a model that did not see it
    assert info["val_ours"].recall >= 0.8
    assert "thresholds by 3-fold cv" in model.description
    again, _ = train(read_coco(synthetic_ball_coco(16, 0)), QUICK_CV, progress=False, log=lambda s: None)
    np.testing.assert_array_equal(again.kernel, model.kernel)
    assert (again.t_high, again.t_low) == (model.t_high, model.t_low)


def test_auto_choice_is_cv_for_few_images_and_split_for_many(synthetic_ball_coco):
    from harness.experiments.detector.train import _resolve_threshold_choice

    few = read_coco(synthetic_ball_coco(16, 0))
    assert _resolve_threshold_choice(few, TrainOptions()) == "cv"
    many = few * 20
    assert _resolve_threshold_choice(many, TrainOptions()) == "split"
    assert _resolve_threshold_choice(few, TrainOptions(threshold_choice="split")) == "split"


def test_fine_tuning_starts_from_and_stays_near_the_base(synthetic_ball_coco, cv_trained):
    base, _ = cv_trained
    opts = TrainOptions(**{**QUICK_CV.__dict__, "l2": 10.0, "seed": 4, "keep_base": "never"})  # the fine-tuned filter, whatever cv says
    tuned, info = train(read_coco(synthetic_ball_coco(12, 1)), opts, progress=False, log=lambda s: None, base=base)
    np.testing.assert_array_equal(tuned.input_scale, base.input_scale)  # the base's input scaling is kept
    near = np.abs(tuned.kernel - base.kernel).max()
    scratch, _ = train(read_coco(synthetic_ball_coco(12, 1)), opts, progress=False, log=lambda s: None)
    assert near < 0.1 * np.abs(base.kernel).max()  # the prior holds it near the base
    assert np.abs(scratch.kernel).max() < 0.1 * np.abs(base.kernel).max()  # the same penalty from scratch flattens it
    assert "fine-tuned from a base model" in tuned.description


def test_augmented_copies_enter_training(synthetic_ball_coco):
    _, plain = train(read_coco(synthetic_ball_coco(12, 0)), QUICK_CV, progress=False, log=lambda s: None)
    _, aug = train(read_coco(synthetic_ball_coco(12, 0)), TrainOptions(**{**QUICK_CV.__dict__, "augment_copies": 2}), progress=False, log=lambda s: None)
    assert aug["n_neg"] > 2.5 * plain["n_neg"]


@pytest.mark.parametrize("kw, match", [(dict(threshold_choice="best"), "threshold_choice"), (dict(augment_copies=-1), "augment_copies"),
                                        (dict(cv_folds=1), "cv_folds"), (dict(augment_copies=True), "augment_copies")])
def test_train_options_hostile(kw, match):
    with pytest.raises(ValueError, match=match):
        TrainOptions(**kw)


# -- command line ---------------------------------------------------------------------------------------
def test_cli_from_model_seeds_and_time_range(synthetic_ball_coco, cv_trained, tmp_path, capsys):
    base = cv_trained[0].save(tmp_path / "base.npz")
    out = tmp_path / "tuned.npz"
    code = main(["train", "--data", str(synthetic_ball_coco(16, 0)), "--out", str(out), "--epochs", "1", "--learned", "off", "--from", str(base),
                 "--seeds", "0", "1", "--augment", "0", "--time-range", "0:12", "--cv-folds", "3",
                 "--backgrounds", f"{synthetic_ball_coco(16, 0)}@12:"])
    assert code == 0
    text = capsys.readouterr().out
    assert f"training from {base} on 12 images + 4 ball-free backgrounds" in text and "spread over 2 seeds: recall" in text
    model = BallSegmentationModel.load(out)
    assert "kept seed" in model.description and str(base) in model.description and "(4 ball-free images)" in model.description


def _two_cameras(synthetic_ball_coco, tmp_path):
    """The 16-image synthetic set with a COCO ``camera`` field: images 0, 2, 4, ... 'left', the others 'right'."""
    import json
    import shutil

    dst = tmp_path / "two"
    shutil.copytree(synthetic_ball_coco(16, 0), dst)
    coco = json.loads((dst / "annotations.json").read_text())
    for k, im in enumerate(sorted(coco["images"], key=lambda im: im["file_name"])):
        im["camera"] = "left" if k % 2 == 0 else "right"
    (dst / "annotations.json").write_text(json.dumps(coco))
    return dst


def test_cli_camera_picks_one_cameras_images_before_the_time_range(synthetic_ball_coco, tmp_path, capsys):
    data = _two_cameras(synthetic_ball_coco, tmp_path)
    out = tmp_path / "left.npz"
    code = main(["train", "--data", str(data), "--out", str(out), "--epochs", "1", "--learned", "off", "--from", "none",
                 "--augment", "0", "--camera", "left", "--time-range", "0:6", "--thresholds", "split"])
    assert code == 0
    assert "on 6 images" in capsys.readouterr().out  # 8 of the left camera, the first 6 of them in its time order
    assert "(cameras left, time range 0:6)" in BallSegmentationModel.load(out).description
    code = main(["train", "--data", str(data), "--out", str(tmp_path / "m.npz"), "--epochs", "1", "--learned", "off", "--camera", "middle"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--camera middle: not in the labelled set; its cameras: left, right" in err
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("args, message", [
    (["--camera", "cam1"], "--camera cam1: not in the labelled set; its cameras: cam0"),
    (["--from", "model.pt"], "--from must be a .npz weights file"),
    (["--from", "missing.npz"], "does not exist"),
    (["--time-range", "x"], "--time-range must be START:STOP"),
    (["--time-range", "100:"], "selects no image"),
    (["--backgrounds", "missing.mp4"], "no such file"),
    (["--backgrounds", "x.mp4@0:3"], "no such file"),
])
def test_cli_hostile_few_label_options(synthetic_ball_coco, tmp_path, capsys, args, message):
    code = main(["train", "--data", str(synthetic_ball_coco(16, 0)), "--out", str(tmp_path / "m.npz"), "--epochs", "1", "--learned", "off", *args])
    assert code == 2
    assert message in capsys.readouterr().err


def test_eval_ball_free_counts_false_alarms(synthetic_ball_coco, cv_trained, tmp_path, capsys):
    import json

    model = cv_trained[0].save(tmp_path / "m.npz")
    data = str(synthetic_ball_coco(16, 0))
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--ball-free", "--json", str(tmp_path / "bf.json"),
                 "--time-range", "4:"]) == 0
    text = capsys.readouterr().out
    assert "ball-free: every labelled ball painted out" in text and "12 images" in text
    rows = json.loads((tmp_path / "bf.json").read_text())
    assert [r["method"] for r in rows] == ["paper", "ours", "topk"]
    assert all(r["recall"] is None for r in rows)


# -- the candidate verifier ------------------------------------------------------------------------------
def test_verifier_training_is_seeded_and_keeps_the_balls(synthetic_ball_coco, tmp_path, capsys):
    from harness.experiments.studies.eval_detector import evaluate

    opts = TrainOptions(**{**QUICK_CV.__dict__, "verifier": True})
    model, info = train(read_coco(synthetic_ball_coco(16, 0)), opts, progress=False, log=lambda s: None)
    v = model.verifier
    assert v is not None and 0 < v.threshold < 1
    assert info["verifier"]["candidate_recall"] >= 0.9 and info["verifier"]["n_ball"] > 0
    assert "verifier (16x16 crops" in model.description
    again, _ = train(read_coco(synthetic_ball_coco(16, 0)), opts, progress=False, log=lambda s: None)
    np.testing.assert_array_equal(again.verifier.w1, v.w1)
    assert again.verifier.threshold == v.threshold
    back = BallSegmentationModel.load(model.save(tmp_path / "v.npz"))
    held_out = read_coco(synthetic_ball_coco(20, 7))
    with_v = {s.method: s for s in evaluate(back, held_out, progress=False)}
    assert with_v["ours"].recall >= 0.85
    # rt2 eval detector runs the verifier, and --no-verifier the filter alone
    data = synthetic_ball_coco(20, 7)
    for flag, expect in (([], "(with its candidate verifier)"), (["--no-verifier"], None)):
        assert main(["eval", "detector", "--data", str(data), "--model", str(tmp_path / "v.npz"), *flag]) == 0
        out = capsys.readouterr().out
        assert (expect in out) if expect else "(with its candidate verifier)" not in out


# -- ball-free backgrounds ------------------------------------------------------------------------------
def test_backgrounds_from_video_coco_and_folder(synthetic_ball_coco, tmp_path):
    import cv2

    from harness.experiments.detector.backgrounds import read_backgrounds

    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for k in range(20):
        writer.write(np.full((48, 64, 3), 10 * k, np.uint8))
    writer.release()
    folder = tmp_path / "imgs"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.zeros((10, 12, 3), np.uint8))
    coco = synthetic_ball_coco(16, 0)
    got = read_backgrounds([str(video), f"{coco}@0:5", str(folder)], frames_per_video=4, load_image=load_image)
    assert len(got) == 4 + 5 + 1
    assert all(li.n_balls == 0 and im.shape[:2] == (li.height, li.width) for im, li in got)
    frames = [im.mean() for im, _ in got[:4]]
    assert frames == sorted(frames) and frames[-1] > frames[0] + 100  # spread over the whole video
    balls = [li for li in take_range(read_coco(coco), "0:5") if li.n_balls]
    assert balls  # and those balls are painted out in the backgrounds
    li = balls[0]
    u, v = np.rint(li.centers_px[0]).astype(int)
    idx = [i for i, l2 in enumerate(take_range(read_coco(coco), "0:5")) if l2.path == li.path][0]
    assert np.abs(got[4 + idx][0][v, u].astype(int) - load_image(li)[v, u].astype(int)).max() > 0


@pytest.mark.parametrize("source, match", [("missing.mp4", "no such file"), ("{tmp}/v.txt", "expected a video"),
                                            ("{tmp}/empty", "holds no image"), ("{tmp}/bad.mp4", "cannot read this video")])
def test_backgrounds_hostile(tmp_path, source, match):
    from harness.experiments.detector.backgrounds import read_backgrounds

    (tmp_path / "v.txt").write_text("x")
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.mp4").write_bytes(b"not a video")
    with pytest.raises(ValueError, match=match):
        read_backgrounds([source.format(tmp=tmp_path)], load_image=load_image)
    with pytest.raises(ValueError, match="background-frames"):
        read_backgrounds([], frames_per_video=0, load_image=load_image)


def test_backgrounds_join_training_only(synthetic_ball_coco):
    from harness.experiments.detector.backgrounds import read_backgrounds

    coco = synthetic_ball_coco(16, 0)
    bg = read_backgrounds([f"{coco}@0:4"], load_image=load_image)
    _, plain = train(read_coco(coco), QUICK_CV, progress=False, log=lambda s: None)
    model, with_bg = train(read_coco(coco), QUICK_CV, progress=False, log=lambda s: None, backgrounds=bg)
    assert with_bg["n_neg"] > plain["n_neg"] and with_bg["n_pos"] == plain["n_pos"]
    assert with_bg["val_ours"].n_images == plain["val_ours"].n_images == 16  # scored on the labelled images only
    assert "4 ball-free background images" in model.description


@pytest.mark.parametrize("args, message", [(["--time-range", "1-3"], "--time-range must be START:STOP"),
                                            (["--time-range", "50:"], "selects no image")])
def test_eval_hostile_time_range(synthetic_ball_coco, cv_trained, tmp_path, capsys, args, message):
    model = cv_trained[0].save(tmp_path / "m.npz")
    assert main(["eval", "detector", "--data", str(synthetic_ball_coco(16, 0)), "--model", str(model), *args]) == 2
    assert message in capsys.readouterr().err
