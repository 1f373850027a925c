"""The motion cue of fixed cameras (tracker/motion.py) and the tracker's use of it (TrackerOptions.motion_cue)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tracker import FrameSet, MotionCue, MotionOptions, Status, Tracker
from tracker.detection.synthetic import draw_disk
from tracker.motion import observe_cells, observe_reference, reduced_size, sample_points

ORANGE = (245, 120, 20)


# -- the kernel: compiled == numpy reference ------------------------------------------------------------
@pytest.mark.parametrize("hw, cells", [((480, 640), (160, 120)), ((3, 2), (1, 1)), ((17, 29), (7, 4)), ((1080, 1440), (360, 270))])
def test_compiled_kernel_agrees_with_the_reference(hw, cells):
    rng = np.random.default_rng(list(hw))
    image = rng.integers(0, 256, (*hw, 3), dtype=np.uint8)
    ys, xs = sample_points(hw[1], hw[0], *cells)
    assert ys.min() >= 0 and ys.max() < hw[0] and xs.min() >= 0 and xs.max() < hw[1]
    bg = rng.uniform(0, 255, (cells[1], cells[0], 3)).astype(np.float32)
    bg[0, 0, 0] = image[ys[0], xs[0], 0] + 12.0 + 0.15 * bg[0, 0, 0]  # a difference right at the threshold
    for threshold, relative, alpha in ((12.0, 0.15, 0.1), (0.0, 0.0, 1.0), (40.0, 0.5, 0.3)):
        a, b = bg.copy(), bg.copy()
        ma, mb = np.zeros(bg.shape[:2], bool), np.zeros(bg.shape[:2], bool)
        na = observe_cells(image, ys, xs, a, threshold, relative, alpha, ma)
        nb = observe_reference(image, ys, xs, b, threshold, relative, alpha, mb)
        assert na == nb and np.array_equal(ma, mb) and np.array_equal(a, b)


# -- options: hostile values -----------------------------------------------------------------------------
@pytest.mark.parametrize("field, value", [
    ("alpha", 0.0), ("alpha", 1.5), ("alpha", math.nan), ("alpha", True), ("alpha", "0.1"),
    ("max_share", 0.0), ("max_share", 2.0),
    ("threshold", -1.0), ("threshold", math.inf), ("threshold", None),
    ("relative", -0.1), ("relative", math.nan),
    ("max_gap_s", 0.0), ("max_gap_s", -1.0), ("max_gap_s", math.inf),
    ("cell_px", 0.5), ("cell_px", math.nan), ("cell_px", "4"),
    ("learn_every", 0), ("learn_every", 1.5), ("learn_every", True),
    ("margin_cells", -1), ("margin_cells", 0.5), ("max_regions", 0), ("regions", "yes"), ("regions", 1), ("max_region_share", 0.0), ("max_region_share", 1.1),
])
def test_bad_options_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=f"MotionOptions.{field}"):
        MotionOptions(**{field: value})


def test_tracker_options_refuse_a_motion_cue_of_another_type():
    from tracker import TrackerOptions

    with pytest.raises(ValueError, match="TrackerOptions.motion_cue"):
        TrackerOptions(motion_cue={"alpha": 0.1})


def test_reduced_size():
    assert reduced_size(640, 480, 4.0) == (160, 120)
    assert reduced_size(1440, 1080, 4.0) == (360, 270)
    assert reduced_size(3, 2, 4.0) == (1, 1)


# -- one camera ------------------------------------------------------------------------------------------
def _frame(seed: int, disks=(), h: int = 120, w: int = 160, level: float = 100.0) -> np.ndarray:
    img = np.clip(np.random.default_rng(seed).normal(level, 4, (h, w, 3)), 0, 255).astype(np.uint8)
    for uv, d in disks:
        draw_disk(img, uv, d, ORANGE)
    return img


LAMP = ((30.0, 40.0), 10.0)


def test_a_moving_ball_moved_a_still_lamp_did_not():
    cue = MotionCue(160, 120, MotionOptions(learn_every=1))
    assert cue.observe(_frame(0, [LAMP]), 0.0, frame=0, need_mask=True) is None  # the first frame: no cue
    assert cue.moved([[30.0, 40.0]], [10.0]).all()  # without a cue every candidate passes
    for f in range(1, 6):
        ball = ((60.0 + 12 * f, 70.0), 10.0)
        mask = cue.observe(_frame(f, [LAMP, ball]), 0.005 * f, frame=f, need_mask=True)
        assert mask is not None
        assert cue.moved([ball[0], LAMP[0]], [10.0, 10.0]).tolist() == [True, False]
    assert not cue.moved([[np.nan, 3.0]], [10.0])[0]  # a non-finite centre is never on moving cells


def test_no_cue_when_the_whole_scene_changes_or_after_a_gap():
    cue = MotionCue(160, 120, MotionOptions(learn_every=1, max_gap_s=0.5))
    cue.observe(_frame(0, [LAMP]), 0.0, frame=0)
    assert cue.observe(_frame(1, [LAMP], level=200.0), 0.005, frame=1, need_mask=True) is None  # the light went on
    assert cue.moved([LAMP[0]], [10.0]).all()
    assert cue.observe(_frame(2, [LAMP], level=200.0), 0.010, frame=2, need_mask=True) is not None  # the new background
    assert not cue.moved([LAMP[0]], [10.0]).any()
    assert cue.observe(_frame(3, [LAMP], level=200.0), 1.0, frame=3, need_mask=True) is None  # 1 s later: starts again
    cue.reset()
    assert cue.observe(_frame(4, [LAMP], level=200.0), 1.005, frame=4, need_mask=True) is None
    assert cue.observe(_frame(5, [LAMP], level=200.0), 1.010, frame=5, need_mask=True) is not None
    assert cue.observe(_frame(6, [LAMP], level=200.0), 0.0, frame=6, need_mask=True) is None  # the clock went back: starts again
    assert cue.observe(_frame(7, [LAMP], level=200.0), 0.005, frame=7, need_mask=True) is not None


def test_a_frame_is_counted_once_and_learnt_every_learn_every_frames():
    cue = MotionCue(160, 120, MotionOptions(learn_every=3, alpha=1.0))  # alpha 1: a learnt frame is the background
    cue.observe(_frame(0), 0.0, frame=0)  # the first frame: the background
    ball = ((80.0, 60.0), 12.0)
    assert cue.observe(_frame(1, [ball]), 0.005, frame=1) is None and cue.mask is None  # 2nd frame: nothing computed
    assert cue.observe(_frame(1, [ball]), 0.005, frame=1, need_mask=True) is not None  # asked for: against frame 0
    assert cue.moved([ball[0]], [12.0]).all()  # (and frame 1, ball included, is learnt)
    assert cue.observe(_frame(2, [ball]), 0.010, frame=2) is None  # 3rd frame: learnt though not asked for ...
    assert cue.mask is not None and not cue.moved([ball[0]], [12.0]).any()  # ... against frame 1: the ball did not move
    assert cue.observe(_frame(2, [ball]), 0.010, frame=2, need_mask=True) is cue.mask  # asked again: the same answer
    moved = ((100.0, 60.0), 12.0)
    cue.observe(_frame(3, [moved]), 0.015, frame=3)  # 4th: not learnt
    assert cue.observe(_frame(3, [moved]), 0.015, frame=3, need_mask=True) is not None
    assert cue.moved([moved[0]], [12.0]).all()


# -- the tracker -----------------------------------------------------------------------------------------
def _scene(rig, X_lamp, X_ball, t_s, index, level=100.0):
    rng = np.random.default_rng([7, index])
    images = []
    for i, cam in enumerate(rig):
        W, H = cam.image_size
        img = np.clip(rng.normal(level, 4, (H, W, 3)), 0, 255).astype(np.uint8)
        for X in [X_lamp] + ([] if X_ball is None else [X_ball]):
            z, uv = cam.depth(np.asarray(X)[None])[0], cam.project(np.asarray(X)[None])[0]
            if z > 0 and np.isfinite(uv).all():  # (the lamp may lie behind a camera)
                draw_disk(img, uv, 0.04 * 0.5 * (cam.K[0, 0] + cam.K[1, 1]) / z, ORANGE)
        images.append(img)
    return FrameSet(t_s, tuple(images), index)


def _on(uv_candidates, px, tol=3.0):
    """Whether any camera's candidates include a point within ``tol`` px of that camera's ``px`` row."""
    d = np.linalg.norm(uv_candidates - px[:, None, :], axis=2)
    return bool((d < tol).any())


@pytest.mark.parametrize("how", ["regions", "gate"])
def test_full_frame_candidates_on_a_still_object_are_dropped(rig, model, how):
    """``regions``: the full-frame search looks only around what moved; ``gate``: the whole frame is searched and the
    candidates where nothing moved are dropped."""
    X_lamp = np.array([0.3, -0.4, 1.2])  # a ball-sized orange object that never moves
    X0, V = np.array([-1.0, 0.1, 1.3]), np.array([-4.0, 0.3, 0.5])
    sets = [_scene(rig, X_lamp, None, 0.0, 0)] + [_scene(rig, X_lamp, X0 + V * 0.005 * f, 0.005 * f, f) for f in range(1, 6)]
    lamp_px = rig.project(X_lamp)
    runs = {}
    for cue in (None, MotionOptions(regions=how == "regions")):
        with Tracker(rig, "rt2", model=model, roi=False, hypotheses=None, motion_cue=cue, workers=2 if how == "gate" else 1) as trk:
            runs[cue is not None] = ([trk.process_with_info(fs) for fs in sets], trk.stats.still_candidates)
    plain, (cued, dropped) = runs[False][0], runs[True]
    assert all(_on(info.uv_candidates_px, lamp_px) for _, info in plain[1:])  # without the cue: the lamp is a candidate
    assert _on(cued[0][1].uv_candidates_px, lamp_px)  # the first frame set gives no cue
    for f, (obs, info) in enumerate(cued[1:], start=1):
        assert not _on(info.uv_candidates_px, lamp_px)
        assert obs.status is Status.OK and np.linalg.norm(obs.position_m - (X0 + V * 0.005 * f)) < 0.02
    assert dropped == 0 if how == "regions" else dropped >= 5 * len(rig)  # regions: the lamp is not even searched


def test_regions_around_what_moved():
    cue = MotionCue(160, 120, MotionOptions(learn_every=1, max_regions=2, max_region_share=0.5))
    assert cue.regions(5.0) is None  # no cue yet
    cue.observe(_frame(0), 0.0, frame=0)
    cue.observe(_frame(1), 0.005, frame=1, need_mask=True)
    assert cue.regions(5.0) == []  # nothing moved: nowhere to look
    ball = ((80.0, 60.0), 10.0)
    cue.observe(_frame(2, [ball]), 0.010, frame=2, need_mask=True)
    (x0, y0, x1, y1), = cue.regions(5.0)
    assert x0 <= 80 - 5 - 5 and x1 >= 80 + 5 + 5 and y0 <= 60 - 10 and y1 >= 60 + 10  # the ball, grown by the margin
    assert (x1 - x0) * (y1 - y0) < 0.1 * 160 * 120
    three = [((20.0, 20.0), 8.0), ((140.0, 20.0), 8.0), ((80.0, 100.0), 8.0)]
    cue.observe(_frame(3, three), 0.015, frame=3, need_mask=True)
    assert cue.regions(5.0) is None  # more boxes than max_regions: the full frame
    cue.observe(_frame(4, [((80.0, 60.0), 40.0)]), 0.020, frame=4, need_mask=True)
    assert cue.regions(30.0) is None  # half the frame or more: the full frame


def test_windows_keep_a_ball_that_stops_and_reset_forgets_the_background(rig, model):
    X0, V = np.array([-1.0, 0.1, 1.3]), np.array([-4.0, 0.3, 0.5])
    X_far = np.array([5.0, 5.0, 5.0])  # the "lamp" out of every view: the scene holds the ball alone
    pos = [X0 + V * 0.005 * min(f, 3) for f in range(40)]  # flies 3 frame sets, then lies still
    with Tracker(rig, "rt2", model=model, hypotheses=None, motion_cue=MotionOptions(learn_every=1)) as trk:
        obs = [trk.process(_scene(rig, X_far, X, 0.005 * f, f)) for f, X in enumerate(pos)]
        assert all(o.status is Status.OK for o in obs)
        assert trk.stats.full_frame_searches == len(rig)  # the first frame set only: windows followed the ball after
        still = rig.project(pos[-1])[0]
        assert not trk.engine.cues[0].moved([still], [10.0]).any()  # still long enough to be background: a full frame would drop it
        trk.reset()  # the background is forgotten: the next frame gives no cue
        assert trk.engine.cues[0].observe(_scene(rig, X_far, pos[-1], 1.0, 99).images[0], 1.0, need_mask=True) is None


def test_a_full_frame_search_ignores_the_cue_every_still_search_s():
    cue = MotionCue(160, 120, MotionOptions(learn_every=1, still_search_s=0.5))
    cue.observe(_frame(0), 0.0, frame=0, need_mask=True)
    assert cue.whole_frame_due(0.0)  # no cue (the first frame): the whole frame, and the time is kept
    cue.observe(_frame(1), 0.005, frame=1, need_mask=True)
    assert cue.mask is not None and not cue.whole_frame_due(0.005)  # a cue, the last whole search 5 ms ago
    cue.observe(_frame(2), 0.499, frame=2, need_mask=True)
    assert not cue.whole_frame_due(0.499)
    cue.observe(_frame(3), 0.5, frame=3, need_mask=True)
    assert cue.whole_frame_due(0.5) and not cue.whole_frame_due(0.5)  # due, then counted
    assert not cue.whole_frame_due(math.nan)  # an unknown time: the cue
    assert cue.whole_frame_due(0.2)  # the clock went back: due
    never = MotionCue(160, 120, MotionOptions(learn_every=1, still_search_s=math.inf))
    never.observe(_frame(0), 0.0, frame=0)
    never.observe(_frame(1), 0.005, frame=1, need_mask=True)
    assert not never.whole_frame_due(0.005) and not never.whole_frame_due(1e9)


@pytest.mark.parametrize("still_search_s", [0.1, math.inf])
def test_a_still_ball_never_followed_is_found_every_still_search_s(rig, model, still_search_s):
    """Full frames only (no windows to keep it): a ball lying still is found on the first frame set (no cue yet), then
    dropped as still, and found again each time the full-frame search ignores the cue; never again with ``inf``."""
    X_far, X = np.array([5.0, 5.0, 5.0]), np.array([-0.9, 0.2, 1.2])
    cue = MotionOptions(learn_every=1, still_search_s=still_search_s)
    with Tracker(rig, "rt2", model=model, roi=False, hypotheses=None, motion_cue=cue) as trk:
        ok = [trk.process(_scene(rig, X_far, X, 0.02 * f, f)).status is Status.OK for f in range(16)]  # 0.3 s at 50 Hz
    assert ok[0]
    expect = [f == 0 or (math.isfinite(still_search_s) and f % 5 == 0) for f in range(16)]  # 0.1 s = every 5th set
    assert ok == expect, ok


@pytest.mark.parametrize("value", [0, -1.0, math.nan, True, "0.5"])
def test_still_search_s_must_be_positive_seconds(value):
    with pytest.raises(ValueError, match="MotionOptions.still_search_s must be a number of seconds > 0"):
        MotionOptions(still_search_s=value)


def test_camera_cues_keep_one_background_per_camera_and_warm_frames_start_it():
    from tracker.motion import CameraCues

    cues = CameraCues(MotionOptions(learn_every=1))
    ball = lambda f: ((40.0 + 6 * f, 60.0), 10.0)  # noqa: E731
    assert cues.observe("a", _frame(0, [LAMP, ball(0)])) is None  # a camera's first frame: no cue
    assert cues.observe("b", _frame(10, [LAMP, ball(0)])) is None  # another camera: its own background
    cue = cues.observe("a", _frame(1, [LAMP, ball(1)]))
    assert cue is not None and cue.moved([ball(1)[0], LAMP[0]], [10.0, 10.0]).tolist() == [True, False]
    assert len(cues) == 2 and "a" in cues and "c" not in cues
    cues.warm("c", _frame(20, [LAMP, ball(0)]))  # a frame before those searched starts the background
    assert cues.observe("c", _frame(21, [LAMP, ball(1)])) is not None
