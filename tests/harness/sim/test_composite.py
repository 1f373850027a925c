"""A ball drawn into a real-like image (harness.sim.render.composite): the local statistics it is matched
to (noise, edge blur, white level) measured right on images of known noise and blur, the ball drawn
where its truth says through a distorted lens, smeared along its image velocity, seeded."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from harness.sim.render.composite import draw_ball, edge_blur_px, local_look, noise_sigma
from harness.sim.render.scene_state import Ball
from tracker import Camera


def camera(k1=-0.25):
    return Camera(name="c", K=[[700.0, 0, 640], [0, 700.0, 360], [0, 0, 1]], distortion=[k1, 0.05, 0, 0, 0],
                  R_world_to_cam=np.eye(3), t_world_to_cam_m=np.zeros(3), image_size=(1280, 720))


def grey(level=120, sigma=0.0, seed=0):
    img = np.full((720, 1280, 3), float(level))
    img += np.random.default_rng(seed).normal(0, sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("sigma", [1.0, 3.0, 6.0])
def test_noise_sigma_measures_added_noise(sigma):
    img = grey(120, sigma)[:200, :200, 0]
    assert noise_sigma(img) == pytest.approx(sigma, rel=0.15)


@pytest.mark.parametrize("blur", [1.0, 2.0, 3.0])
def test_edge_blur_of_a_blurred_step(blur):
    img = np.full((120, 120), 40.0, np.float32)
    img[:, 60:] = 200.0
    img = cv2.GaussianBlur(img, (0, 0), blur)
    assert edge_blur_px(img) == pytest.approx(blur, rel=0.2)
    assert np.isnan(edge_blur_px(np.full((50, 50), 90.0)))  # no edge: nothing to measure


def _centroid(before, after):
    d = np.abs(after.astype(float) - before.astype(float)).sum(axis=2)
    ys, xs = np.nonzero(d > 3)
    return np.array([xs.mean(), ys.mean()]), d  # the silhouette's centre (shading would pull a weighted one to the lit side)


def test_ball_drawn_where_its_truth_is_through_a_distorted_lens():
    cam, bg = camera(), grey(110)
    for X in ([0.0, 0.0, 1.0], [0.35, -0.2, 1.0], [-0.4, 0.25, 1.2]):
        ball = Ball(position_m=np.array(X), velocity_mps=np.zeros(3))
        img, truth = draw_ball(bg, cam, ball, 0.002, np.random.default_rng(0), light_dir_world=[0, -1, 0], frame_blur_px=0.5)
        c, d = _centroid(bg, img)
        assert np.linalg.norm(c - truth.center_px) < 0.3
        area = (d > 3).sum()
        assert 2 * np.sqrt(area / np.pi) == pytest.approx(truth.diameter_px, rel=0.1)
        assert truth.visible and truth.diameter_px == pytest.approx(2 * 0.02 * 700 / np.linalg.norm(X), rel=0.1)
        r, g, b = img[int(round(truth.center_px[1])), int(round(truth.center_px[0]))].astype(int)
        assert r > g > b  # orange


def test_motion_blur_along_the_image_velocity_and_same_seed_same_bytes():
    cam, bg = camera(0.0), grey(110, 2.0)
    ball = Ball(position_m=np.array([0.0, 0.0, 1.0]), velocity_mps=np.array([5.0, 0.0, 0.0]))
    a, _ = draw_ball(bg, cam, ball, 0.01, np.random.default_rng(3), light_dir_world=[0, -1, 0], frame_blur_px=0.5)
    b, _ = draw_ball(bg, cam, ball, 0.01, np.random.default_rng(3), light_dir_world=[0, -1, 0], frame_blur_px=0.5)
    assert np.array_equal(a, b)
    _, d = _centroid(bg, a)
    ys, xs = np.nonzero(d > 20)
    assert np.ptp(xs) > np.ptp(ys) + 0.8 * 5.0 * 0.01 * 700  # 35 px of smear along u
    c, _ = draw_ball(bg, cam, ball, 0.01, np.random.default_rng(4), light_dir_world=[0, -1, 0], frame_blur_px=0.5)
    assert not np.array_equal(a, c)


def test_ball_follows_local_light_and_sharpness():
    cam = camera(0.0)
    dark, bright = grey(40), grey(200)
    ball = Ball(position_m=np.array([0.0, 0.0, 1.0]))
    for bg in (dark, bright):
        img, t = draw_ball(bg, cam, ball, 0.002, np.random.default_rng(0), light_dir_world=[0, 0, -1], frame_blur_px=0.5)
        centre = img[360, 640].astype(int)
        assert centre[0] <= max(40, local_look(bg, t.center_px, t.diameter_px, frame_blur_px=0.5).white_dn[0]) + 1
    lo = draw_ball(dark, cam, ball, 0.002, np.random.default_rng(0), light_dir_world=[0, 0, -1], frame_blur_px=0.5)[0][360, 640, 0]
    hi = draw_ball(bright, cam, ball, 0.002, np.random.default_rng(0), light_dir_world=[0, 0, -1], frame_blur_px=0.5)[0][360, 640, 0]
    assert hi > 2 * lo
    sharp = local_look(bright, (640, 360), 28.0, frame_blur_px=0.5)
    soft = local_look(bright, (640, 360), 28.0, frame_blur_px=2.5)  # a flat window: the frame's sharpness
    assert sharp.defocus_px < 0.5 < 2.0 < soft.defocus_px


def test_ball_behind_the_camera_is_not_drawn():
    cam, bg = camera(), grey(110)
    img, t = draw_ball(bg, cam, Ball(position_m=np.array([0.0, 0.0, -1.0])), 0.002, np.random.default_rng(0),
                       light_dir_world=[0, -1, 0], frame_blur_px=0.5)
    assert np.array_equal(img, bg) and not t.visible
