"""Per-camera ground truth of each ball: exact projected centre, apparent size, visibility, box.

* ``center_px``: the projection of the sphere's centre at mid-exposure, lens distortion included
  (``Camera.project``): what a perfect detector should report, and what the triangulation needs.
* ``diameter_px``: diameter of the disk with the area of the ball's silhouette. The silhouette is
  the image of the tangent-cone circle (64 points, each projected exactly), so it follows the lens
  distortion and the perspective elongation toward the image edge.
* ``visibility``: the fraction of that silhouette's area that is inside the image and not hidden
  (by the static lab, the net's mesh, or the other objects), measured by the draw kernel at
  mid-exposure from the per-pixel coverage.
* ``box_xywh``: COCO box (image covers [0, W] x [0, H]) of the silhouettes at exposure start, middle
  and end (the whole smear), clipped to the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker import Camera

__all__ = ["VISIBLE_FRACTION", "BallTruth", "ball_truths"]

#: a ball counts as visible (gets a label box) from this visibility on
VISIBLE_FRACTION = 0.5
_N_RIM = 64


@dataclass(frozen=True)
class BallTruth:
    """What one camera sees of one ball.

    center_px : (2,) projected centre, rt2 pixels ((0, 0) = centre of the top-left pixel); NaN behind the camera
    diameter_px : apparent diameter (equal-area disk), pixels; NaN behind the camera
    visibility : fraction of the ball's disk inside the image and not occluded, in [0, 1]
    box_xywh : (4,) COCO box of the (smeared) ball clipped to the image; zeros when outside
    """

    center_px: np.ndarray
    diameter_px: float
    visibility: float
    box_xywh: np.ndarray

    @property
    def visible(self) -> bool:
        """True when ``visibility >= VISIBLE_FRACTION`` (the ball gets a label)."""
        return self.visibility >= VISIBLE_FRACTION


def _silhouette(camera: Camera, centre_m: np.ndarray, radius_m: float) -> np.ndarray | None:
    """(64, 2) distorted pixels of the tangent-cone circle of a sphere, or None if not in front."""
    O = camera.center_world
    w = centre_m - O
    D = float(np.linalg.norm(w))
    if D <= radius_m * 1.0001 or camera.depth(centre_m)[0] <= radius_m:
        return None
    w /= D
    e1 = np.cross(w, [0.0, 0.0, 1.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(w, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w, e1)
    k = radius_m * radius_m / (D * D)
    centre = O + (centre_m - O) * (1 - k)
    rho = radius_m * np.sqrt(1 - k)
    phi = 2 * np.pi * np.arange(_N_RIM) / _N_RIM
    pts = centre + rho * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    return camera.project(pts)


def ball_truths(camera: Camera, balls, exposure_s: float, coverage_px: np.ndarray) -> tuple[BallTruth, ...]:
    """Ground truth of ``balls`` in ``camera``.

    balls : the scene's :class:`~harness.sim.render.scene_state.Ball` objects
    exposure_s : shutter time (for the smeared box)
    coverage_px : (n_balls,) visible coverage summed over pixels, from the draw kernel
    """
    out = []
    w, h = camera.image_size
    for ball, cov in zip(balls, coverage_px):
        mid = _silhouette(camera, ball.position_m, ball.radius_m)
        if mid is None:
            out.append(BallTruth(np.full(2, np.nan), float("nan"), 0.0, np.zeros(4)))
            continue
        x, y = mid[:, 0], mid[:, 1]
        area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))  # shoelace
        rims = [mid]
        for sign in (-0.5, 0.5):
            end = _silhouette(camera, ball.position_m + sign * exposure_s * ball.velocity_mps, ball.radius_m)
            if end is not None:
                rims.append(end)
        pts = np.concatenate(rims) + 0.5  # rt2 pixels -> COCO coordinates
        x0, y0 = np.clip(pts.min(axis=0), 0, [w, h])
        x1, y1 = np.clip(pts.max(axis=0), 0, [w, h])
        box = np.array([x0, y0, x1 - x0, y1 - y0]) if (x1 > x0 and y1 > y0) else np.zeros(4)
        vis = float(np.clip(cov / area, 0.0, 1.0)) if area > 0 else 0.0
        out.append(BallTruth(camera.project(ball.position_m), float(2 * np.sqrt(area / np.pi)), vis, box))
    return tuple(out)
