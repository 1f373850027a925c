"""Is this a usable camera frame? The one image check of the tracker, applied once where images come in.

:class:`~tracker.pipeline.Tracker` checks every image of a frame set (:func:`image_problem`: a wrong
type, shape, dtype or size is a note and the camera is skipped for that frame set); the per-camera
steps after it (:class:`~tracker.detection.BallDetector`, RTBlob's detectors) trust their inputs.
Public entry points that take a single image (``BallSegmentationModel.logits``, ``RTBlobDetector.detect``)
raise with :func:`check_image`.
"""

from __future__ import annotations

import numpy as np

from checks.arrays import describe

__all__ = ["check_image", "image_problem"]


def image_problem(image, image_size: tuple[int, int] | None = None, name: str = "image"):
    """Why ``image`` cannot be used, or None.

    image : anything; a usable one is a non-empty (H, W, 3) uint8 RGB numpy array
    image_size : (width, height) pixels the camera is calibrated for, or None (any size)
    Returns None, ``("type", message)`` for anything that is not a non-empty (H, W, 3) uint8 array,
    or ``("size", message)`` for a valid image of another size than ``image_size``.
    """
    if not isinstance(image, np.ndarray):
        return "type", f"{name} must be an (H, W, 3) uint8 RGB array, got {describe(image)}"
    if image.ndim != 3 or image.shape[2] != 3:
        return "type", f"{name} must be an (H, W, 3) uint8 RGB array, got shape {image.shape}"
    if image.dtype != np.uint8:
        return "type", f"{name} must have dtype uint8 (8-bit RGB), got dtype {image.dtype}"
    if image.shape[0] == 0 or image.shape[1] == 0:
        return "type", f"{name} is empty: shape {image.shape}"
    if image_size is not None:
        w, h = image_size
        if image.shape[:2] != (h, w):
            return "size", f"{name} is {image.shape[1]}x{image.shape[0]} px but the camera is calibrated for {w}x{h}"
    return None


def check_image(image, name: str = "image", image_size: tuple[int, int] | None = None) -> np.ndarray:
    """``image`` unchanged (no copy) when :func:`image_problem` finds nothing; else ``ValueError`` with its message."""
    problem = image_problem(image, image_size, name)
    if problem is not None:
        raise ValueError(problem[1])
    return image
