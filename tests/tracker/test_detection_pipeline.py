"""The shipped model, and detections going straight into the robust estimator on rendered lab frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tracker import BallDetector, BallSegmentationModel, DetectorOptions
from tracker.detection.synthetic import SKIN_RGB, WHITE_RGB, draw_disk

DATA = Path(__file__).resolve().parents[2] / "data"
DEFAULT_MODEL = DATA / "models" / "ball_seg_default.npz"
RENDERED_ORANGE_RGB = (242, 97, 13)  # the renderer's "orange" reflectance (0.95, 0.38, 0.05) at nominal exposure


@pytest.fixture(scope="module")
def model():
    return BallSegmentationModel.load(DEFAULT_MODEL)


def test_shipped_model_is_valid(model):
    assert model.input_transform == "log" and model.colour_order == "RGB"
    assert 0.5 <= model.t_high < 1 and 0 < model.t_low < model.t_high
    assert "orange balls" in model.description and "rt2 train" in model.description
    assert 1 <= model.area_range_px[0] < model.area_range_px[1] < 1000


def test_shipped_model_prefers_the_orange_ball(model):
    image = np.full((80, 240, 3), 70, np.uint8)
    image[:, :, 2] = 110  # bluish-grey
    for u, colour in ((40.0, SKIN_RGB), (120.0, WHITE_RGB), (200.0, RENDERED_ORANGE_RGB)):
        draw_disk(image, (u, 40.0), 10.0, colour)
    det = BallDetector(model, DetectorOptions(max_candidates=3)).detect(image)
    assert len(det) == 1
    np.testing.assert_allclose(det.uv_px[0], [200.0, 40.0], atol=0.5)


def test_rendered_frames_to_robust_estimator(model):
    """Real-data stand-in: the lab renderer's 4-camera frames with arms, skin and orange/white
    distractors; the tracker's full-frame candidates (n_cams, k, 2), NaN-padded, go straight into
    RobustTriangulator.estimate. A camera without a frame is an all-NaN row."""
    from harness.sim.render.renderer import Renderer
    from harness.sim.render.scenes import SceneOptions, random_scene
    from tracker import FrameSet, Rig, Tracker
    from tracker.robust import RobustTriangulator

    rig = Rig.load(DATA / "rigs" / "lab4_vga.yaml")
    renderer = Renderer(rig, seed=0)
    k = BallDetector(model).options.max_candidates
    tracker = Tracker(rig, "rt2", model=model, roi=False, size_from_rig=False, max_size_ratio=None, hypotheses=None,
                      handover_max_age_s=None)
    est = RobustTriangulator(rig)
    errors = []
    for i in range(25):
        scene = random_scene(np.random.default_rng([7, i]), options=SceneOptions(p_no_ball=0.0, p_white=0.0, p_second_ball=0.0), frame_index=i)
        images = list(renderer.render(scene))
        if i == 24:  # one more frame set without camera 1's frame: its row is all NaN
            images[1] = None
        _, pinfo = tracker.process_with_info(FrameSet(0.01 * i, tuple(images), i))
        uv, scores = pinfo.uv_candidates_px, pinfo.scores
        assert uv.shape == (len(rig), k, 2) and scores.shape == uv.shape[:2]
        for c in range(len(rig)):  # NaN padding after the real candidates
            m = int(np.isfinite(scores[c]).sum())
            assert np.isfinite(uv[c, :m]).all() and np.isnan(uv[c, m:]).all()
        if i == 24:
            assert np.isnan(uv[1]).all() and np.isnan(scores[1]).all()
            break
        X_world, info = est.estimate(uv)
        errors.append(np.inf if X_world is None else np.linalg.norm(X_world - scene.balls[0].position_m))
    errors = np.array(errors)
    found = np.isfinite(errors)
    assert found.mean() >= 0.7
    assert np.median(errors[found]) < 0.005  # metres
    assert np.sum(errors[found] > 0.02) <= 2
