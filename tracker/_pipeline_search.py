"""Where the rt2 pipeline searches each camera's image: the window around the predicted ball pixel,
its neighbourhood, or the full frame. The pipeline owns these decisions; the detector searches the
box it is given (``BallDetector.detect(image, window)``).

Per camera with a prediction (docs/pipeline.md, "ROI"):

1. :func:`search_boxes`: the neighbourhood, the window of half side ``h`` around the prediction plus a
   margin of ``h / 2`` (clipped to the image), is the view the detector gets; nothing is searched
   when the window lies entirely outside the image;
2. :func:`search_around`: the window inside that view first; the whole view when the window holds no
   candidate or its best candidate touches the window's edge inside the view (truncated);
3. the full frame, once per frame set, when the estimate from the windows is not confirmed
   (``TrackerOptions.retry_full_frame``; :class:`tracker._pipeline_rt2.SegmentationEngine`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["search_around", "search_boxes", "truncated"]


def search_boxes(roi_px: np.ndarray, use_window: np.ndarray, half_px: np.ndarray, wh: np.ndarray) -> np.ndarray:
    """(n_cams, 4) int ``[x0, y0, x1, y1]`` image region handed to the detector per camera.

    roi_px : (n_cams, 2) predicted pixels (NaN: none); use_window : (n_cams,) bool, search a window
    half_px : (n_cams, 1) int window half sides; wh : (n_cams, 2) int image width, height
    Rows: the neighbourhood (module docstring) where ``use_window``; ``[0, 0, W, H]`` for a full-frame
    search; ``x0 = -1`` for a window entirely outside the image (nothing to search).
    """
    margin = half_px // 2
    boxes = np.zeros((len(wh), 4), np.int64)
    boxes[:, 2:] = wh
    if use_window.any():
        c = np.rint(np.where(use_window[:, None], roi_px, 0.0)).astype(np.int64)
        inside = ((c + half_px > 0) & (c - half_px < wh)).all(axis=1)
        lo = np.clip(c - half_px - margin, 0, wh)
        hi = np.clip(c + half_px + margin, 0, wh)
        sel = use_window & inside
        boxes[sel, :2], boxes[sel, 2:] = lo[sel], hi[sel]
        boxes[use_window & ~inside, 0] = -1
    return boxes


def truncated(det, window, w: int, h: int) -> bool:
    """Whether the best candidate of ``det`` touches an edge of ``window = (x0, y0, x1, y1)`` that is
    not the image's edge (image ``w`` x ``h`` pixels): the window may have cut the ball."""
    x0, y0, x1, y1 = window
    bx, by, bw, bh = det.boxes_xywh[0] - np.array([x0, y0, 0, 0])
    bx0, by0, bx1, by1 = bx, by, bx + bw - 1, by + bh - 1
    return bool((bx0 == 0 and x0 > 0) or (by0 == 0 and y0 > 0) or (bx1 == x1 - x0 - 1 and x1 < w) or (by1 == y1 - y0 - 1 and y1 < h))


def search_around(detector, image: np.ndarray, center_px, frame_shape=None) -> "Detections":  # noqa: F821 (tracker.detection.Detections)
    """Step 2 of the module docstring: the window of half side ``detector.options.roi_half_size_px``
    around ``center_px`` (u, v) in ``image`` first, then the whole ``image`` when the window is empty,
    holds no candidate or its best one is truncated (:func:`truncated`).

    detector : :class:`~tracker.detection.BallDetector`; image : (H, W, 3) uint8 RGB (the neighbourhood
    view in the pipeline); center_px : (2,) finite predicted pixel in ``image``'s pixels; frame_shape : the
    shape of the camera frame ``image`` is a view of (the learned stage searches it at the frame's scale)
    """
    h, w = image.shape[:2]
    half = detector.options.roi_half_size_px
    cu, cv = int(round(center_px[0])), int(round(center_px[1]))
    window = (max(cu - half, 0), max(cv - half, 0), min(cu + half, w), min(cv + half, h))
    if window[0] >= window[2] or window[1] >= window[3]:  # the prediction is outside the image
        return detector.detect(image, frame_shape=frame_shape)
    det = detector.detect(image, window, frame_shape=frame_shape)
    if len(det) == 0 or truncated(det, window, w, h):
        return detector.detect(image, frame_shape=frame_shape)
    return det
