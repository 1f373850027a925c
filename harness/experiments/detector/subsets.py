"""Subsets of labelled images in time order, so a video's later frames can be held out.

Consecutive frames of a video are near copies: a random split puts copies of the evaluation frames
into training. :func:`time_order` sorts images by their file name as a time key
(:func:`checks.time_order.time_key`: natural order of the digits, with the prefixes and suffixes
labelling tools add removed), and :func:`take_range` (with :func:`checks.time_order.parse_range`)
selects a ``START:STOP`` slice of that order (``rt2 train --time-range``, ``rt2 eval detector --time-range``).
"""

from __future__ import annotations

import re
from pathlib import Path

from checks.time_order import parse_range, time_key

__all__ = ["camera_of", "image_camera", "select_cameras", "take_range", "time_order"]

#: the camera in a file name: ``f000123_cam2`` (``rt2 sim dataset``) or ``cam2_s000017`` (``rt2 label`` on a session log)
_CAMERA_SUFFIX = re.compile(r"_(cam\d+)$")
_CAMERA_PREFIX = re.compile(r"^(.+)_s\d+$")


def camera_of(path) -> str:
    """The camera of an image file name: ``cam2`` of ``f000123_cam2.png`` (``rt2 sim dataset``) or of
    ``cam2_s000017.png`` (``rt2 label`` on a session log); "" for a name without one (a one-camera set)."""
    stem = Path(path).stem
    m = _CAMERA_SUFFIX.search(stem) or _CAMERA_PREFIX.match(stem)
    return m.group(1) if m else ""


def image_camera(labelled) -> str:
    """The camera of a ``LabelledImage``: its ``camera`` field (the COCO image field rt2 writes) where it has one, else
    :func:`camera_of` its file name; "" for neither."""
    return labelled.camera or camera_of(labelled.path)


def select_cameras(labelled, names, option: str = "--camera") -> list:
    """The images of ``labelled`` whose :func:`image_camera` is one of ``names``; ValueError naming the cameras the
    set has when one is not there."""
    present = sorted({image_camera(li) for li in labelled} - {""})
    unknown = [n for n in names if n not in present]
    if unknown:
        have = ", ".join(present) or ("none (the COCO image field 'camera', as rt2 sim dataset and rt2 label --auto write it, "
                                      "or a file name like f000123_cam2.png, names an image's camera)")
        raise ValueError(f"{option} {' '.join(unknown)}: not in the labelled set; its cameras: {have}")
    wanted = set(names)
    return [li for li in labelled if image_camera(li) in wanted]


def time_order(labelled) -> list:
    """The labelled images sorted by :func:`time_key` of their paths (stable for equal keys)."""
    return sorted(labelled, key=lambda li: (str(Path(li.path).parent), time_key(li.path)))


def take_range(labelled, text: str | None, option: str = "--time-range") -> list:
    """The images at positions START:STOP of :func:`time_order` (all of them when ``text`` is None)."""
    if text is None:
        return list(labelled)
    start, stop = parse_range(text, option)
    out = time_order(labelled)[start:stop]
    if not out:
        raise ValueError(f"{option} {text}: selects no image of the {len(labelled)} given")
    return out
