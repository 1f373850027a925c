"""harness.sim.render: the synthetic multi-camera renderer (images, ground truth, determinism)."""

from __future__ import annotations

import numpy as np
import pytest

from harness.sim.lab import preview_rig
from harness.sim.render import Ball, Box, Capsule, Disk, Exposure, RenderOptions, Renderer, Scene, Sphere
from harness.sim.render.primitives import DN_PER_RADIANCE

CLEAN = RenderOptions(noise_dn=0.0, shading="flat", vignette=0.0)


@pytest.fixture(scope="module")
def rig():
    return preview_rig()


@pytest.fixture(scope="module")
def clean(rig):
    """Noise-free, flat-shaded renderer: silhouettes are pure geometry."""
    return Renderer(rig, CLEAN, seed=0)


@pytest.fixture(scope="module")
def noisy(rig):
    return Renderer(rig, RenderOptions(supersample=1), seed=3)


def _ball_weights(renderer, scene, cam=0):
    """Per-pixel contrast of the scene's balls against the empty lab, and the ground truth."""
    images, truths = renderer.render_labelled(scene)
    empty = renderer.render_camera(cam, Scene(exposure=scene.exposure, frame_index=scene.frame_index))
    w = np.abs(images[cam].astype(float) - empty.astype(float)).sum(axis=2)
    return w, truths[cam]


def _ball_coverage(renderer, scene, cam=0):
    """Per-pixel coverage of the (single, flat-shaded) ball: (image - lab) / (ball - lab) in the
    channel where the ball stands out most, so a changing background does not weight it."""
    images, truths = renderer.render_labelled(scene)
    lab = renderer.render_camera(cam, Scene(exposure=scene.exposure, frame_index=scene.frame_index)).astype(float)
    ball_dn = np.minimum(np.asarray(scene.balls[0].colour) * DN_PER_RADIANCE, 255.0)
    contrast = ball_dn - lab
    ch = np.argmax(np.abs(contrast), axis=2)[..., None]
    num = np.take_along_axis(images[cam].astype(float) - lab, ch, 2)[..., 0]
    den = np.take_along_axis(contrast, ch, 2)[..., 0]
    cov = np.where(np.abs(den) > 20, num / np.where(den == 0, 1, den), 0.0).clip(0, 1)
    return cov, truths[cam]


def _moments(w):
    v, u = np.nonzero(w)
    ww = w[v, u]
    c = np.array([(u * ww).sum(), (v * ww).sum()]) / ww.sum()
    d = np.stack([u - c[0], v - c[1]])
    cov = (d * ww) @ d.T / ww.sum()
    return c, cov


# -- smoke -----------------------------------------------------------------------------------------
def test_renders_one_rgb_image_per_camera(noisy, rig):
    scene = Scene(
        balls=(Ball([-1.2, 0.0, 1.2], [-5.0, 0.3, 1.0], "orange"),),
        capsules=(Capsule([-1.5, 0.4, 1.4], [-1.25, 0.1, 1.25], 0.04, "skin_medium"),),
        spheres=(Sphere([-1.0, -0.2, 1.1], 0.05, "white"),),
        disks=(Disk([-1.3, -0.2, 1.3], [0.3, 0.2, 1.0]),),
        boxes=(Box([-1.1, 0.2, 0.81], [0.08, 0.08, 0.1], colour="orange"),),
    )
    images = noisy.render(scene)
    assert len(images) == len(rig) == len(noisy)
    for img, cam in zip(images, rig):
        w, h = cam.image_size
        assert img.shape == (h, w, 3) and img.dtype == np.uint8 and img.flags.c_contiguous
    assert images[0].std() > 5  # not a blank image


# -- shapes and batching -----------------------------------------------------------------------------
def test_render_camera_equals_render_and_accepts_names(noisy):
    scene = Scene(balls=(Ball([-1.2, 0.05, 1.15], [3.0, 0.0, 0.0], "white"),), frame_index=4)
    all_images = noisy.render(scene)
    for i, name in enumerate(noisy.rig.names):
        np.testing.assert_array_equal(noisy.render_camera(i, scene), all_images[i])
        np.testing.assert_array_equal(noisy.render_camera(name, scene), all_images[i])
    images, truths = noisy.render_labelled(scene)
    assert len(truths) == len(noisy.rig) and all(len(t) == 1 for t in truths)
    np.testing.assert_array_equal(images[1], all_images[1])


def test_truth_fields(clean):
    _, truths = clean.render_labelled(Scene(balls=(Ball([-1.2, 0.0, 1.2]), Ball([-1.1, 0.1, 1.3], colour="white"))))
    for per_cam, cam in zip(truths, clean.rig):
        for t in per_cam:
            assert t.center_px.shape == (2,) and t.box_xywh.shape == (4,)
            x, y, w, h = t.box_xywh
            assert 0 <= x and 0 <= y and x + w <= cam.image_size[0] and y + h <= cam.image_size[1]
            assert x <= t.center_px[0] + 0.5 <= x + w and y <= t.center_px[1] + 0.5 <= y + h
            assert 0.0 <= t.visibility <= 1.0 and 6 < t.diameter_px < 14


# -- bad input -------------------------------------------------------------------------------------
def test_scene_primitives_validate():
    with pytest.raises(ValueError, match=r"Ball.position_m must have shape \(3,\), got shape \(2,\)"):
        Ball([1.0, 2.0])
    with pytest.raises(ValueError, match=r"unknown Ball.colour 'pink'; valid names: .*'orange'"):
        Ball([0, 0, 1], colour="pink")
    with pytest.raises(ValueError, match=r"Ball.velocity_mps must be finite"):
        Ball([0, 0, 1], [np.nan, 0, 0])
    with pytest.raises(ValueError, match=r"Capsule.radius_m must be a number in \(0, 2\]"):
        Capsule([0, 0, 0], [0, 0, 1], -0.1)
    with pytest.raises(ValueError, match="Disk.normal must be a non-zero vector"):
        Disk([0, 0, 1], [0, 0, 0])
    with pytest.raises(ValueError, match="Box.R_box_to_world must be a rotation matrix"):
        Box([0, 0, 1], [1, 1, 1], np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"colour must be a colour name or \(r, g, b\) in \[0, 1\], got \(2, 0, 0\)"):
        Sphere([0, 0, 1], 0.1, (2, 0, 0))
    with pytest.raises(ValueError, match=r"Scene.balls\[0\] must be a Ball, got Sphere"):
        Scene(balls=(Sphere([0, 0, 1], 0.1),))
    with pytest.raises(ValueError, match="Scene.frame_index must be a non-negative integer, got -1"):
        Scene(frame_index=-1)
    with pytest.raises(ValueError, match=r"Exposure.exposure_s must be a number in \(0, 0.1\], got 0"):
        Exposure(exposure_s=0)


def test_renderer_validates_its_inputs(rig, clean):
    with pytest.raises(ValueError, match=r"unknown RenderOptions.method 'gpu'; valid: \['numba', 'numpy'\]"):
        RenderOptions(method="gpu")
    with pytest.raises(ValueError, match=r"unknown RenderOptions.shading 'toon'"):
        RenderOptions(shading="toon")
    with pytest.raises(ValueError, match="supersample must be an integer in"):
        RenderOptions(supersample=0)
    with pytest.raises(ValueError, match="Renderer needs a tracker.Rig, got str"):
        Renderer("lab4_vga")
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -2"):
        Renderer(rig, seed=-2)
    with pytest.raises(ValueError, match="render needs a harness.sim.render.Scene, got dict"):
        clean.render({"balls": []})
    with pytest.raises(ValueError, match=r"camera index must be in \[0, 2\) or a camera name"):
        clean.render_camera(2, Scene())
    with pytest.raises(ValueError, match="unknown camera 'cam9'"):
        clean.render_camera("cam9", Scene())


# -- accuracy on synthetic scenes --------------------------------------------------------------------
def test_rendered_centre_and_diameter_follow_the_camera_model(clean):
    """Distortion on: the centroid of the ball's pixels is the projected centre within 0.3 px, and
    the covered area gives the apparent diameter within 3 %."""
    rng = np.random.default_rng(11)
    errors, ratios = [], []
    for _ in range(12):
        p = rng.uniform([-1.45, -0.25, 0.95], [-0.95, 0.25, 1.45])
        for colour in ("orange", "white"):
            scene = Scene(balls=(Ball(p, colour=colour),))
            for cam in range(2):
                cov, truth = _ball_coverage(clean, scene, cam)
                (t,) = truth
                if t.visibility < 0.999:
                    continue
                c, _ = _moments(cov)
                errors.append(np.linalg.norm(c - t.center_px))
                ratios.append(2 * np.sqrt(cov.sum() / np.pi) / t.diameter_px)
    assert len(errors) >= 30
    assert max(errors) < 0.3, f"centroid errors {np.round(errors, 3)}"
    assert np.median(errors) < 0.05
    assert np.abs(np.array(ratios) - 1).max() < 0.03, f"diameter ratios {np.round(ratios, 3)}"


def test_net_mesh_partially_hides_a_ball_behind_it(clean, rig):
    """cam0 sits behind the robot (x < 0): a ball just beyond the net is seen through the mesh."""
    front = Scene(balls=(Ball([-0.05, 0.0, 0.84]),))
    behind = Scene(balls=(Ball([0.05, 0.0, 0.84]),))
    (tf,) = clean.render_labelled(front)[1][0]
    (tb,) = clean.render_labelled(behind)[1][0]
    assert tf.visibility > 0.99
    assert 0.2 < tb.visibility < 0.8
    w_front, _ = _ball_weights(clean, front)
    w_behind, _ = _ball_weights(clean, behind)
    assert w_behind.sum() < 0.8 * w_front.sum()


def test_objects_occlude_balls_by_depth(clean):
    cam = clean.rig[0]
    p = np.array([-1.2, 0.0, 1.2])
    towards_cam = (cam.center_world - p) / np.linalg.norm(cam.center_world - p)
    side = np.cross(towards_cam, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    # a thin vertical capsule 0.3 m in front of the ball, covering half of it (offset by its edge)
    q = p + 0.3 * towards_cam + 0.0 * side
    half = Capsule(q + side * 0.02 + [0, 0, -0.2], q + side * 0.02 + [0, 0, 0.2], 0.02 * 0.7, "robot_black")
    (t_half,) = clean.render_labelled(Scene(balls=(Ball(p),), capsules=(half,)))[1][0]
    assert 0.2 < t_half.visibility < 0.8
    full = Capsule(q + [0, 0, -0.2], q + [0, 0, 0.2], 0.05, "robot_black")
    (t_full,) = clean.render_labelled(Scene(balls=(Ball(p),), capsules=(full,)))[1][0]
    assert t_full.visibility == 0.0 and not t_full.visible
    behind = Capsule(p - 0.3 * towards_cam + [0, 0, -0.2], p - 0.3 * towards_cam + [0, 0, 0.2], 0.05, "robot_black")
    (t_behind,) = clean.render_labelled(Scene(balls=(Ball(p),), capsules=(behind,)))[1][0]
    assert t_behind.visibility > 0.99
    under_table = Scene(balls=(Ball([-1.0, 0.0, 0.5]),))  # the table top hides it from above
    assert clean.render_labelled(under_table)[1][0][0].visibility == 0.0


def test_motion_blur_elongates_along_the_projected_velocity(clean):
    cam = clean.rig[0]
    p = np.array([-1.2, 0.0, 1.2])
    side = np.cross(cam.center_world - p, [0.0, 0.0, 1.0])
    v = 8.0 * side / np.linalg.norm(side) + [0.0, 0.0, 1.5]  # across the view, a little upward
    exp = Exposure(exposure_s=0.003)
    w_still, _ = _ball_weights(clean, Scene(balls=(Ball(p),), exposure=exp))
    w_fast, truth = _ball_weights(clean, Scene(balls=(Ball(p, v),), exposure=exp))
    _, cov_still = _moments(w_still)
    c_fast, cov_fast = _moments(w_fast)
    evals, evecs = np.linalg.eigh(cov_fast)
    streak = cam.project(p + v * exp.exposure_s / 2) - cam.project(p - v * exp.exposure_s / 2)
    assert np.linalg.norm(streak) > 4  # a smear of more than half a diameter
    major = evecs[:, 1]
    cos = abs(major @ streak) / np.linalg.norm(streak)
    assert cos > 0.99, f"blur axis {major} vs projected velocity {streak}"
    # a disk swept uniformly over a segment of length L adds L^2 / 12 of variance along it
    L = np.linalg.norm(streak)
    assert evals[1] - evals[0] == pytest.approx(L**2 / 12, rel=0.25)
    assert abs(evals[0] - np.linalg.eigvalsh(cov_still).mean()) < 0.15 * evals[0]
    assert np.linalg.eigvalsh(cov_still).max() / np.linalg.eigvalsh(cov_still).min() < 1.1
    # the smear is centred on the mid-exposure projection and the box covers all of it
    assert np.linalg.norm(c_fast - truth[0].center_px) < 0.5
    x, y, bw, bh = truth[0].box_xywh
    assert bw > abs(streak[0]) and bh > abs(streak[1])


def test_frames_without_a_visible_ball_have_no_box(clean):
    images, truths = clean.render_labelled(Scene(capsules=(Capsule([-1.3, 0, 1.1], [-1.1, 0, 1.3], 0.04, "skin_light"),)))
    assert truths == [(), ()]
    _, truths = clean.render_labelled(Scene(balls=(Ball([3.0, 3.0, 0.5]),)))  # far out of view
    assert all(not t[0].visible and t[0].visibility == 0.0 for t in truths)
    cam = clean.rig[0]
    behind = cam.center_world - 2.0 * cam.R_world_to_cam[2]  # 2 m behind camera 0
    (t,) = clean.render_labelled(Scene(balls=(Ball(behind),)))[1][0]
    assert np.isnan(t.center_px).all() and t.visibility == 0.0 and not t.visible


def test_static_depth_map_matches_the_table_geometry(clean):
    """The depth map's hit point of the central pixel lies on the table top (z = 0.76 m)."""
    cam = clean.rig[0]
    bg = clean.background(0)
    w, h = cam.image_size
    v, u = h // 2, w // 2
    ray_world = cam.R_world_to_cam.T @ bg.rays_cam[v, u].astype(float)
    hit = cam.center_world + bg.depth_m[v, u] * ray_world
    assert abs(hit[2] - 0.76) < 1e-3 and abs(hit[0]) < 1.37 and abs(hit[1]) < 0.76
    np.testing.assert_allclose(cam.project(hit), [u, v], atol=1e-3)  # the ray is the pixel's, distortion included


# -- statistical checks with a seeded RNG ----------------------------------------------------------
def test_same_seed_same_bytes_and_noise_varies_by_frame_and_seed(rig, noisy):
    scene = Scene(balls=(Ball([-1.2, 0.0, 1.2], [-4.0, 0.0, 0.0]),), exposure=Exposure(gain=2.0), frame_index=7)
    a = noisy.render(scene)
    b = Renderer(rig, RenderOptions(supersample=1), seed=3).render(scene)
    for x, y in zip(a, b):
        assert x.tobytes() == y.tobytes()
    other_frame = noisy.render(Scene(balls=scene.balls, exposure=scene.exposure, frame_index=8))
    other_seed = Renderer(rig, RenderOptions(supersample=1), seed=4).render(scene)
    assert not np.array_equal(a[0], other_frame[0]) and not np.array_equal(a[0], other_seed[0])


def test_noise_level_and_brightness_follow_the_exposure(rig):
    quiet = Renderer(rig, RenderOptions(noise_dn=0.0, supersample=1))
    loud = Renderer(rig, RenderOptions(noise_dn=3.0, supersample=1), seed=5)
    for gain in (1.0, 2.0):
        scene = Scene(exposure=Exposure(gain=gain), frame_index=1)
        diff = loud.render_camera(0, scene).astype(float) - quiet.render_camera(0, scene).astype(float)
        inner = diff[(quiet.render_camera(0, scene) > 10).all(axis=2) & (quiet.render_camera(0, scene) < 240).all(axis=2)]
        assert abs(inner.std() - 3.0 * gain) < 0.25 * gain and abs(inner.mean()) < 0.1 * gain
    dim = quiet.render_camera(0, Scene(exposure=Exposure(exposure_s=0.001)))
    bright = quiet.render_camera(0, Scene(exposure=Exposure(exposure_s=0.002, gain=1.5)))
    assert 2.5 < bright.mean() / dim.mean() < 3.1  # brightness 1.5 vs 0.5 (minus saturation)


def test_render_into_given_images_gives_the_same_bytes(rig, noisy):
    scenes = [Scene(balls=(Ball([-1.2, 0.1 * k, 1.2], [-4.0, 0.0, 0.0]),), exposure=Exposure(gain=1.5), frame_index=k) for k in range(3)]
    scenes.append(Scene(frame_index=9))  # no primitive: background and noise only
    outs = [np.full((c.image_size[1], c.image_size[0], 3), 77, np.uint8) for c in rig]
    for scene in scenes:
        want = noisy.render(scene)
        got = noisy.render(scene, out=outs)
        assert all(g is o for g, o in zip(got, outs))  # rendered in place, no new image
        for x, y in zip(want, got):
            assert x.tobytes() == y.tobytes()


def test_render_into_refuses_wrong_images(rig, noisy):
    w, h = rig[0].image_size
    good = [np.zeros((c.image_size[1], c.image_size[0], 3), np.uint8) for c in rig]
    scene = Scene(frame_index=0)
    bad = [
        (good[:-1], "one image per camera"),
        ([np.zeros((h, w, 3), np.float32)] + good[1:], r"out\[0\] must be"),
        ([np.zeros((h, w + 1, 3), np.uint8)] + good[1:], r"out\[0\] must be"),
        ([np.zeros((h, 2 * w, 3), np.uint8)[:, ::2]] + good[1:], r"out\[0\] must be"),
        ([np.zeros((h, w, 3), np.uint8)] + good[1:-1] + ["image"], rf"out\[{len(good) - 1}\] must be"),
    ]
    ro = np.zeros((h, w, 3), np.uint8)
    ro.setflags(write=False)
    bad.append(([ro] + good[1:], r"out\[0\] must be"))
    for out, match in bad:
        with pytest.raises(ValueError, match=match):
            noisy.render(scene, out=out)
