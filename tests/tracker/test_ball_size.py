"""The detectors' size limits from the rig (tracker.ball_size, TrackerOptions.size_from_rig): the ball's
pixel diameter over the workspace, the limits that follow, and a near rig whose large balls the trained
limits drop while the rig's keep them; the shipped simulated rigs keep their detectors."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tests.tracker._tracker_scenes import shipped_rig
from tracker import Camera, FrameSet, Rig, Status, Tracker
from tracker.ball_size import ball_diameter_range_px, rtblob_radius_floor_px, size_limits
from tracker.detection.synthetic import draw_disk, hand_made_model


def look_at(name, centre, target, f=800.0, size=(1280, 720)):
    z = np.asarray(target, float) - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return Camera(name=name, K=[[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1]], distortion=np.zeros(5), R_world_to_cam=R,
                  t_world_to_cam_m=-R @ np.asarray(centre, float), image_size=size)


def near_rig(distance_m=1.0, half_m=0.1) -> Rig:
    """Four cameras ``distance_m`` from the origin, around it; a workspace box of half side ``half_m``."""
    cams = [look_at(f"c{i}", distance_m * np.array([math.cos(a), math.sin(a), 0.5]) / np.linalg.norm([1, 0, 0.5]), [0, 0, 0])
            for i, a in enumerate(np.deg2rad([0, 80, 170, 260]))]
    return Rig(cams, workspace_m=[[-half_m] * 3, [half_m] * 3])


def test_diameter_of_a_pinhole_camera_is_2rf_over_distance():
    rig = near_rig(1.0, 0.1)
    d = ball_diameter_range_px(rig)
    # nearest box point ~0.83-0.9 m, farthest ~1.17 m (corners); 2 r f / D with f = 800, r = 0.02
    for cam, (lo, hi) in zip(rig, d):
        dist = [np.linalg.norm(cam.center_world - c) for c in np.array(np.meshgrid(*[[-0.1, 0.1]] * 3)).reshape(3, -1).T]
        assert lo == pytest.approx(2 * 0.02 * 800 / max(dist), rel=0.02)
        assert hi >= 2 * 0.02 * 800 / min(dist) * 0.98
    assert np.allclose(ball_diameter_range_px(rig, ball_radius_m=0.01), d / 2, rtol=0.01)


def test_camera_seeing_no_workspace_gets_nan_and_keeps_its_limits():
    rig = near_rig()
    away = look_at("away", [3.0, 0, 0.5], [6.0, 0.0, 0.5])  # looks away from the box
    rig2 = Rig([*rig.cameras, away], workspace_m=rig.workspace_m)
    d = ball_diameter_range_px(rig2)
    assert np.isfinite(d[:4]).all() and np.isnan(d[4]).all()
    lim = size_limits(d, (4.02, 156.42), 32, edge_loss_px=2.8)
    assert tuple(lim.area_px[4]) == (4.02, 156.42) and lim.roi_half_size_px[4] == 32
    assert math.isnan(rtblob_radius_floor_px(d)[4])


def test_size_limits_widen_never_narrow():
    lim = size_limits([[6.0, 14.0], [20.0, 60.0], [3.0, 10.0]], (4.02, 156.42), 32, edge_loss_px=2.8)
    assert tuple(lim.area_px[0]) == (4.02, 156.42)  # inside the trained range: kept as it is
    assert lim.area_px[1, 0] == 4.02 and lim.area_px[1, 1] == math.ceil(math.pi / 4 * (60 - 2.8) ** 2)
    assert lim.area_px[2, 0] == 1.0  # a 3 px ball's blob (0.2 px wide): at least 1 px
    assert list(lim.roi_half_size_px) == [32, 60, 32]


@pytest.mark.parametrize("name", ["lab4_vga", "sim_c4", "sim_c8", "sim_c15"])
def test_shipped_simulated_rigs_keep_the_trained_limits(name):
    """On rigs whose balls the shipped model was trained on, rt2 keeps one detector with its own limits."""
    rig = shipped_rig(name)
    tr = Tracker(rig, "rt2")
    assert all(d is tr.engine.detector for d in tr.engine.detectors)
    rt = Tracker(rig, "rtblob")
    ref = Tracker(rig, "rtblob", size_from_rig=False)
    assert np.array_equal(rt.engine.rtblob.radius_px, ref.engine.rtblob.radius_px, equal_nan=True)


def _model():
    """The hand-made colour model with trained-like limits: blobs of 4-156 px, as the shipped model's."""
    return replace(hand_made_model(), area_range_px=np.array([4.0, 156.0]))


def _frameset(rig, X, t_s=0.0):
    images = []
    for cam, (lo, hi) in zip(rig, ball_diameter_range_px(rig)):
        img = np.full((cam.image_size[1], cam.image_size[0], 3), 90, np.uint8)
        uv = cam.project(X)
        draw_disk(img, uv, 2 * 0.02 * cam.K[0, 0] / cam.depth(X)[0], (245, 120, 20))
        images.append(img)
    return FrameSet(t_s, tuple(images))


def test_near_rig_large_balls_found_with_rig_limits_dropped_with_trained_ones():
    rig = near_rig(1.0, 0.1)
    assert (ball_diameter_range_px(rig)[:, 1] > 30).all()  # 30-40 px balls: blobs of ~700-1200 px
    X = np.array([0.03, -0.02, 0.05])
    fs = _frameset(rig, X)
    sized = Tracker(rig, "rt2", model=_model(), hypotheses=None)
    trained = Tracker(rig, "rt2", model=_model(), hypotheses=None, size_from_rig=False)
    obs = sized.process(fs)
    assert obs.status is Status.OK and np.linalg.norm(obs.position_m - X) < 0.005
    assert trained.process(fs).position_m is None
    # the window follows the ball: a second frame set 1 cm away is found in the windows, no full-frame retry
    X2 = X + [0.01, 0.0, 0.0]
    obs2, info = sized.process_with_info(_frameset(rig, X2, 0.005))
    assert info.used_roi.all() and not info.retried and np.linalg.norm(obs2.position_m - X2) < 0.005
    assert all(d.options.roi_half_size_px >= 30 for d in sized.engine.detectors)


def test_rtblob_template_raised_to_the_farthest_ball_on_a_near_rig():
    rig = near_rig(1.0, 0.1)
    floor = rtblob_radius_floor_px(ball_diameter_range_px(rig))
    rt = Tracker(rig, "rtblob")
    published = Tracker(rig, "rtblob", size_from_rig=False)
    assert np.allclose(published.engine.rtblob.radius_px, 800 * 0.02 / 3.0)  # sized for 3 m
    assert np.allclose(rt.engine.rtblob.radius_px, floor) and (floor > 800 * 0.02 / 3.0).all()
    X = np.array([0.03, -0.02, 0.05])
    obs = rt.process(_frameset(rig, X))
    assert np.linalg.norm(obs.position_m - X) < 0.01


def test_size_from_rig_option_is_checked():
    with pytest.raises(ValueError, match="size_from_rig must be True or False"):
        Tracker(near_rig(), "rt2", size_from_rig="yes")


@pytest.mark.parametrize("bad, match", [
    (dict(workspace_m=[[0, 0, 0], [0, 1, 1]]), "min < max"),
    (dict(workspace_m=[[0, 0], [1, 1]]), "workspace_m"),
    (dict(ball_radius_m=0.0), "ball_radius_m"),
    (dict(ball_radius_m=float("nan")), "ball_radius_m"),
])
def test_hostile_inputs(bad, match):
    with pytest.raises(ValueError, match=match):
        ball_diameter_range_px(near_rig(), **bad)


def test_rig_without_workspace_needs_a_box():
    rig = Rig(near_rig().cameras)
    with pytest.raises(ValueError, match="no workspace_m"):
        ball_diameter_range_px(rig)
    tr = Tracker(rig, "rt2")
    assert all(d is tr.engine.detector for d in tr.engine.detectors)  # no box: the detector's own limits
    with pytest.raises(ValueError, match="rig must be a tracker.Rig"):
        ball_diameter_range_px("rig.yaml")
