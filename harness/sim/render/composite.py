"""A moving ball drawn into a real camera image: the camera's lens, the image's local light, blur and noise.

Semi-real frame sets (``rt2 eval framesets --scene caliscope``) keep a real recording's frames and
calibration and add one ball of known 3D flight. Per camera, :func:`draw_ball`:

1. **lens**: the ball's silhouette is traced per sub-pixel (``SUPERSAMPLE`` x ``SUPERSAMPLE`` rays per
   pixel) through the camera's own distortion (:meth:`tracker.Camera.undistort` of every sub-pixel),
   so a ball near the edge of a wide lens is as oval as the lens makes it;
2. **motion blur**: the coverage is averaged over ``TIME_SAMPLES`` positions spread over the exposure
   (the flight's image-space velocity smears it, as a rolling-free shutter would);
3. **light**: the ball's lit colour is its reflectance times the local *white level* (the
   ``WHITE_PERCENTILE`` th percentile of the brightest channel in a window of ``STATS_WINDOW_BALLS`` ball
   diameters around it, at least ``MIN_STATS_PX``: what the brightest surfaces there reach), tinted by the window's grey-world colour cast, and shaded
   (ambient + diffuse from the scene's light direction);
4. **defocus**: the ball layer is blurred by a Gaussian whose sigma makes its edge as soft as the
   local image's sharpest edges (:func:`edge_blur_px`: contrast / (peak gradient sqrt(2 pi)), the
   sigma of a blurred step; the frame's median where the window holds no edge);
5. **noise**: Gaussian noise of the image's own local noise level (:func:`noise_sigma`, Immerkaer's
   estimator) is added where the ball covers the background (which already carries its own).

The ball is drawn in front of everything (a real object between it and the camera does not hide it).
Everything is numpy on a window around the ball; the random numbers come from the ``rng`` passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from harness.sim.render.scene_state import Ball
from harness.sim.render.textured import _undistort_grid
from harness.sim.render.truth import BallTruth, ball_truths
from tracker import Camera

__all__ = ["BallLook", "draw_ball", "edge_blur_px", "local_look", "noise_sigma"]

SUPERSAMPLE = 3  #: rays per pixel side
TIME_SAMPLES = 8  #: ball positions over the exposure
STATS_WINDOW_BALLS = 6.0  #: side of the statistics window, in ball diameters (at least MIN_STATS_PX)
MIN_STATS_PX = 128  #: light varies slowly; a dark surface behind the ball says little about the light on it
WHITE_PERCENTILE = 98  #: of the brightest channel in the window: what white (the brightest surfaces there) shows
AMBIENT, DIFFUSE = 0.45, 0.55  #: the ball's shading: ambient + diffuse (n . light)
DRAWN_EDGE_SIGMA_PX = 0.29  #: the softness the pixel-integrated silhouette already has (a 1 px box: 1 / sqrt(12))
ESTIMATOR_SPREAD_PX2 = 0.55  #: what central differences on pixels add to a measured edge's sigma^2 (a blurred step: m^2 = sigma^2 + 0.55)
MAX_DEFOCUS_PX = 4.0
MIN_EDGE_CONTRAST = 40.0  #: a window whose grey levels span less than this has no edge to measure


@dataclass(frozen=True)
class BallLook:
    """How the ball looks at one place of one image (from the image's local statistics).

    white_dn : (3,) what a white surface there shows, per channel (RGB levels)
    defocus_px : Gaussian sigma applied to the ball layer, pixels
    noise_dn : sensor noise sigma added under the ball, levels
    """

    white_dn: np.ndarray
    defocus_px: float
    noise_dn: float


def noise_sigma(gray: np.ndarray) -> float:
    """Sensor noise sigma of a grey image (levels), Immerkaer's fast estimator (1996)."""
    g = np.asarray(gray, np.float32)
    if min(g.shape) < 3:
        return 0.0
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    conv = cv2.filter2D(g, cv2.CV_32F, k)[1:-1, 1:-1]
    return float(math.sqrt(math.pi / 2) * np.abs(conv).mean() / 6.0)


def edge_blur_px(gray: np.ndarray) -> float:
    """Gaussian sigma (pixels) of the sharpest edges in a grey image: a step of contrast C blurred by
    sigma has peak gradient C / (sigma sqrt(2 pi)); C = 99th - 1st percentile of the levels, peak =
    99.5th percentile of the gradient magnitude (central differences, whose own spread
    ``ESTIMATOR_SPREAD_PX2`` is removed in quadrature). NaN when the contrast is below ``MIN_EDGE_CONTRAST``."""
    g = np.asarray(gray, np.float32)
    lo, hi = np.percentile(g, [1, 99])
    if hi - lo < MIN_EDGE_CONTRAST or min(g.shape) < 5:
        return float("nan")
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    peak = float(np.percentile(np.hypot(gx, gy), 99.5))
    if not peak > 0:
        return float("nan")
    m = float((hi - lo) / (peak * math.sqrt(2 * math.pi)))
    return math.sqrt(max(m * m - ESTIMATOR_SPREAD_PX2, 0.0))


def local_look(image: np.ndarray, center_px, diameter_px: float, *, frame_blur_px: float) -> BallLook:
    """The :class:`BallLook` at ``center_px`` (u, v) of an (H, W, 3) uint8 RGB image for a ball of
    ``diameter_px``; ``frame_blur_px``: :func:`edge_blur_px` of the whole frame (used where the window has no edge)."""
    h, w = image.shape[:2]
    half = int(max(MIN_STATS_PX, STATS_WINDOW_BALLS * diameter_px) // 2)
    cu, cv = int(round(float(center_px[0]))), int(round(float(center_px[1])))
    x0, x1 = np.clip([cu - half, cu + half], 0, w)
    y0, y1 = np.clip([cv - half, cv + half], 0, h)
    if x1 - x0 < 8 or y1 - y0 < 8:  # the ball at the image's border: the nearest inside window
        x0, x1 = (0, min(2 * half, w)) if cu < w / 2 else (max(w - 2 * half, 0), w)
        y0, y1 = (0, min(2 * half, h)) if cv < h / 2 else (max(h - 2 * half, 0), h)
    patch = image[y0:y1, x0:x1].astype(np.float32)
    gray = cv2.cvtColor(patch, cv2.COLOR_RGB2GRAY)
    level = float(np.clip(np.percentile(patch.max(axis=2), WHITE_PERCENTILE), 40.0, 255.0))
    mean = patch.reshape(-1, 3).mean(axis=0) + 1.0
    cast = np.clip(np.sqrt(mean / mean.mean()), 0.7, 1.3)  # half the grey-world cast (in log terms)
    blur = edge_blur_px(gray)
    blur = frame_blur_px if not np.isfinite(blur) else blur
    defocus = math.sqrt(max(blur * blur - DRAWN_EDGE_SIGMA_PX**2, 0.0)) if np.isfinite(blur) else 0.0
    return BallLook(level * cast, min(defocus, MAX_DEFOCUS_PX), noise_sigma(gray))


def draw_ball(image: np.ndarray, camera: Camera, ball: Ball, exposure_s: float, rng: np.random.Generator, *,
              light_dir_world, frame_blur_px: float) -> tuple[np.ndarray, BallTruth]:  # fmt: skip
    """``image`` (H, W, 3) uint8 RGB of ``camera`` with ``ball`` drawn in (module docstring); a new
    image and the ball's :class:`~harness.sim.render.truth.BallTruth` there.

    ball : position at mid-exposure and velocity, world frame; exposure_s : shutter time, seconds
    light_dir_world : (3,) direction towards the light, world frame; rng : the noise's generator
    """
    out = image.copy()
    w, h = camera.image_size
    T = float(exposure_s)
    times = (np.arange(TIME_SAMPLES) + 0.5) / TIME_SAMPLES - 0.5
    centres = ball.position_m + times[:, None] * T * ball.velocity_mps  # (S, 3) over the exposure
    r = float(ball.radius_m)
    Xc = camera.to_camera(centres)  # (S, 3)
    front = Xc[:, 2] > r
    coverage = 0.0
    if front.all():
        uv = camera.project(centres)
        dist = np.linalg.norm(Xc, axis=1)
        f = float(max(camera.K[0, 0], camera.K[1, 1]))
        rad_px = f * r / Xc[:, 2] * dist / Xc[:, 2] * 1.5 + 2  # generous: the lens can stretch the silhouette
        x0 = int(np.floor(np.min(uv[:, 0] - rad_px))); x1 = int(np.ceil(np.max(uv[:, 0] + rad_px))) + 1
        y0 = int(np.floor(np.min(uv[:, 1] - rad_px))); y1 = int(np.ceil(np.max(uv[:, 1] + rad_px))) + 1
        look = local_look(image, uv[TIME_SAMPLES // 2], 2 * f * r / Xc[TIME_SAMPLES // 2, 2], frame_blur_px=frame_blur_px)
        pad = int(math.ceil(3 * look.defocus_px))
        x0, y0 = max(x0 - pad, 0), max(y0 - pad, 0)
        x1, y1 = min(x1 + pad, w), min(y1 + pad, h)
        if x1 > x0 and y1 > y0:
            alpha, shade = _trace(camera, centres, r, x0, y0, x1, y1, light_dir_world)
            colour = np.clip(np.asarray(ball.colour, float)[None, None, :] * look.white_dn[None, None, :], 0, 255)
            premult = (alpha * shade)[..., None] * colour
            if look.defocus_px > 0.05:
                alpha = cv2.GaussianBlur(alpha, (0, 0), look.defocus_px)
                premult = cv2.GaussianBlur(premult, (0, 0), look.defocus_px)
            bg = image[y0:y1, x0:x1].astype(np.float32)
            comp = bg * (1.0 - alpha[..., None]) + premult
            comp += rng.standard_normal(comp.shape, dtype=np.float32) * (look.noise_dn * alpha[..., None])
            out[y0:y1, x0:x1] = np.clip(np.rint(comp), 0, 255).astype(np.uint8)
            coverage = float(alpha.sum())
    return out, ball_truths(camera, (ball,), T, np.array([coverage]))[0]


def _trace(camera: Camera, centres: np.ndarray, r: float, x0: int, y0: int, x1: int, y1: int, light_dir_world):
    """(h, w) float32 coverage and shading of the ball over the exposure in the window [x0, x1) x [y0, y1)."""
    s = SUPERSAMPLE
    us = x0 - 0.5 + (np.arange((x1 - x0) * s) + 0.5) / s
    vs = y0 - 0.5 + (np.arange((y1 - y0) * s) + 0.5) / s
    xn = _undistort_grid(camera, us, vs)  # exact on a 2 px grid, bilinear in between
    D = np.hstack([xn, np.ones((len(xn), 1))])
    D /= np.linalg.norm(D, axis=1, keepdims=True)  # (N, 3) unit rays, camera frame
    C = camera.to_camera(centres)  # (S, 3)
    L = camera.R_world_to_cam @ (np.asarray(light_dir_world, float) / np.linalg.norm(light_dir_world))
    hit = np.zeros(len(D), np.float32)
    shade = np.zeros(len(D), np.float32)
    for c in C:
        b = D @ c  # distance along the ray to the point nearest the centre
        d2 = c @ c - b * b
        inside = (d2 < r * r) & (b > 0)
        t = b[inside] - np.sqrt(r * r - d2[inside])
        n = (D[inside] * t[:, None] - c) / r  # outward normal at the hit
        hit[inside] += 1.0
        shade[inside] += AMBIENT + DIFFUSE * np.clip(n @ L, 0.0, None)
    alpha = hit / len(C)
    shade = np.divide(shade, hit, out=np.zeros_like(shade), where=hit > 0)
    hh, ww = (y1 - y0), (x1 - x0)
    a = alpha.reshape(hh, s, ww, s).mean(axis=(1, 3))
    sh = (shade * alpha).reshape(hh, s, ww, s).mean(axis=(1, 3))
    sh = np.divide(sh, a, out=np.zeros_like(sh), where=a > 0)
    return a.astype(np.float32), sh.astype(np.float32)
