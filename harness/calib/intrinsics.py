"""ChArUco views for intrinsics (``rt2 calib intrinsics``, ``rt2 calib board``): the board's corners per frame
of a video or image folder (mirrored boards too), and the one-camera result as a ``Camera``."""

from __future__ import annotations

import cv2
import numpy as np

from harness.calib.inputs import iter_frames
from tracker import Camera
from tracker.calibration.board import CharucoCorners, detect_charuco, make_detector

__all__ = ["detect_views", "intrinsics_camera"]


def detect_views(source, spec, *, every=1, max_frames=None, mirror="auto"):
    """ChArUco corners per frame of ``source``; returns (views, image_size (w, h), mirrored, frame names).

    A board seen from behind (printed on a transparent sheet, or shown mirrored) is found only in the
    left-right flipped image; its corners are detected there and mapped back to the real image
    (``mirrored`` says so), which keeps every corner at its physical place on the board.
    """
    det = make_detector(spec)
    views, names, size = [], [], None
    flips = {"no": [False], "yes": [True], "auto": [False, True]}[mirror]
    scores = {f: 0 for f in flips}
    for _, name, img in iter_frames(source, every=every, max_frames=max_frames):
        if size is None:
            size = (img.shape[1], img.shape[0])
        elif (img.shape[1], img.shape[0]) != size:
            raise ValueError(f"{name}: image size {img.shape[1]}x{img.shape[0]} differs from the first image's {size[0]}x{size[1]}")
        found = {f: detect_charuco(cv2.flip(img, 1) if f else img, spec, det) for f in flips}
        for f, v in found.items():
            scores[f] += len(v)
        views.append(found)
        names.append(name)
    if size is None:
        raise ValueError(f"{source}: no frames")
    mirrored = max(scores, key=lambda f: (scores[f], not f))
    out = [v[mirrored] for v in views]
    if mirrored:  # corners found in the flipped image, put back where they are in the real image
        out = [CharucoCorners(v.ids, np.column_stack([size[0] - 1 - v.uv[:, 0], v.uv[:, 1]]), v.n_markers) for v in out]
    return out, size, bool(mirrored), names


def intrinsics_camera(name: str, result) -> Camera:
    return Camera(name=name, K=result.K, distortion=result.distortion, R_world_to_cam=np.eye(3),
                  t_world_to_cam_m=np.zeros(3), image_size=result.image_size)
