"""The full-frame search at a reduced resolution (tracker._pipeline_pyramid, TrackerOptions.full_frame_pyramid):
which cameras use it (off by default, on in the live service), that its candidates are the full frame's (found again at full resolution), and that a
nine-camera 1440x1080 rig's tracker gives the same positions with it as without."""

from __future__ import annotations

import numpy as np
import pytest

from tracker import Tracker, TrackerOptions
from tracker._pipeline_pyramid import MAX_LEVEL, PyramidSearch, pyramid_levels
from tracker.detection import BallDetector, DetectorOptions
from tracker.detection.synthetic import draw_disk
from tracker.observation import FrameSet
from tracker.pipeline import load_model
from tracker.rig_files import resolve_rig


def test_levels_follow_the_smallest_ball():
    levels = pyramid_levels([6.4, 10.9, 11.0, 13.6, 21.9, 22.0, 25.6, 60.0, 400.0, np.nan])
    assert levels.tolist() == [0, 0, 1, 1, 1, 2, 2, 2, MAX_LEVEL, 0]


def _frame(rng, h, w, balls):
    img = np.clip(rng.normal(100, 4, (h, w, 3)), 0, 255).astype(np.uint8)
    for uv, d in balls:
        draw_disk(img, np.asarray(uv, float), d, (245, 120, 20))
    return img


@pytest.mark.parametrize("level, balls", [
    (1, [((700.3, 500.6), 16.0)]),
    (1, [((200.0, 300.0), 14.0), ((1100.7, 820.2), 24.0)]),
    (2, [((900.4, 600.1), 40.0)]),
    (1, [((3.0, 540.0), 18.0)]),  # at the image's edge: the full-resolution window is clipped to the image
    (2, []),
])
def test_the_candidates_are_the_full_frames(level, balls, model):
    rng = np.random.default_rng(level)
    img = _frame(rng, 1080, 1440, balls)
    det = BallDetector(model, DetectorOptions(min_area_px=4, max_area_px=3000))
    full, pyr = det.detect(img), PyramidSearch(det, level).detect(img)
    assert len(full) == len(pyr) == len(balls)
    order = np.lexsort(full.uv_px.T), np.lexsort(pyr.uv_px.T)
    np.testing.assert_allclose(full.uv_px[order[0]], pyr.uv_px[order[1]], atol=1e-9)
    np.testing.assert_array_equal(full.areas_px[order[0]], pyr.areas_px[order[1]])
    np.testing.assert_allclose(full.scores[order[0]], pyr.scores[order[1]], atol=1e-6)


def test_which_trackers_use_it():
    vga, ace = resolve_rig("lab8_vga"), resolve_rig("lab9_ace")
    assert Tracker(vga, full_frame_pyramid=True).engine.pyramid == [None] * len(vga)  # VGA balls: the full resolution
    levels = [p.level for p in Tracker(ace, full_frame_pyramid=True).engine.pyramid]
    assert levels == [1] * 8 + [2]
    assert Tracker(ace).engine.pyramid == [None] * len(ace)  # off unless asked for (the live service asks)
    white = Tracker(ace, model="data/models/ball_seg_white.npz", full_frame_pyramid=True)
    assert white.engine.pyramid == [None] * len(ace)  # a learned stage: its own scale
    assert Tracker(ace, "rt2-paper", full_frame_pyramid=True).engine.pyramid == [None] * len(ace)  # the paper's system as published
    with pytest.raises(ValueError, match="TrackerOptions.full_frame_pyramid must be True or False, got 'yes'"):
        TrackerOptions(full_frame_pyramid="yes")
    det = BallDetector(load_model(None))
    with pytest.raises(ValueError, match=r"pyramid level must be in \[1, 2\], got 0"):
        PyramidSearch(det, 0)
    with pytest.raises(ValueError, match="a learned stage runs at its own scale"):
        PyramidSearch(BallDetector(load_model("data/models/ball_seg_white.npz")), 1)


def test_a_nine_camera_rig_tracks_the_same_with_the_pyramid(model):
    """lab9_ace (nine 1440x1080 cameras): a 40 mm ball drawn where it projects in each camera, two distractor disks,
    full-frame search every time: the same positions with the pyramid as without."""
    rig = resolve_rig("lab9_ace")
    lo, hi = rig.workspace_m
    rng = np.random.default_rng(3)
    for k in range(2):
        X = lo + (hi - lo) * rng.uniform(0.2, 0.8, 3)
        images = []
        for cam in rig:
            W, H = cam.image_size
            d = 0.04 * cam.K[0, 0] / cam.depth(X[None])[0]
            decoys = [((rng.uniform(50, W - 50), rng.uniform(50, H - 50)), d * rng.uniform(0.8, 1.2)) for _ in range(2)]
            images.append(_frame(rng, H, W, [(cam.project(X[None])[0], d), *decoys]))
        fs = FrameSet(0.01 * k, tuple(images), k)
        on, off = (Tracker(rig, model=model, roi=False, hypotheses=None, full_frame_pyramid=p) for p in (True, False))
        a, b = on.process(fs), off.process(fs)
        assert a.status == b.status and a.status.value == "ok" and np.linalg.norm(a.position_m - X) < 0.005
        np.testing.assert_allclose(a.position_m, b.position_m, atol=1e-9)
        assert on.stats.full_frame_searches == off.stats.full_frame_searches == len(rig)


def test_the_live_service_asks_for_it():
    import argparse

    from harness.cli.track import add_arguments, track_config
    from harness.live.config import ConfigError, TrackConfig

    assert TrackConfig().full_frame_pyramid is True
    with pytest.raises(ConfigError, match="full_frame_pyramid must be True or False, got 'no'"):
        TrackConfig(full_frame_pyramid="no")
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert track_config(parser.parse_args([])).full_frame_pyramid is True  # rt2 track, rt2 bench live
    assert track_config(parser.parse_args(["--no-full-frame-pyramid"])).full_frame_pyramid is False
