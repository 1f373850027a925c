"""The full-frame search at a reduced resolution, for cameras whose ball is large in pixels.

A full-frame search costs in proportion to the frame's pixels: on a 1440x1080 camera the 5x5 filter takes
~3.5x as long as on a VGA one, and the rig's balls there are 11-55 px wide where the filter was trained on
VGA balls of 5.5-15 px. So (``TrackerOptions.full_frame_pyramid``) a camera whose smallest ball in the rig's
workspace (:mod:`tracker.ball_size`) is at least ``2^k x MIN_SEARCH_DIAMETER_PX`` wide is searched on its
frame reduced ``2^k`` times (k <= ``MAX_LEVEL``; halved k times by ``cv2.resize`` with pixel-area averaging, whose
halving has a fast path: a one-off probe timed a 1440x1080 frame reduced 4x at once at 1.6 ms, halved twice at 0.45 ms, one thread, the values
within one grey level of each other), and each candidate
is then found again in a window at the full resolution around it: its centre, score, box and area are the
full frame's, as without the pyramid (the reduced frame's, scaled, only where that window holds none).
Two candidates that land on one blob are kept once. VGA rigs (balls of 5.5-16 px) stay at level 0: their
searches are unchanged.

Measured with a probe, not a command (lab9_ace, rendered frame sets, 146 visible balls; this machine): the full-frame search 9.5 ms per
1440x1080 camera, 3.5 ms at half resolution; the ball among the candidates 145 vs 144 times.

Only for the filter's blobs: a learned stage already runs its network at its own scale of the frame.
"""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np

from tracker.detection import BallDetector
from tracker.detection.detector import Detections

__all__ = ["MAX_LEVEL", "MIN_SEARCH_DIAMETER_PX", "PyramidSearch", "pyramid_levels"]

#: the smallest ball the reduced frame may show, px: the smallest of the VGA rigs the filter was trained for
MIN_SEARCH_DIAMETER_PX = 5.5
#: at most a quarter of the resolution
MAX_LEVEL = 2
#: a refined candidate this close to an earlier one (px) is the same blob
SAME_BLOB_PX = 1.0


def pyramid_levels(min_diameters_px) -> np.ndarray:
    """(n_cams,) int levels k: the largest with ``min_diameter / 2^k >= MIN_SEARCH_DIAMETER_PX``, at most ``MAX_LEVEL``
    (0 where the smallest ball is not known: NaN)."""
    d = np.asarray(min_diameters_px, float)
    out = np.zeros(len(d), np.int64)
    ok = np.isfinite(d) & (d >= 2 * MIN_SEARCH_DIAMETER_PX)
    out[ok] = np.minimum(np.floor(np.log2(d[ok] / MIN_SEARCH_DIAMETER_PX)), MAX_LEVEL).astype(np.int64)
    return out


class PyramidSearch:
    """The full-frame search of one camera at level ``level`` (module docstring).

    detector : the camera's (sized) :class:`BallDetector`, filter only; level : >= 1
    """

    def __init__(self, detector: BallDetector, level: int):
        if detector.learned is not None:
            raise ValueError("the pyramid search is for the filter's blobs; a learned stage runs at its own scale")
        if not 1 <= level <= MAX_LEVEL:
            raise ValueError(f"pyramid level must be in [1, {MAX_LEVEL}], got {level!r}")
        self.detector, self.level, self.factor = detector, int(level), 1 << int(level)
        lo, hi = detector.area_range_px
        f2 = self.factor * self.factor
        o = detector.options
        self.reduced = BallDetector(detector.model, replace(o, min_area_px=max(1, int(math.floor(lo / f2))),
                                                            max_area_px=max(2, int(math.ceil(hi / f2)))))

    def __repr__(self) -> str:
        return f"PyramidSearch(level={self.level})"

    def detect(self, image: np.ndarray) -> Detections:
        """The candidates of the full ``image`` ((H, W, 3) uint8 RGB, trusted), in its pixels, best first."""
        f = self.factor
        h, w = image.shape[:2]
        small = image
        for _ in range(self.level):  # halvings: cv2's fast path (one 4x reduction is ~3.5x slower)
            small = cv2.resize(small, (small.shape[1] // 2, small.shape[0] // 2), interpolation=cv2.INTER_AREA)
        coarse = self.reduced.detect(small)
        if len(coarse) == 0:
            return Detections.empty()
        centres = f * (coarse.uv_px + 0.5) - 0.5  # the reduced pixel's centre in full-resolution pixels
        uv, scores, boxes, areas = [], [], [], []
        for c, box, score, area in zip(centres, coarse.boxes_xywh, coarse.scores, coarse.areas_px):
            r = f * (max(box[2], box[3]) + 2.0)  # twice the blob: its low-threshold rim reaches farther at full resolution
            window = (max(int(math.floor(c[0] - r)), 0), max(int(math.floor(c[1] - r)), 0),
                      min(int(math.ceil(c[0] + r)) + 1, w), min(int(math.ceil(c[1] + r)) + 1, h))
            fine = self.detector.detect(image, window) if window[0] < window[2] and window[1] < window[3] else Detections.empty()
            if len(fine):
                j = int(np.argmin(np.linalg.norm(fine.uv_px - c, axis=1)))
                found = (fine.uv_px[j], fine.scores[j], fine.boxes_xywh[j], fine.areas_px[j])
            else:  # the reduced frame's candidate, scaled
                found = (c, score, np.array([f * box[0], f * box[1], f * box[2], f * box[3]]), int(area) * f * f)
            if any(math.hypot(found[0][0] - u[0], found[0][1] - u[1]) <= SAME_BLOB_PX for u in uv):
                continue
            uv.append(np.asarray(found[0], float))
            scores.append(float(found[1]))
            boxes.append(np.asarray(found[2], float))
            areas.append(int(found[3]))
        return Detections(np.array(uv).reshape(-1, 2), np.array(scores), np.array(boxes).reshape(-1, 4), np.array(areas, np.int64))
