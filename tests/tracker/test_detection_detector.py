"""BallDetector: detections on synthetic scenes, one window, the pipeline's window -> neighbourhood fallback
(tracker._pipeline_search), bad input."""

from __future__ import annotations

import numpy as np
import pytest

from tracker import BallDetector, DetectorOptions, Detections
from tracker._pipeline_search import search_around, truncated
from tracker.detection.synthetic import ORANGE_RGB, draw_disk, hand_made_model, synthetic_scene

MODEL = hand_made_model(ORANGE_RGB)


def _scene(seed, **kw):
    return synthetic_scene(np.random.default_rng(seed), **kw)


# -- smoke -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["paper", "ours"])
def test_smoke_finds_the_ball(method):
    image, centers, diam = _scene(0)
    det = BallDetector(MODEL, DetectorOptions(method=method)).detect(image)
    assert isinstance(det, Detections) and len(det) >= 1 and not det.used_roi
    assert np.linalg.norm(det.uv_px[0] - centers[0]) < 0.3
    assert 0.5 <= det.scores[0] <= 1.0


def test_no_ball_no_detection():
    image, _, _ = _scene(1, n_balls=0)
    for method in ("paper", "ours"):
        assert len(BallDetector(MODEL, DetectorOptions(method=method)).detect(image)) == 0


# -- shapes and layout ---------------------------------------------------------------------------------
def test_detection_fields_and_box_convention():
    image = np.full((60, 80, 3), 90, np.uint8)
    image[20:26, 30:34] = ORANGE_RGB  # rows 20..25, cols 30..33
    det = BallDetector(MODEL, DetectorOptions(min_fill_ratio=0.0)).detect(image)
    assert det.uv_px.shape == (1, 2) and det.scores.shape == (1,) and det.boxes_xywh.shape == (1, 4)
    np.testing.assert_allclose(det.uv_px[0], [31.5, 22.5], atol=1e-9)
    np.testing.assert_array_equal(det.boxes_xywh[0], [30, 20, 4, 6])  # COCO: top-left pixel spans [0, 1]
    assert det.areas_px[0] == 24


def test_top_k_candidates_and_paper_single():
    image = np.full((100, 160, 3), 80, np.uint8)
    truth = [(30.3, 40.6), (120.2, 70.1), (80.7, 20.4)]
    for c in truth:
        draw_disk(image, c, 9.0, ORANGE_RGB)
    ours = BallDetector(MODEL, DetectorOptions(max_candidates=4)).detect(image)
    assert len(ours) == 3
    d = np.linalg.norm(ours.uv_px[:, None] - np.array(truth)[None], axis=2)
    assert np.all(d.min(axis=1) < 0.2) and len(set(d.argmin(axis=1))) == 3
    assert np.all(np.diff(ours.scores) <= 0)  # best first
    paper = BallDetector(MODEL, DetectorOptions(method="paper")).detect(image)
    assert len(paper) == 1
    np.testing.assert_allclose(paper.uv_px[0], ours.uv_px[0])


def test_area_range_defaults_to_the_model_and_options_override():
    import dataclasses

    image = np.full((60, 80, 3), 90, np.uint8)
    draw_disk(image, (30.0, 30.0), 6.0, ORANGE_RGB)  # ~28 px
    strict = dataclasses.replace(MODEL, area_range_px=np.array([50.0, 100.0]))
    det = BallDetector(strict)
    assert det.area_range_px == (50.0, 100.0) and len(det.detect(image)) == 0
    assert len(BallDetector(strict, DetectorOptions(min_area_px=5)).detect(image)) == 1
    assert len(BallDetector(strict, DetectorOptions(method="paper")).detect(image)) == 1  # no shape test


# -- ROI mode ------------------------------------------------------------------------------------------
def test_roi_used_and_equal_to_full_frame():
    image, centers, _ = _scene(5, diameter_px=(10, 10))
    det = BallDetector(MODEL)
    full = det.detect(image)
    roi = search_around(det, image, centers[0] + [7.0, -5.0])
    assert roi.used_roi and not full.used_roi
    np.testing.assert_allclose(roi.uv_px[0], full.uv_px[0], atol=1e-4)
    np.testing.assert_allclose(roi.boxes_xywh[0], full.boxes_xywh[0])


def test_detect_searches_only_the_window():
    image, centers, _ = _scene(6, diameter_px=(10, 10))
    det = BallDetector(MODEL, DetectorOptions(roi_half_size_px=16))
    u, v = (int(round(c)) for c in centers[0])
    around = det.detect(image, (u - 16, v - 16, u + 16, v + 16))
    assert around.used_roi and np.linalg.norm(around.uv_px[0] - centers[0]) < 0.3
    x0 = u + 40 if u < 320 else u - 72  # a window beside the ball: nothing, and no search beyond it
    assert len(det.detect(image, (x0, v - 16, x0 + 32, v + 16))) == 0


def test_roi_falls_back_to_full_frame():
    image, centers, _ = _scene(6, diameter_px=(10, 10))
    det = BallDetector(MODEL, DetectorOptions(roi_half_size_px=16))
    far = centers[0] + [200.0 if centers[0][0] < 320 else -200.0, 0.0]
    res = search_around(det, image, far)  # window without the ball
    assert not res.used_roi and np.linalg.norm(res.uv_px[0] - centers[0]) < 0.3
    res = search_around(det, image, [-500.0, -500.0])  # prediction outside the image
    assert not res.used_roi and len(res) >= 1
    # the window edge cuts the ball: truncated blob -> full frame, centre unbiased
    cut = centers[0] + [16.0 + 2.0, 0.0]
    cu, cv = (int(round(c)) for c in cut)
    window = (cu - 16, cv - 16, cu + 16, cv + 16)
    assert truncated(det.detect(image, window), window, image.shape[1], image.shape[0])
    res = search_around(det, image, cut)
    assert not res.used_roi and np.linalg.norm(res.uv_px[0] - centers[0]) < 0.3


def test_roi_at_image_border_is_not_truncation():
    image = np.full((100, 100, 3), 80, np.uint8)
    draw_disk(image, (3.0, 50.0), 8.0, ORANGE_RGB)  # cut by the image edge, not by the window
    res = search_around(BallDetector(MODEL, DetectorOptions(min_fill_ratio=0.0)), image, (10.0, 50.0))
    assert res.used_roi and len(res) == 1


# -- accuracy on synthetic scenes ----------------------------------------------------------------------
def test_subpixel_centre_accuracy():
    rng = np.random.default_rng(8)
    det = BallDetector(MODEL)
    errs = []
    for _ in range(60):
        image, centers, _ = synthetic_scene(rng, diameter_px=(6, 20))
        res = det.detect(image)
        errs.append(np.linalg.norm(res.uv_px[0] - centers[0]) if len(res) else np.inf)
    errs = np.array(errs)
    assert np.isfinite(errs).all()
    assert np.median(errs) < 0.1 and np.percentile(errs, 95) < 0.3


# -- backends agree ------------------------------------------------------------------------------------
def test_numba_and_python_backends_agree_on_scenes():
    for seed in range(5):
        image, _, _ = _scene(20 + seed, n_balls=3)
        a = BallDetector(MODEL, DetectorOptions(backend="numba")).detect(image)
        b = BallDetector(MODEL, DetectorOptions(backend="python")).detect(image)
        np.testing.assert_array_equal(a.uv_px, b.uv_px)
        np.testing.assert_array_equal(a.boxes_xywh, b.boxes_xywh)


def test_the_coarse_to_fine_full_frame_finds_the_full_searchs_candidates():
    """``coarse_full_frame`` (the default) against every pixel computed: the same candidates, to the bit, on synthetic
    scenes with up to four balls of 6-14 px, on frames without a ball, and on a frame mostly of the ball's colour
    (where the blocks would cover most of it and the whole frame is computed); "paper" never searches coarse."""
    exact = BallDetector(MODEL, DetectorOptions(coarse_full_frame=False))
    coarse = BallDetector(MODEL, DetectorOptions())
    images = [_scene(40 + seed, n_balls=seed % 5, diameter_px=(6, 14))[0] for seed in range(40)]
    orange = np.empty((96, 128, 3), np.uint8)
    orange[:] = ORANGE_RGB
    images.append(orange)
    found = 0
    for image in images:
        a, b = exact.detect(image), coarse.detect(image)
        assert a.uv_px.tobytes() == b.uv_px.tobytes() and a.boxes_xywh.tobytes() == b.boxes_xywh.tobytes()
        assert a.scores.tobytes() == b.scores.tobytes() and a.areas_px.tobytes() == b.areas_px.tobytes()
        found += len(a)
    assert found >= 60  # the scenes' balls were found, not only their absence agreed on
    assert not BallDetector(MODEL, DetectorOptions(method="paper"))._coarse


def test_the_coarse_to_fine_search_grows_its_blocks_until_no_blob_is_cut():
    """A blob above T_l that reaches past the blocks the coarse pass chose (one-pixel stripes of the ball's colour
    hanging from a ball: the coarse pass samples every other column and sees only the grey between them) is flood
    filled as on the full frame: the blocks grow until no pixel above T_l lies on the edge of the computed region."""
    import cv2

    from tracker.detection._correlate import coarse_blocks
    from tracker.detection.detector import COARSE_MARGIN_LOGIT
    from tracker.detection.model import LogitWorkspace, logit

    image = np.full((96, 128, 3), 90, np.uint8)
    draw_disk(image, (40.0, 20.0), 6.0, ORANGE_RGB)
    image[20:90, 35:46:2] = ORANGE_RGB  # stripes at odd columns from the ball down to near the bottom
    opts = dict(min_area_px=1, max_area_px=100000, min_fill_ratio=0.0, max_aspect=100.0)
    exact = BallDetector(MODEL, DetectorOptions(coarse_full_frame=False, **opts)).detect(image)
    coarse = BallDetector(MODEL, DetectorOptions(**opts)).detect(image)
    assert len(exact) >= 1
    assert exact.uv_px.tobytes() == coarse.uv_px.tobytes() and exact.areas_px.tobytes() == coarse.areas_px.tobytes()
    assert exact.scores.tobytes() == coarse.scores.tobytes() and exact.boxes_xywh.tobytes() == coarse.boxes_xywh.tobytes()
    # the scene does need the growth: the full search's blob reaches past the coarse pass's own blocks
    tl = logit(MODEL.t_low)
    first = coarse_blocks(MODEL.logits_coarse_trusted(image, LogitWorkspace()) >= tl - COARSE_MARGIN_LOGIT, 96, 128)
    inside = np.zeros((96, 128), bool)
    for x0, y0, x1, y1 in first:
        inside[y0:y1, x0:x1] = True
    _, labels = cv2.connectedComponents((MODEL.logits(image) > tl).astype(np.uint8), connectivity=4)
    blob = labels == labels[20, 40]
    assert blob.sum() == exact.areas_px[0] and (blob & ~inside).any()


# -- bad input -----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(method="magic"), r"method must be one of \('paper', 'ours'\), got 'magic'"),
        (dict(t_high=1.5), "t_high must be a probability"),
        (dict(t_high=0.3, t_low=0.6), "need t_low < t_high"),
        (dict(max_candidates=0), "max_candidates must be a positive integer"),
        (dict(max_candidates=20, max_seeds=4), "max_seeds"),
        (dict(min_area_px=50, max_area_px=10), "min_area_px"),
        (dict(min_fill_ratio=2.0), "min_fill_ratio"),
        (dict(max_aspect=0.5), "max_aspect"),
        (dict(backend="gpu"), "backend"),
        (dict(coarse_full_frame="yes"), "coarse_full_frame must be True or False"),
    ],
)
def test_bad_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DetectorOptions(**kwargs)


def test_bad_detector_arguments():
    with pytest.raises(ValueError, match="model must be a BallSegmentationModel"):
        BallDetector("model.npz")
    with pytest.raises(ValueError, match="options must be a DetectorOptions"):
        BallDetector(MODEL, {"method": "paper"})
    with pytest.raises(ValueError, match="need t_low < t_high"):
        BallDetector(MODEL, DetectorOptions(t_low=0.6))  # model's t_high is 0.5


def test_bad_images_are_refused_where_they_come_in():
    """The detector trusts its inputs; the check it relied on is tracker.images' (the frame-set
    boundary of Tracker, and the model's public logits)."""
    from tracker.images import check_image, image_problem

    with pytest.raises(ValueError, match="image must have dtype uint8"):
        check_image(np.zeros((10, 10, 3), np.float64))
    with pytest.raises(ValueError, match=r"images\[1\] must be an \(H, W, 3\) uint8 RGB array, got shape \(10, 10\)"):
        check_image(np.zeros((10, 10), np.uint8), "images[1]")
    with pytest.raises(ValueError, match=r"images\[0\] is empty"):
        check_image(np.zeros((10, 0, 3), np.uint8), "images[0]")
    with pytest.raises(ValueError, match="is 10x10 px but the camera is calibrated for 20x10"):
        check_image(np.zeros((10, 10, 3), np.uint8), image_size=(20, 10))
    assert image_problem(np.zeros((10, 10, 3), np.uint8), (10, 10)) is None
    assert image_problem(None)[0] == "type" and image_problem(np.zeros((5, 5, 3), np.uint8), (4, 5))[0] == "size"
