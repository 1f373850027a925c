"""The numba draw kernel against its plain-numpy reference, and the renderer on a real lens model."""

from __future__ import annotations

import numpy as np
import pytest

from harness.sim.lab import preview_rig
from harness.sim.render import Ball, RenderOptions, Renderer, Scene
from harness.sim.render.scenes import SceneOptions, random_scene


@pytest.fixture(scope="module")
def pair():
    rig = preview_rig(160, 120)
    return (
        Renderer(rig, RenderOptions(noise_dn=0.0, supersample=1, method="numba")),
        Renderer(rig, RenderOptions(noise_dn=0.0, supersample=1, method="numpy")),
    )


def test_numba_and_numpy_kernels_agree_on_random_scenes(pair):
    """Every primitive type, occlusions, the net veil, motion blur: same pixels (up to one grey
    level of rounding) and the same ball coverage."""
    fast, ref = pair
    opts = SceneOptions(p_no_ball=0.0, p_person=1.0, p_robot=1.0, p_racket=1.0, p_second_ball=0.5, max_distractors=6)
    box = fast.rig.workspace_m
    n_pixels_drawn = 0
    for f in range(12):
        scene = random_scene(np.random.default_rng([21, f]), box, opts, frame_index=f)
        (ia, ta), (ib, tb) = fast.render_labelled(scene), ref.render_labelled(scene)
        empty = fast.render(Scene(exposure=scene.exposure))
        for x, y, e, tx, ty in zip(ia, ib, empty, ta, tb):
            d = np.abs(x.astype(int) - y.astype(int))
            assert d.max() <= 1 and (d > 0).mean() < 1e-3
            n_pixels_drawn += int((x != e).any(axis=2).sum())
            for p, q in zip(tx, ty):
                assert p.visibility == pytest.approx(q.visibility, abs=1e-6)
                np.testing.assert_array_equal(p.box_xywh, q.box_xywh)
    assert n_pixels_drawn > 5000  # the scenes did draw things


def test_ball_on_a_real_calibrated_lens(ewand_rig):
    """Real-data check: a camera of the ewand lab (1280x1024, its own plumb_bob calibration). The
    rendered ball's coverage centroid equals OpenCV's projection of the centre (cv2.projectPoints)."""
    import cv2

    cam = ewand_rig[1]
    rig = ewand_rig.subset([cam.name])
    renderer = Renderer(rig, RenderOptions(noise_dn=0.0, supersample=1, shading="flat", vignette=0.0))
    rng = np.random.default_rng(2)
    w, h = cam.image_size
    for _ in range(4):
        uv = rng.uniform([0.15 * w, 0.15 * h], [0.85 * w, 0.85 * h])
        X = cam.center_world + 2.5 * cam.rays_world(uv)[0]
        scene = Scene(balls=(Ball(X, colour="white"),))
        img = renderer.render_camera(0, scene).astype(float)
        lab = renderer.render_camera(0, Scene()).astype(float)
        cov = np.clip((img - lab)[..., 1] / (0.92 * 200 - lab[..., 1]).clip(20, None), 0, 1)
        v, u = np.nonzero(cov)
        centroid = np.array([(u * cov[v, u]).sum(), (v * cov[v, u]).sum()]) / cov[v, u].sum()
        rvec = cv2.Rodrigues(cam.R_world_to_cam)[0]
        ref = cv2.projectPoints(X.reshape(1, 3), rvec, cam.t_world_to_cam_m, cam.K, cam.distortion)[0].ravel()
        assert np.linalg.norm(centroid - ref) < 0.3
