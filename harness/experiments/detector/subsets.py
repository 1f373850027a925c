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

__all__ = ["camera_of", "camera_sequences", "frames_before", "image_camera", "select_cameras", "sequence_key", "take_range", "time_order"]

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


def sequence_key(labelled) -> tuple:
    """The fixed camera a ``LabelledImage`` is a frame of: its :func:`image_camera` ("" for none: a one-camera set), image
    size and folder."""
    return image_camera(labelled), labelled.width, labelled.height, str(Path(labelled.path).parent)


def camera_sequences(labelled) -> list[list[int]]:
    """The indices of ``labelled`` as fixed cameras' frame sequences: one list per :func:`sequence_key`, in time order
    (:func:`time_order`'s key; stable), the cameras in the order they first appear."""
    seqs: dict = {}
    for i, li in enumerate(labelled):
        seqs.setdefault(sequence_key(li), []).append(i)
    return [sorted(idx, key=lambda i: time_key(labelled[i].path)) for idx in seqs.values()]


def frames_before(labelled, selected, n: int = 1) -> list:
    """Per camera of ``selected`` (a subset of ``labelled``, e.g. :func:`take_range`'s), the ``n`` images of ``labelled``
    of that camera (:func:`sequence_key`) just before its first selected one in time order, oldest first: what a live
    camera's stream showed before the selected frames."""
    chosen = {id(li) for li in selected}
    out = []
    for seq in camera_sequences(labelled):
        first = next((k for k, i in enumerate(seq) if id(labelled[i]) in chosen), None)
        if first:
            out.extend(labelled[i] for i in seq[max(first - n, 0):first])
    return out
