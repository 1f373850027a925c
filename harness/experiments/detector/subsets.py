"""Subsets of labelled images in time order, so a video's later frames can be held out.

Consecutive frames of a video are near copies: a random split puts copies of the evaluation frames
into training. :func:`time_order` sorts images by their file name as a time key (natural order of
the digits, with the prefixes and suffixes labelling tools add removed: Roboflow's ``train_`` /
``valid_`` / ``test_`` split prefix and ``.rf.<hash>`` suffix), and :func:`parse_range` /
:func:`take_range` select a ``START:STOP`` slice of that order (``rt2 train --time-range``,
``rt2 eval detector --time-range``).
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["camera_of", "parse_range", "take_range", "time_key", "time_order"]

_SPLIT_PREFIX = re.compile(r"^(train|valid|val|test)_", re.IGNORECASE)
_ROBOFLOW_SUFFIX = re.compile(r"\.rf\.[0-9a-f]+$", re.IGNORECASE)
#: the camera in a file name: ``f000123_cam2`` (``rt2 sim dataset``) or ``cam2_s000017`` (``rt2 label`` on a session log)
_CAMERA_SUFFIX = re.compile(r"_(cam\d+)$")
_CAMERA_PREFIX = re.compile(r"^(.+)_s\d+$")


def camera_of(path) -> str:
    """The camera of an image file name: ``cam2`` of ``f000123_cam2.png`` (``rt2 sim dataset``) or of
    ``cam2_s000017.png`` (``rt2 label`` on a session log); "" for a name without one (a one-camera set)."""
    stem = Path(path).stem
    m = _CAMERA_SUFFIX.search(stem) or _CAMERA_PREFIX.match(stem)
    return m.group(1) if m else ""


def time_key(path) -> tuple:
    """Sort key of an image file name as a time stamp: the stem without split prefix / Roboflow hash,
    digits compared as numbers (``f2`` before ``f10``)."""
    stem = _ROBOFLOW_SUFFIX.sub("", Path(path).stem)
    stem = _SPLIT_PREFIX.sub("", stem)
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", stem))


def time_order(labelled) -> list:
    """The labelled images sorted by :func:`time_key` of their paths (stable for equal keys)."""
    return sorted(labelled, key=lambda li: (str(Path(li.path).parent), time_key(li.path)))


def parse_range(text: str, option: str = "--time-range") -> tuple[int | None, int | None]:
    """``"START:STOP"`` (either may be empty; negative counts from the end) -> (start, stop)."""
    parts = str(text).split(":")
    if len(parts) != 2:
        raise ValueError(f"{option} must be START:STOP (e.g. 0:58, 58:, -25:), got {text!r}")
    try:
        return tuple(int(p) if p.strip() else None for p in parts)  # type: ignore[return-value]
    except ValueError:
        raise ValueError(f"{option} must be START:STOP with integer bounds (e.g. 0:58, 58:, -25:), got {text!r}") from None


def take_range(labelled, text: str | None, option: str = "--time-range") -> list:
    """The images at positions START:STOP of :func:`time_order` (all of them when ``text`` is None)."""
    if text is None:
        return list(labelled)
    start, stop = parse_range(text, option)
    out = time_order(labelled)[start:stop]
    if not out:
        raise ValueError(f"{option} {text}: selects no image of the {len(labelled)} given")
    return out
