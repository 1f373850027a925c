"""Augmented copies of labelled images for ``rt2 train``: the camera, lighting and ball changes a model
must survive on cameras it never saw (domain randomisation applied to the training images).

One call of :func:`augment` draws, from the seeded ``rng``:

* geometry: a horizontal flip (p = 1/2) and a scale factor in ``scale_range`` (the boxes follow);
* colour: per-channel gains (white balance, ``wb_range``), an exposure gain (``exposure_range``),
  a gamma (``gamma_range``) and a warm or cool lamp tint over a smooth random patch (a specular-like
  highlight region, p = ``p_lamp``);
* optics: motion blur along a random direction (length up to ``motion_blur_px``) or defocus (Gaussian
  sigma up to ``defocus_sigma_px``);
* sensor: Gaussian gain noise (sigma up to ``noise_dn`` DN) and JPEG artefacts (quality in
  ``jpeg_quality``, p = ``p_jpeg``).

Ball colour itself changes with the gains, exposure and gamma (a white ball under a warm lamp turns
cream, an orange one under cool light pales), which keeps it within the range real balls show.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["AugmentOptions", "augment", "augmented_copies", "jpeg", "optics"]


@dataclass(frozen=True)
class AugmentOptions:
    """Ranges of :func:`augment` (see the module docstring); ``(lo, hi)`` pairs are uniform draws."""

    scale_range: tuple = (0.75, 1.3)
    p_flip: float = 0.5
    wb_range: tuple = (0.8, 1.2)
    exposure_range: tuple = (0.55, 1.6)
    gamma_range: tuple = (0.75, 1.35)
    p_lamp: float = 0.3
    motion_blur_px: float = 7.0
    defocus_sigma_px: float = 1.2
    noise_dn: float = 6.0
    jpeg_quality: tuple = (35, 95)
    p_jpeg: float = 0.5

    def __post_init__(self):
        for name in ("scale_range", "wb_range", "exposure_range", "gamma_range", "jpeg_quality"):
            lo, hi = getattr(self, name)
            if not (0 < lo <= hi):
                raise ValueError(f"AugmentOptions.{name} must be (lo, hi) with 0 < lo <= hi, got {getattr(self, name)!r}")
        for name in ("p_flip", "p_lamp", "p_jpeg"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"AugmentOptions.{name} must be a probability in [0, 1], got {getattr(self, name)!r}")
        for name in ("motion_blur_px", "defocus_sigma_px", "noise_dn"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"AugmentOptions.{name} must be >= 0, got {getattr(self, name)!r}")


def _motion_kernel(length: float, angle: float) -> np.ndarray:
    size = int(math.ceil(length)) | 1
    k = np.zeros((size, size), np.float32)
    c = size // 2
    dx, dy = math.cos(angle), math.sin(angle)
    for t in np.linspace(-length / 2, length / 2, 4 * size):
        k[int(round(c + t * dy)), int(round(c + t * dx))] = 1.0
    return k / k.sum()


def optics(image: np.ndarray, rng: np.random.Generator, opts: AugmentOptions) -> np.ndarray:
    """Motion blur along a random direction (p = 1/2) or else defocus, as :func:`augment` draws them."""
    if rng.random() < 0.5:
        length = float(rng.uniform(0, opts.motion_blur_px))
        if length >= 1.5:
            return cv2.filter2D(image, -1, _motion_kernel(length, float(rng.uniform(0, math.pi))), borderType=cv2.BORDER_REFLECT_101)
        return image
    sigma = float(rng.uniform(0, opts.defocus_sigma_px))
    return cv2.GaussianBlur(image, (0, 0), sigma) if sigma >= 0.3 else image


def jpeg(image: np.ndarray, rng: np.random.Generator, opts: AugmentOptions) -> np.ndarray:
    """JPEG artefacts (p = ``opts.p_jpeg``, quality in ``opts.jpeg_quality``), as :func:`augment` draws them."""
    if rng.random() < opts.p_jpeg:
        q = int(rng.integers(opts.jpeg_quality[0], opts.jpeg_quality[1] + 1))
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, q])
        if ok:
            return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    return image


def augment(image: np.ndarray, labelled, rng: np.random.Generator, opts: AugmentOptions = AugmentOptions()):
    """One augmented copy: ``(image (H', W', 3) uint8 RGB, labelled with boxes and size moved to match)``.

    image : (H, W, 3) uint8 RGB of ``labelled`` (a ``LabelledImage``; its path is kept as a name only)
    """
    h, w = image.shape[:2]
    boxes = np.array(labelled.boxes_xywh, np.float64).reshape(-1, 4)
    centers = np.array(labelled.centers_px, np.float64).reshape(-1, 2)
    s = float(rng.uniform(*opts.scale_range))
    nw, nh = max(int(round(w * s)), 8), max(int(round(h * s)), 8)
    sx, sy = nw / w, nh / h
    out = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    boxes = boxes * np.array([sx, sy, sx, sy])
    centers = (centers + 0.5) * np.array([sx, sy]) - 0.5  # rt2 pixels: (0, 0) is the centre of the first pixel
    if rng.random() < opts.p_flip:
        out = np.ascontiguousarray(out[:, ::-1])
        boxes[:, 0] = nw - boxes[:, 0] - boxes[:, 2]
        centers[:, 0] = nw - 1 - centers[:, 0]
    # optics before the sensor: blur the scene, then gains, curve, noise, compression
    out = optics(out, rng, opts)
    x = out.astype(np.float32) / 255.0
    gains = rng.uniform(*opts.wb_range, size=3) * rng.uniform(*opts.exposure_range)
    x = x * gains.astype(np.float32)
    if rng.random() < opts.p_lamp:  # a smooth warm/cool patch, as from a lamp or a specular reflection
        cy, cx = rng.uniform(0, nh), rng.uniform(0, nw)
        r = rng.uniform(0.1, 0.5) * max(nw, nh)
        yy, xx = np.mgrid[0:nh, 0:nw].astype(np.float32)
        blob = np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r))[..., None]
        tint = rng.uniform(0.0, 0.5) * np.array([1.0, rng.uniform(0.7, 1.0), rng.uniform(0.4, 1.0)], np.float32)
        if rng.random() < 0.5:
            tint = tint[::-1]
        x = x + blob * tint
    x = np.clip(x, 0.0, 1.0) ** np.float32(rng.uniform(*opts.gamma_range))
    x = x * 255.0 + rng.normal(0.0, rng.uniform(0, opts.noise_dn), size=x.shape).astype(np.float32)
    out = np.clip(np.rint(x), 0, 255).astype(np.uint8)
    out = jpeg(out, rng, opts)
    boxes[:, 2:] = np.maximum(boxes[:, 2:], 1e-3)
    boxes[:, :2] = np.clip(boxes[:, :2], 0, None)
    boxes[:, 2] = np.minimum(boxes[:, 2], nw - boxes[:, 0])
    boxes[:, 3] = np.minimum(boxes[:, 3], nh - boxes[:, 1])
    keep = (boxes[:, 2] > 0.5) & (boxes[:, 3] > 0.5)
    return out, dataclasses.replace(labelled, width=nw, height=nh, boxes_xywh=boxes, centers_px=centers).only(keep)


def augmented_copies(items, n_copies: int, rng: np.random.Generator, opts: AugmentOptions = AugmentOptions()) -> list:
    """``items`` (list of ``(image, labelled)``) plus ``n_copies`` augmented copies of each, originals first."""
    out = list(items)
    for _ in range(n_copies):
        out += [augment(im, li, rng, opts) for im, li in items]
    return out
