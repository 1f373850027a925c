"""Ball-free frames from labelled ones: every labelled ball painted out, to count false alarms on real
scenes that have no ball-free frames of their own (``rt2 eval detector --ball-free``).

Each ball's box, grown by ``margin_px`` on every side (motion-blur trails and loose boxes leave the
ball's rim outside its box), is filled by OpenCV's Telea inpainting from the pixels around it, so
the frame keeps its real background, people, lines and lamps, and no ball. A detection in such a
frame is a false alarm. The filled patch is smooth; it is not a new ball-like blob (its colour is the
surroundings' and it has no rim), which the evaluation's figures on the frames confirm or refute.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

__all__ = ["ball_free", "mask_balls", "without_balls"]


def mask_balls(image: np.ndarray, boxes_xywh, margin_px: float = 4.0) -> np.ndarray:
    """(H, W, 3) uint8 RGB copy of ``image`` with every box (COCO ``[x, y, w, h]``, grown by ``margin_px``) inpainted."""
    h, w = image.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    for x, y, bw, bh in np.asarray(boxes_xywh, float).reshape(-1, 4):
        x0, y0 = max(int(math.floor(x - margin_px)), 0), max(int(math.floor(y - margin_px)), 0)
        x1, y1 = min(int(math.ceil(x + bw + margin_px)), w), min(int(math.ceil(y + bh + margin_px)), h)
        mask[y0:y1, x0:x1] = 255
    if not mask.any():
        return image.copy()
    return cv2.inpaint(image, mask, 5, cv2.INPAINT_TELEA)


def without_balls(labelled):
    """``labelled`` (a ``LabelledImage``) with no ball: the labels of its ball-free frame."""
    return dataclasses.replace(labelled, boxes_xywh=np.zeros((0, 4)), centers_px=np.zeros((0, 2)), ball_colours=())


def ball_free(image: np.ndarray, labelled, margin_px: float = 4.0):
    """``(image with its balls inpainted, labelled without boxes)``: a ball-free frame of the same scene."""
    return mask_balls(image, labelled.boxes_xywh, margin_px), without_balls(labelled)
