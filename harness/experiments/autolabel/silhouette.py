"""A ball's centre from its silhouette in the grey image: what the auto labels re-centre a white ball on.

The edge fit of :mod:`tracker.detection.edge_refine` fits a circle; a ball smeared over its exposure is a capsule (a
disk swept along its path), whose ends lie beyond the fit's rays, and the circle slides along the smear: on the
semi-real caliscope frames with the rally's real white balls (smeared by a median of one diameter), the labels of
smeared balls were within 1.5 px of the truth in 85.5 % of cases, round ones in 98.0 %. The truth, the ball at
mid-exposure, is the middle of the smear: the centroid of the capsule. So, around the position's projection ``uv``
with the ball's projected diameter ``d`` (radius ``r``):

1. the grey image (OpenCV's luminance, a Gaussian of ``SMOOTH_PX``) in a window of ``RING_OUT r + 3`` px about ``uv``;
2. the ball's level is the median of a core disk (``CORE r``, at least 1 px), the background's the median of a ring
   ``RING_IN r`` .. ``RING_OUT r + 2`` px away (beyond the longest smear the rig's flights make); they must differ by
   ``MIN_CONTRAST`` grey levels;
3. the pixels past ``LEVEL`` of the way from the background's level to the ball's, within ``REACH r + 2`` px, and
   of them the connected region at ``uv``: the silhouette;
4. refused (None) where it reaches ``REACH r`` (the ball merged with something as bright), touches the image's border
   (cut off), or its bounding rectangle (``cv2.minAreaRect``) is not a ball's: narrower than ``MIN_WIDTH d`` or wider
   than ``MAX_WIDTH d``, or longer than ``MAX_LENGTH d``;
5. the centre is the silhouette's centroid, each pixel once.

``LEVEL`` 0.65, not the half-way level, chosen on those frames: measured per camera by a one-off script (the 1280
labels of `rt2 eval autolabel --scene caliscope --ball white --crop-frames 58: --model data/models/ball_seg_white.npz
--frames 400 --seed 0`, each camera re-centred from the consensus's projection; the command prints the labels' figures,
not these), within 1.5 px of the truth: the edge fit 83.1 %; this, with the edge fit
where it refuses, 90.5 % at 0.65 (94 % answered here), 89.5 % at 0.5 (86 % answered), 86.8 % at 0.75, 85.9 % at 0.35;
a second, lower level grown from the 0.65 silhouette (to take in a shaded rim) lost too (80-87 %). The truth there is
the real crop's matte centroid, weighted by how far each pixel is from the background towards the ball's colour: a
shaded rim weighs less in it, as it does here. The misses left are the largest balls (>= 40 px). In the auto labels
(the consensus triangulates from three or more cameras' centres, then ``consensus.smoothed``): 88.4 -> 98.1 % within
1.5 px (README, "Labels for free").

A ball darker on one side *along its smear* moves the silhouette towards its lit end: a drawn capsule one diameter
long whose every instant's disk is 8 % darker on one side than the other (4 % brighter, 4 % darker than its middle)
came out 0.7-1.5 px off (24-50 px balls smeared over 1-1.1 diameters; 0.1 px for a round one), 16 % darker 1.1-2.3 px
(round: 0.3 px); a one-off run of the drawing of tests/harness/experiments/test_autolabel_smear.py, whose cases
(unshaded on a textured wall with a slope of light: 0.1-0.45 px) hold it within 0.5 px.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["silhouette_centre"]

SMOOTH_PX = 0.7  #: the grey image's Gaussian, px
CORE = 0.4  #: the ball's level: the median of a disk of this x r (at least 1 px)
RING_IN, RING_OUT = 3.2, 3.6  #: the background's level: the median of a ring from RING_IN r to RING_OUT r + 2 px
MIN_CONTRAST = 10.0  #: ball and background levels at least this far apart, grey levels
LEVEL = 0.65  #: the silhouette: pixels past this share of the way from the background's level to the ball's
REACH = 3.0  #: a silhouette reaching this x r from uv has merged with something else
MIN_WIDTH, MAX_WIDTH, MAX_LENGTH = 0.6, 1.25, 3.2  #: a ball's silhouette rectangle, x d (width across, length along)


def silhouette_centre(image: np.ndarray, uv, diameter_px: float) -> np.ndarray | None:
    """(2,) the centroid of the ball's silhouette near ``uv`` (rt2 pixels) in ``image`` ((H, W, 3) uint8 RGB) for a ball
    of ``diameter_px`` (module docstring), or None where there is no clear silhouette there."""
    d = float(diameter_px)
    u, v = (float(x) for x in uv)
    if not (math.isfinite(u) and math.isfinite(v) and math.isfinite(d) and d >= 2.0):
        return None
    r = 0.5 * d
    h, w = image.shape[:2]
    half = int(math.ceil(RING_OUT * r + 3.0))
    x0, y0 = max(int(math.floor(u)) - half, 0), max(int(math.floor(v)) - half, 0)
    x1, y1 = min(int(math.floor(u)) + half + 2, w), min(int(math.floor(v)) + half + 2, h)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    gray = cv2.GaussianBlur(cv2.cvtColor(np.ascontiguousarray(image[y0:y1, x0:x1]), cv2.COLOR_RGB2GRAY).astype(np.float32),
                            (0, 0), SMOOTH_PX)
    cu, cv_ = u - x0, v - y0
    yy, xx = np.mgrid[0:gray.shape[0], 0:gray.shape[1]]
    dist = np.hypot(xx - cu, yy - cv_)
    core = dist <= max(CORE * r, 1.0)
    ring = (dist >= RING_IN * r) & (dist <= RING_OUT * r + 2.0)
    if not core.any() or ring.sum() < 8:
        return None
    inner, outer = float(np.median(gray[core])), float(np.median(gray[ring]))
    if abs(inner - outer) < MIN_CONTRAST:
        return None
    level = outer + LEVEL * (inner - outer)
    mask = ((gray > level) if inner > outer else (gray < level)) & (dist <= REACH * r + 2.0)
    _, lab = cv2.connectedComponents(mask.astype(np.uint8))
    at = lab[min(max(int(round(cv_)), 0), gray.shape[0] - 1), min(max(int(round(cu)), 0), gray.shape[1] - 1)]
    if at == 0:
        return None
    sel = lab == at
    if sel[dist > REACH * r].any():
        return None
    border = (x0 == 0 and sel[:, 0].any()) or (y0 == 0 and sel[0].any()) or (x1 == w and sel[:, -1].any()) \
        or (y1 == h and sel[-1].any())
    if border:
        return None
    ys, xs = np.nonzero(sel)
    _, (a, b), _ = cv2.minAreaRect(np.column_stack([xs, ys]).astype(np.float32))
    width, length = min(a, b), max(a, b)
    if not (MIN_WIDTH * d <= width <= MAX_WIDTH * d) or length > MAX_LENGTH * d:
        return None
    return np.array([xs.mean() + x0, ys.mean() + y0])
