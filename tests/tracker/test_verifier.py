"""The candidate verifier: crop features, the perceptron, storage in the model file, and its place in
the detector (drops and reorders candidates, refines centres, ROI and full frame agree)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tracker import BallDetector, BallSegmentationModel, CandidateVerifier, DetectorOptions
from tracker.detection.synthetic import ORANGE_RGB, draw_disk, hand_made_model as orange_model


def _verifier(crop=8, hidden=4, threshold=0.5, bias=0.0, refine=False, w1=None, w2=None):
    f = 3 * crop * crop
    rng = np.random.default_rng(0)
    w1 = rng.normal(0, 0.1, (f, hidden)) if w1 is None else w1
    w2 = np.zeros((hidden, 3)) if w2 is None else w2
    return CandidateVerifier(w1, np.zeros(hidden), w2, np.array([bias, 0.0, 0.0]), crop_px=crop, threshold=threshold, refine_center=refine)


def _brightness_verifier(crop=8):
    """A hand-made verifier whose logit is the brightness of the crop's centre minus its mean (a disk detector)."""
    f = 3 * crop * crop
    w1 = np.zeros((f, 1))
    idx = np.arange(f).reshape(crop, crop, 3)
    w1[idx[crop // 2 - 1 : crop // 2 + 1, crop // 2 - 1 : crop // 2 + 1].reshape(-1), 0] = 1.0
    w2 = np.array([[4.0, 0.0, 0.0]])
    return CandidateVerifier(w1, np.zeros(1), w2, np.array([-2.0, 0.0, 0.0]), crop_px=crop, threshold=0.5, refine_center=False)


def test_features_are_exposure_free_and_shaped():
    v = _verifier()
    rng = np.random.default_rng(1)
    image = rng.integers(20, 120, (60, 80, 3)).astype(np.uint8)
    f = v.features(image, [[40.0, 30.0], [5.0, 5.0]], [16.0, 16.0])
    assert f.shape == (2, 3 * 64) and f.dtype == np.float32
    np.testing.assert_allclose(f.mean(axis=1), 0.0, atol=1e-5)
    p, off = v.predict(f)
    assert p.shape == (2,) and off.shape == (2, 2) and ((0 < p) & (p < 1)).all()
    assert v.verify(image, np.zeros((0, 2)), np.zeros(0))[0].shape == (0,)


def test_save_load_round_trip_and_old_files(tmp_path):
    model = dataclasses.replace(orange_model(), verifier=_verifier(refine=True, threshold=0.3))
    back = BallSegmentationModel.load(model.save(tmp_path / "m.npz"))
    assert back.verifier is not None and back.verifier.threshold == 0.3 and back.verifier.refine_center
    np.testing.assert_array_equal(back.verifier.w1, model.verifier.w1)
    plain = BallSegmentationModel.load(orange_model().save(tmp_path / "p.npz"))
    assert plain.verifier is None


@pytest.mark.parametrize("change, match", [
    (lambda d: d.pop("verifier_w2"), "verifier fields incomplete"),
    (lambda d: d.update(verifier_w1=np.zeros((5, 4))), "w1 must have shape"),
    (lambda d: d.update(verifier_threshold=np.array(1.5)), "threshold must be a probability"),
    (lambda d: d.update(verifier_crop_px=np.array(2.5)), "verifier_crop_px' must be an integer"),
    (lambda d: d.update(verifier_side_range_px=np.array([9.0])), "must hold \\[min, max\\]"),
    (lambda d: d.update(verifier_b1=np.array(["a"] * 4)), "must be numbers"),
])
def test_hostile_verifier_fields(tmp_path, change, match):
    path = dataclasses.replace(orange_model(), verifier=_verifier()).save(tmp_path / "m.npz")
    data = dict(np.load(path))
    change(data)
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(ValueError, match=match):
        BallSegmentationModel.load(tmp_path / "bad.npz")


def test_constructor_hostile():
    with pytest.raises(ValueError, match="crop_px"):
        _verifier(crop=2)
    with pytest.raises(ValueError, match="finite"):
        CandidateVerifier(np.full((192, 4), np.nan), np.zeros(4), np.zeros((4, 3)), np.zeros(3), crop_px=8)
    with pytest.raises(ValueError, match="verifier must be a CandidateVerifier"):
        dataclasses.replace(orange_model(), verifier="yes")


def _two_balls():
    image = np.full((80, 120, 3), 40, np.uint8)
    draw_disk(image, (30.0, 40.0), 8.0, ORANGE_RGB)
    draw_disk(image, (90.0, 40.0), 8.0, ORANGE_RGB)
    image[36:45, 86:95] = np.maximum(image[36:45, 86:95], 0)
    return image


def test_detector_drops_candidates_below_the_threshold_and_keeps_paper_unchanged():
    image = _two_balls()
    plain = orange_model()
    assert len(BallDetector(plain).detect(image)) == 2
    reject_all = dataclasses.replace(plain, verifier=_verifier(bias=-20.0))
    assert len(BallDetector(reject_all).detect(image)) == 0
    assert len(BallDetector(reject_all, DetectorOptions(verify=False)).detect(image)) == 2  # switched off
    paper = BallDetector(reject_all, DetectorOptions(method="paper")).detect(image)
    assert len(paper) == 1  # the paper's Algorithm 1 never runs the verifier
    accept_all = dataclasses.replace(plain, verifier=_verifier(bias=20.0))
    det = BallDetector(accept_all).detect(image)
    assert len(det) == 2 and (det.scores > 0.99).all()


def test_detector_orders_by_the_verifier_and_roi_agrees():
    image = np.full((80, 120, 3), 90, np.uint8)
    image[20:60, 70:110] = 5  # dark surroundings: the brightness verifier prefers the ball inside them
    draw_disk(image, (30.0, 40.0), 8.0, ORANGE_RGB)
    draw_disk(image, (90.0, 40.0), 8.0, ORANGE_RGB)
    model = dataclasses.replace(orange_model(), verifier=_brightness_verifier())
    det = BallDetector(model).detect(image)
    assert len(det) >= 1 and abs(det.uv_px[0, 0] - 90.0) < 1.5
    from tracker._pipeline_search import search_around

    roi = search_around(BallDetector(model), image, (90.0, 40.0))
    assert roi.used_roi and np.allclose(roi.uv_px[0], det.uv_px[0])
    assert roi.scores[0] == pytest.approx(det.scores[0])


def test_center_refinement_moves_by_the_predicted_offset():
    image = _two_balls()
    w2 = np.zeros((4, 3))
    v = _verifier(bias=20.0, refine=True, w2=w2)
    v = dataclasses.replace(v, b2=np.array([20.0, 0.1, -0.05]))
    model = dataclasses.replace(orange_model(), verifier=v)
    det = BallDetector(model).detect(image)
    plain = BallDetector(orange_model()).detect(image)
    sides = v.sides_px(plain.boxes_xywh[:, 2:].max(axis=1))
    order = np.argsort(plain.uv_px[:, 0])
    got = det.uv_px[np.argsort(det.uv_px[:, 0])]
    np.testing.assert_allclose(got, plain.uv_px[order] + np.array([0.1, -0.05]) * sides[order][:, None], atol=1e-9)
