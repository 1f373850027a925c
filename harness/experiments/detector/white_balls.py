"""White table-tennis balls drawn into real images, with exact centres: training data we may make.

:func:`draw_white_ball` paints one ball into a window of an (H, W, 3) uint8 RGB image as a real
camera shows a flying white ball: a shaded sphere (ambient + diffuse from a random light
direction, a specular highlight), cream- or peach-tinted, as bright as the image's white level
(the brightest surfaces in the frame), smeared into a capsule by motion blur along a random direction (the coverage is
averaged over ``TIME_SAMPLES`` positions over the exposure, each traced with ``SUPERSAMPLE`` x
``SUPERSAMPLE`` rays per pixel), defocused by a Gaussian and given sensor noise where it covers the
background. :func:`random_ball` draws the random look (size, blur, colour, light) from ``rng``.

Centres use the rt2 convention ((0, 0) = centre of the top-left pixel); the ball's centre is the
middle of its blur path (the middle of the exposure), its box the capsule's bounding box (COCO
``[x, y, w, h]``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["WhiteBall", "draw_white_ball", "random_ball"]

SUPERSAMPLE = 3  #: rays per pixel side
TIME_SAMPLES = 9  #: ball positions over the exposure, at least (4 per ball radius of blur path)
WHITE_PERCENTILE = 99  #: of the brightest channel over the frame: what white shows there


@dataclass(frozen=True)
class WhiteBall:
    """The look of one drawn ball.

    center_px : (2,) centre (u, v), rt2 pixels (middle of the blur path)
    diameter_px : ball diameter, pixels
    blur_px : (2,) blur path (du, dv) over the exposure, pixels
    tint : (3,) RGB reflectance (1 = white; cream/peach balls have G, B < 1)
    brightness : lit colour = brightness * tint * the local white level
    light : (3,) unit light direction (x right, y down, z towards the camera)
    specular : highlight strength (fraction of the white level)
    defocus_px : Gaussian sigma of the ball layer, pixels
    noise_dn : sensor noise sigma under the ball, levels
    """

    center_px: tuple
    diameter_px: float
    blur_px: tuple
    tint: tuple
    brightness: float
    light: tuple
    specular: float
    defocus_px: float
    noise_dn: float


def random_ball(rng: np.random.Generator, center_px, diameter_range_px=(18.0, 34.0), max_blur_diameters: float = 1.4) -> WhiteBall:
    """A random :class:`WhiteBall` at ``center_px`` (the ranges are those of real rally frames: blur paths up
    to ``max_blur_diameters`` ball diameters, capsules up to ~2.4:1)."""
    d = float(rng.uniform(*diameter_range_px))
    length = float(max_blur_diameters * d * rng.uniform(0, 1) ** 1.2)
    ang = rng.uniform(0, 2 * math.pi)
    g = rng.uniform(0.84, 1.0)
    tint = (1.0, g, g * rng.uniform(0.72, 1.02)) if rng.uniform() < 0.75 else (rng.uniform(0.9, 1.0), rng.uniform(0.93, 1.0), 1.0)
    light = np.array([rng.uniform(-0.7, 0.7), rng.uniform(-1.0, 0.3), 1.0])
    light /= np.linalg.norm(light)
    return WhiteBall(center_px=(float(center_px[0]), float(center_px[1])), diameter_px=d,
                     blur_px=(length * math.cos(ang), length * math.sin(ang)), tint=tuple(float(t) for t in tint),
                     brightness=float(rng.uniform(0.78, 1.1)), light=tuple(float(v) for v in light),
                     specular=float(rng.uniform(0.0, 0.35)), defocus_px=float(rng.uniform(0.3, 1.8)),
                     noise_dn=float(rng.uniform(0.5, 4.0)))


def draw_white_ball(image: np.ndarray, ball: WhiteBall, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(image copy with the ball drawn in, (4,) COCO box ``[x, y, w, h]`` of the ball). image: (H, W, 3) uint8 RGB."""
    h, w = image.shape[:2]
    r = ball.diameter_px / 2
    cu, cv = ball.center_px
    bu, bv = ball.blur_px
    pad = r + 3 * ball.defocus_px + 3
    x0, x1 = max(int(math.floor(cu - abs(bu) / 2 - pad)), 0), min(int(math.ceil(cu + abs(bu) / 2 + pad)) + 1, w)
    y0, y1 = max(int(math.floor(cv - abs(bv) / 2 - pad)), 0), min(int(math.ceil(cv + abs(bv) / 2 + pad)) + 1, h)
    out = image.copy()
    if x0 >= x1 or y0 >= y1:
        return out, np.zeros(4)
    s = SUPERSAMPLE
    us = x0 - 0.5 + (np.arange((x1 - x0) * s) + 0.5) / s
    vs = y0 - 0.5 + (np.arange((y1 - y0) * s) + 0.5) / s
    uu, vv = np.meshgrid(us, vs)
    light = np.asarray(ball.light)
    half = light + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    cov = np.zeros(uu.shape)
    lit = np.zeros(uu.shape)
    n_t = max(TIME_SAMPLES, int(math.ceil(4 * math.hypot(bu, bv) / r)) + 1)
    for t in np.linspace(-0.5, 0.5, n_t):
        dx, dy = (uu - cu - t * bu) / r, (vv - cv - t * bv) / r
        rho2 = dx * dx + dy * dy
        inside = rho2 < 1.0
        nz = np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
        ndotl = np.clip(dx * light[0] + dy * light[1] + nz * light[2], 0.0, 1.0)
        ndoth = np.clip(dx * half[0] + dy * half[1] + nz * half[2], 0.0, 1.0)
        shade = 0.7 + 0.3 * ndotl + ball.specular * ndoth**40
        cov += inside
        lit += inside * shade
    cov = cv2.resize(cov / n_t, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    lit = cv2.resize(lit / n_t, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    if ball.defocus_px > 0:
        cov = cv2.GaussianBlur(cov, (0, 0), ball.defocus_px)
        lit = cv2.GaussianBlur(lit, (0, 0), ball.defocus_px)
    white = float(np.percentile(image[::8, ::8].max(axis=2), WHITE_PERCENTILE))  # the frame's white level
    white = max(white, 120.0)
    colour = ball.brightness * white * np.asarray(ball.tint)
    bg = image[y0:y1, x0:x1].astype(np.float64)
    fg = lit[:, :, None] * colour[None, None, :]
    a = cov[:, :, None]
    px = bg * (1 - a) + fg + a * rng.normal(0.0, ball.noise_dn, bg.shape)
    out[y0:y1, x0:x1] = np.clip(np.round(px), 0, 255).astype(np.uint8)
    bx0, bx1 = cu - abs(bu) / 2 - r, cu + abs(bu) / 2 + r
    by0, by1 = cv - abs(bv) / 2 - r, cv + abs(bv) / 2 + r
    box = np.array([bx0 + 0.5, by0 + 0.5, bx1 - bx0, by1 - by0])  # rt2 centres -> COCO's pixel-corner frame
    return out, box
