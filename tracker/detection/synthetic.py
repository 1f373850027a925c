"""Small synthetic ball images with exact ground truth, for tests, benchmarks and quick training checks.

Not a renderer of the lab (that is ``harness.sim.render``): a textured background, anti-aliased
coloured disks whose coverage-weighted centre is known exactly, and colour distractors
(skin-coloured ellipses, white bars) that a colour filter can confuse with the ball.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["ORANGE_RGB", "SKIN_RGB", "WHITE_RGB", "draw_disk", "hand_made_model", "synthetic_scene"]

ORANGE_RGB = (245, 120, 20)
SKIN_RGB = (205, 150, 120)
WHITE_RGB = (235, 235, 230)


def draw_disk(image: np.ndarray, center_px, diameter_px: float, colour_rgb, *, supersample: int = 8) -> None:
    """Blend an anti-aliased disk into ``image`` (H, W, 3) uint8, in place.

    center_px : (u, v) centre, pixel (0, 0) = centre of the top-left pixel
    Coverage is found by ``supersample`` x ``supersample`` sampling per pixel, so the
    coverage-weighted centroid of the disk is ``center_px`` to ~1e-3 px.
    """
    h, w = image.shape[:2]
    u, v = float(center_px[0]), float(center_px[1])
    r = diameter_px / 2.0
    x0, x1 = max(int(np.floor(u - r)) - 1, 0), min(int(np.ceil(u + r)) + 2, w)
    y0, y1 = max(int(np.floor(v - r)) - 1, 0), min(int(np.ceil(v + r)) + 2, h)
    if x0 >= x1 or y0 >= y1:
        return
    s = (np.arange(supersample) + 0.5) / supersample - 0.5
    xs = (np.arange(x0, x1)[:, None] + s[None, :]).reshape(-1)
    ys = (np.arange(y0, y1)[:, None] + s[None, :]).reshape(-1)
    inside = ((xs[None, :] - u) ** 2 + (ys[:, None] - v) ** 2) <= r * r
    cover = inside.reshape(y1 - y0, supersample, x1 - x0, supersample).mean(axis=(1, 3))[:, :, None]
    patch = image[y0:y1, x0:x1].astype(np.float64)
    blended = cover * np.asarray(colour_rgb, dtype=np.float64) + (1.0 - cover) * patch
    image[y0:y1, x0:x1] = np.clip(np.rint(blended), 0, 255).astype(np.uint8)


def synthetic_scene(
    rng: np.random.Generator,
    *,
    size_hw=(480, 640),
    n_balls: int = 1,
    diameter_px=(6.0, 20.0),
    ball_rgb=ORANGE_RGB,
    n_skin: int = 2,
    n_white: int = 2,
    noise_std: float = 3.0,
):
    """One image with ``n_balls`` coloured disks on a textured background with distractors.

    rng : the random generator (all randomness comes from it)
    size_hw : image (height, width)
    diameter_px : (min, max) ball diameter, drawn uniformly
    returns ``image`` (H, W, 3) uint8 RGB, ``centers_px`` (n_balls, 2) and ``diameters_px`` (n_balls,)
    """
    h, w = size_hw
    coarse = rng.uniform(40, 150, size=(max(h // 40, 2), max(w // 40, 2), 3))
    coarse[..., 2] += 20  # bluish-grey lab
    image = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    image += rng.normal(0, noise_std, size=image.shape)
    image = np.clip(image, 0, 255).astype(np.uint8)
    for _ in range(n_skin):  # arm-like ellipses
        c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        axes = (int(rng.uniform(20, 80)), int(rng.uniform(8, 20)))
        shade = rng.uniform(0.8, 1.1)
        colour = tuple(int(min(255, x * shade)) for x in SKIN_RGB)
        cv2.ellipse(image, c, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1, cv2.LINE_AA)
    for _ in range(n_white):  # table lines / white objects
        x, y = int(rng.uniform(0, w - 60)), int(rng.uniform(0, h - 10))
        cv2.rectangle(image, (x, y), (x + int(rng.uniform(20, 60)), y + int(rng.uniform(3, 8))), WHITE_RGB, -1)
    centers = np.empty((n_balls, 2))
    diameters = rng.uniform(diameter_px[0], diameter_px[1], size=n_balls)
    for i in range(n_balls):
        margin = diameters[i]
        centers[i] = rng.uniform([margin, margin], [w - 1 - margin, h - 1 - margin])
        draw_disk(image, centers[i], diameters[i], ball_rgb)
    return image, centers, diameters


def hand_made_model(colour_rgb=ORANGE_RGB, *, sharpness: float = 12.0):
    """A hand-set model (no training) that responds to pixels of ``colour_rgb``.

    The kernel is a colour direction on the centre tap only, so a pixel's probability depends on its
    own colour: ``logit = sharpness * (cos(colour, pixel) - 0.97)`` roughly; symmetric, hence an
    unbiased centroid. For tests and examples; trained models come from ``rt2 train``.
    """
    from tracker.detection.model import BallSegmentationModel

    c = np.asarray(colour_rgb, dtype=np.float64)
    c = c - c.mean()
    c /= np.linalg.norm(c)
    kernel = np.zeros((5, 5, 3))
    kernel[2, 2] = c * sharpness
    # input: pixel / 255 - 0.5 -> logit = sharpness * (c . (x/255 - 0.5)) + bias; c sums to zero.
    bias = -0.45 * sharpness
    return BallSegmentationModel(
        kernel=kernel,
        bias=bias,
        input_scale=np.full(3, 1 / 255),
        input_offset=np.full(3, -0.5),
        t_high=0.5,
        t_low=0.2,
        description="hand-made colour-direction model (tests)",
    )
