"""Real ball crops (harness.sim.render.ball_crops): cut with a matte from a labelled video (a synthetic one whose
balls are known exactly, and the real rally frames of ../shared/data/real/phone_rally), and pasted where asked:
the centre recovered within 0.5 px, the matte in [0, 1] and zero on the border, seeded, bad input named."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from checks.time_order import time_key
from harness.sim.render.ball_crops import GAMMA, MIN_FIT, NEIGHBOURS, cut_ball_crops, paste_ball
from tests.conftest import REAL

RALLY = REAL / "phone_rally"
needs_rally = pytest.mark.skipif(not (RALLY / "annotations.json").is_file(), reason=f"real rally frames not found at {RALLY}")


def textured(seed=0, size=(360, 480)):
    """A static scene: smooth shading and mid-frequency texture, (H, W, 3) uint8."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.uniform(30, 110, (size[0] // 8, size[1] // 8, 3)).astype(np.float32), (0, 0), 1.5)
    img = cv2.resize(base, size[::-1], interpolation=cv2.INTER_CUBIC) + rng.normal(0, 6, (*size, 3))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def draw_white_ball(image, centre, diameter_px, blur_px, rng, defocus_px=0.6, noise_dn=1.0):
    """(copy of ``image`` with a white ball drawn at ``centre`` (u, v, rt2 pixels), its COCO box): a sphere shaded
    0.7 + 0.3 n_z (a dimmer rim, as real balls have), averaged over 9 positions along ``blur_px`` (3 x 3 rays per
    pixel), defocused, noised where it covers the background."""
    h, w = image.shape[:2]
    r, (cu, cv), (bu, bv) = diameter_px / 2, centre, blur_px
    s = 3
    us = -0.5 + (np.arange(w * s) + 0.5) / s
    vs = -0.5 + (np.arange(h * s) + 0.5) / s
    uu, vv = np.meshgrid(us, vs)
    cov, lit = np.zeros(uu.shape), np.zeros(uu.shape)
    for t in np.linspace(-0.5, 0.5, 9):
        rho2 = ((uu - cu - t * bu) ** 2 + (vv - cv - t * bv) ** 2) / (r * r)
        inside = rho2 < 1.0
        cov += inside
        lit += inside * (0.7 + 0.3 * np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0)))
    cov = cv2.GaussianBlur(cv2.resize(cov / 9, (w, h), interpolation=cv2.INTER_AREA), (0, 0), defocus_px)
    lit = cv2.GaussianBlur(cv2.resize(lit / 9, (w, h), interpolation=cv2.INTER_AREA), (0, 0), defocus_px)
    px = image * (1 - cov[..., None]) + lit[..., None] * np.array([240.0, 228.0, 205.0]) + cov[..., None] * rng.normal(0, noise_dn, image.shape)
    box = [cu - abs(bu) / 2 - r + 0.5, cv - abs(bv) / 2 - r + 0.5, abs(bu) + 2 * r, abs(bv) + 2 * r]
    return np.clip(np.rint(px), 0, 255).astype(np.uint8), np.array(box)


def video(tmp_path, n=5, blur=(0.0, 0.0), same_background=True, jitter_px=2.5):
    """A COCO set of ``n`` frames with one drawn white ball each, loose boxes; returns the exact centres by file name."""
    rng = np.random.default_rng(1)
    scene = textured()
    images, annotations, truth = [], [], {}
    for k in range(n):
        bg = scene if same_background else textured(seed=10 + k)
        c = (60.0 + 80 * k + rng.uniform(0, 1), 100.0 + 30 * k + rng.uniform(0, 1))
        img, box = draw_white_ball(bg, c, 22.0, blur, rng)
        name = f"train_frame-{k:04d}_jpg.rf.{k:08x}.png"
        cv2.imwrite(str(tmp_path / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        x, y, w, h = box
        loose = [x - rng.uniform(0, jitter_px), y - rng.uniform(0, jitter_px), w + 2 * jitter_px, h + 2 * jitter_px]
        images.append({"id": 100 - k, "file_name": name, "width": 480, "height": 360})
        annotations.append({"id": k, "image_id": 100 - k, "category_id": 1, "bbox": [float(v) for v in loose]})
        truth[name] = np.array(c)
    (tmp_path / "annotations.json").write_text(json.dumps({"images": images[::-1], "annotations": annotations,
                                                           "categories": [{"id": 1, "name": "ball"}]}))
    return truth


def global_centre(crop):
    return np.asarray(crop.origin_px, float) + crop.center_px


# -- cutting: a synthetic video whose balls are known ---------------------------------------------------


@pytest.mark.parametrize("same_background", [True, False])  # neighbour frames as background / inpainting
@pytest.mark.parametrize("blur", [(0.0, 0.0), (14.0, -6.0)])
def test_cut_recovers_the_drawn_ball(tmp_path, same_background, blur):
    truth = video(tmp_path, blur=blur, same_background=same_background)
    crops = cut_ball_crops(tmp_path)
    assert [c.source for c in crops] == sorted(truth, key=time_key)  # time order, not the file's order
    for c in crops:
        assert np.abs(global_centre(c) - truth[c.source]).max() < 0.5, (c.source, global_centre(c), truth[c.source])
        assert c.diameter_px == pytest.approx(22.0, rel=0.15)
        assert np.hypot(*c.blur_px) == pytest.approx(np.hypot(*blur), abs=4.0)
        assert c.alpha.min() >= 0 and c.alpha.max() <= 1 and c.alpha.max() > 0.9
        assert not c.alpha[[0, -1], :].any() and not c.alpha[:, [0, -1]].any()
        assert c.fit >= MIN_FIT
        assert c.rgb.dtype == np.uint8 and c.rgb.shape[:2] == c.alpha.shape == c.foreground.shape[:2]


def test_frames_by_range_and_by_id(tmp_path):
    truth = video(tmp_path)
    names = sorted(truth, key=time_key)
    assert [c.source for c in cut_ball_crops(tmp_path / "annotations.json", "1:3")] == names[1:3]
    assert [c.frame for c in cut_ball_crops(tmp_path, "-2:")] == [3, 4]
    assert [c.image_id for c in cut_ball_crops(tmp_path, [96, 100])] == [100, 96]


def test_bad_input_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no COCO file"):
        cut_ball_crops(tmp_path / "nothing.json")
    video(tmp_path)
    with pytest.raises(ValueError, match="frames must be START:STOP"):
        cut_ball_crops(tmp_path, "a:b:c")
    with pytest.raises(ValueError, match="select no image"):
        cut_ball_crops(tmp_path, "9:")
    with pytest.raises(ValueError, match=r"no image with id \[7\]"):
        cut_ball_crops(tmp_path, [7])
    data = json.loads((tmp_path / "annotations.json").read_text())
    data["annotations"][2]["bbox"] = [1, 2, -3, 4]
    (tmp_path / "annotations.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"annotations\[2\]\.bbox must be"):
        cut_ball_crops(tmp_path)
    (tmp_path / "annotations.json").write_text("{not json")
    with pytest.raises(ValueError, match="not JSON"):
        cut_ball_crops(tmp_path)


# -- pasting ----------------------------------------------------------------------------------------------


def pasted_alpha(crop, centre, diameter, **kw):
    """The matte a paste leaves, measured from the ball pasted on black and on white (no noise, no jitter)."""
    kw = {"gain": 1.0, "colour_gain": (1, 1, 1), "light_match": 0.0, "noise": False, **kw}
    black = paste_ball(np.zeros((200, 260, 3), np.uint8), crop, centre, diameter, np.random.default_rng(0), **kw)
    white = paste_ball(np.full((200, 260, 3), 255, np.uint8), crop, centre, diameter, np.random.default_rng(0), **kw)
    lin = lambda im: (im.astype(np.float64) / 255) ** GAMMA  # noqa: E731
    return np.clip(1.0 - (lin(white.image) - lin(black.image)).mean(axis=2), 0, 1), black


def centroid(a):
    v, u = np.mgrid[0:a.shape[0], 0:a.shape[1]]
    return np.array([(a * u).sum(), (a * v).sum()]) / a.sum()


@pytest.mark.parametrize("diameter,blur,defocus,angle", [(22.0, (0, 0), 0.0, 0.0), (9.5, (0, 0), 0.0, 0.0), (35.0, (12.0, 5.0), 1.0, 0.0),
                                                         (14.0, (-6.0, 9.0), 0.5, 0.0), (26.0, (0, 0), 0.0, 70.0)])
def test_paste_puts_the_ball_where_asked(tmp_path, diameter, blur, defocus, angle):
    video(tmp_path, n=3, blur=(10.0, 4.0))
    for crop in cut_ball_crops(tmp_path):
        for centre in [(101.3, 87.8), (130.55, 95.2)]:
            a, res = pasted_alpha(crop, centre, diameter, blur_px=blur, defocus_px=defocus, angle_deg=angle)
            assert np.abs(centroid(a) - centre).max() < 0.5
            assert np.allclose(res.center_px, centre)
            assert np.abs(centroid(res.alpha) - centre).max() < 0.25  # the returned matte is the one composited
            x, y, w, h = res.box_xywh
            assert x - 0.5 < centre[0] < x + w - 0.5 and w >= diameter and h >= diameter
            scale = diameter / crop.diameter_px
            assert a.sum() == pytest.approx(crop.alpha.sum() * scale**2, rel=0.05)  # blur spreads the matte, scaling scales it
            if angle:  # the crop's smear turned by the angle
                t = np.radians(angle)
                want = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]]) @ crop.blur_px
                vv, uu = np.mgrid[0:a.shape[0], 0:a.shape[1]]
                du, dv = uu - centre[0], vv - centre[1]
                cov = np.array([[(a * du * du).sum(), (a * du * dv).sum()], [(a * du * dv).sum(), (a * dv * dv).sum()]])
                axis = np.linalg.eigh(cov)[1][:, 1]
                assert abs(axis @ want) / np.linalg.norm(want) > np.cos(np.radians(5))


def test_a_small_paste_moves_smoothly_with_its_centre(tmp_path):
    """Shrunk 3-4x, a ball moved by sub-pixel steps keeps its mass and moves by the step (no aliasing)."""
    video(tmp_path, n=2)
    crop = cut_ball_crops(tmp_path)[0]
    masses, shifts = [], []
    for du in np.arange(0.0, 1.01, 0.125):
        a, _ = pasted_alpha(crop, (100.0 + du, 90.3), 6.0)
        masses.append(a.sum())
        shifts.append(centroid(a)[0] - (100.0 + du))
    assert np.ptp(masses) < 0.01 * np.mean(masses)
    assert np.ptp(shifts) < 0.05


def test_paste_is_seeded_and_random_where_asked(tmp_path):
    video(tmp_path, n=2)
    crop = cut_ball_crops(tmp_path)[0]
    img = textured(3)
    one = paste_ball(img, crop, (200.2, 150.7), 18.0, np.random.default_rng(5), blur_px=(7, 3))
    two = paste_ball(img, crop, (200.2, 150.7), 18.0, np.random.default_rng(5), blur_px=(7, 3))
    other = paste_ball(img, crop, (200.2, 150.7), 18.0, np.random.default_rng(6), blur_px=(7, 3))
    assert one.image.tobytes() == two.image.tobytes() and one.image.tobytes() != other.image.tobytes()
    assert np.array_equal(img, textured(3))  # the input is not changed
    far = one.alpha == 0
    assert np.array_equal(one.image[far], img[far])  # only the ball's pixels change


def test_paste_refuses_bad_input(tmp_path):
    video(tmp_path, n=2)
    crop = cut_ball_crops(tmp_path)[0]
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="uint8 RGB"):
        paste_ball(np.zeros((50, 50), np.uint8), crop, (10, 10), 10, rng)
    with pytest.raises(ValueError, match="diameter_px must be > 0"):
        paste_ball(np.zeros((50, 50, 3), np.uint8), crop, (10, 10), -1, rng)
    out = paste_ball(np.zeros((50, 50, 3), np.uint8), crop, (500, 500), 10, rng)  # off the image: unchanged
    assert not out.image.any() and not out.alpha.any()


# -- the real rally frames ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rally_crops():
    return cut_ball_crops(RALLY)


@needs_rally
def test_real_rally_balls(rally_crops):
    data = json.loads((RALLY / "annotations.json").read_text())
    boxes = {a["image_id"]: np.array(a["bbox"]) for a in data["annotations"]}
    assert len(rally_crops) == 83
    good = [c for c in rally_crops if c.fit >= MIN_FIT]
    assert len(good) >= 65  # a dozen balls sit in a hand, on a bat or behind one
    for c in rally_crops:
        assert 0 <= c.alpha.min() and c.alpha.max() <= 1 and not c.alpha[[0, -1], :].any() and not c.alpha[:, [0, -1]].any()
        x, y, w, h = boxes[c.image_id]
        u, v = global_centre(c)
        assert x - 3 <= u + 0.5 <= x + w + 3 and y - 3 <= v + 0.5 <= y + h + 3  # inside the loose box
    for c in good:  # the README: 21-54 px boxes around balls smeared by motion; the ball's own width is smaller
        assert 10 <= c.diameter_px <= 32 and c.contrast_dn > 10
    d = np.median([c.diameter_px for c in good])
    assert 16 <= d <= 24
    early = cut_ball_crops(RALLY, "0:58")
    assert [c.frame for c in early] == list(range(58)) and {c.source for c in early} < {c.source for c in rally_crops}
    for c in early:  # the neighbouring frames tried as background stay inside the range: only its end differs
        ref = next(r for r in rally_crops if r.source == c.source)
        assert np.allclose(c.center_px, ref.center_px, atol=0.01 if c.frame < 58 - NEIGHBOURS else 0.5)


@needs_rally
def test_real_crops_pasted_where_asked(rally_crops):
    for crop in [c for c in rally_crops if c.fit >= MIN_FIT][::7]:
        for d in (8.0, 20.0, 40.0):
            a, _ = pasted_alpha(crop, (129.4, 99.6), d, blur_px=(5.0, -2.0))
            assert np.abs(centroid(a) - (129.4, 99.6)).max() < 0.5, (crop.source, d, centroid(a))
