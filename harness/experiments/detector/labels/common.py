"""What the label formats share: the ball's name, checked numbers and boxes, finding an image named by a
label file, and placing images in a data set being written.

Every reader returns :class:`~harness.experiments.detector.coco.LabelledImage` (boxes ``[x, y, w, h]`` in
COCO's continuous pixel coordinates, the image covering ``[0, width] x [0, height]``); outside COCO the
formats store no centre of their own, so the centre is the box centre in rt2 pixels (``x + w/2 - 0.5``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
from pathlib import Path, PurePosixPath

import numpy as np

from checks.files import short
from harness.experiments.detector.coco import BALL_CATEGORY, LabelledImage

__all__ = ["BOX_TOL_PX", "IMAGE_SUFFIXES", "LabelError", "box_inside", "find_image", "image_size", "is_ball",
           "labelled", "number", "place_images"]

BOX_TOL_PX = 1e-3  # boxes may touch the image border up to rounding (as coco.py)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


class LabelError(ValueError):
    """A label file refused: the message names the file and the field."""


def is_ball(name) -> bool:
    """True for the label ``ball`` (any case, surrounding spaces ignored): the only label rt2 reads."""
    return isinstance(name, str) and name.strip().lower() == BALL_CATEGORY


def number(value, where: str, field: str) -> float:
    """``value`` as a finite float; a string is accepted only where the format stores numbers as text (XML, YOLO)."""
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise LabelError(f"{where}: field {field!r} must be a number, got {short(value)}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise LabelError(f"{where}: field {field!r} must be a finite number, got {short(value)}")
    return float(value)


def box_inside(x: float, y: float, w: float, h: float, width: int, height: int, where: str, field: str) -> list[float]:
    """``[x, y, w, h]`` checked: positive size, inside the ``width`` x ``height`` image (up to :data:`BOX_TOL_PX`)."""
    if not (w > 0 and h > 0):
        raise LabelError(f"{where}: field {field!r} must have positive width and height, got {w:g}x{h:g} px")
    if x < -BOX_TOL_PX or y < -BOX_TOL_PX or x + w > width + BOX_TOL_PX or y + h > height + BOX_TOL_PX:
        raise LabelError(f"{where}: field {field!r} box [{x:g}, {y:g}, {w:g}, {h:g}] px lies outside the {width}x{height} image")
    return [x, y, w, h]


def labelled(path: Path, width: int, height: int, boxes_xywh) -> LabelledImage:
    """A :class:`LabelledImage` whose centres are its box centres (rt2 pixels)."""
    boxes = np.array(boxes_xywh, float).reshape(-1, 4)
    centers = boxes[:, :2] + boxes[:, 2:] / 2 - 0.5
    return LabelledImage(path=path, width=width, height=height, boxes_xywh=boxes, centers_px=centers)


def image_size(path: Path, where: str) -> tuple[int, int]:
    """(width, height) of the image file ``path`` (for formats that do not store it)."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise LabelError(f"{where}: cannot read the image {str(path)!r} (not an image format OpenCV reads)")
    return int(image.shape[1]), int(image.shape[0])


def find_image(name: str, roots, where: str, field: str) -> Path:
    """The image file a label names: ``name`` (Windows separators allowed) relative to each of ``roots`` in
    turn, then its bare file name in each root. Refuses a name found nowhere, listing where it looked."""
    if not isinstance(name, str) or not name.strip():
        raise LabelError(f"{where}: field {field!r} must name an image file, got {short(name)}")
    rel = PurePosixPath(name.strip().replace("\\", "/"))
    tried = []
    for candidate in [*(Path(r) / rel for r in roots if not rel.is_absolute()), *(Path(r) / rel.name for r in roots)]:
        if candidate.is_file():
            return candidate
        tried.append(str(candidate))
    if rel.is_absolute() and Path(str(rel)).is_file():
        return Path(str(rel))
    raise LabelError(f"{where}: field {field!r} names {short(name)}, which does not exist (looked for {short(sorted(set(tried)), 300)})")


def place_images(images, out_dir: Path, sub: str = "images") -> list[LabelledImage]:
    """Copy (hard-link where possible) each image into ``out_dir/sub`` keeping the sources' folder structure
    below their common folder; an image already inside ``out_dir`` stays. Returns the images at their new paths."""
    out_dir = Path(out_dir).resolve()
    outside = [Path(li.path).resolve() for li in images if not _inside(Path(li.path).resolve(), out_dir)]
    common = Path(os.path.commonpath([str(p.parent) for p in outside])) if outside else out_dir
    placed = []
    for li in images:
        src = Path(li.path).resolve()
        if _inside(src, out_dir):
            placed.append(li)
            continue
        dst = out_dir / sub / src.relative_to(common)
        dst.parent.mkdir(parents=True, exist_ok=True)
        if not dst.exists():
            try:
                os.link(src, dst)
            except OSError:
                shutil.copy2(src, dst)
        placed.append(dataclasses.replace(li, path=dst))  # its camera, time and balls' colours kept
    return placed


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
        return True
    except ValueError:
        return False
