"""File names as time stamps: the time order of a video's frames from their names, and ``START:STOP`` ranges of it.

Consecutive frames of a video are near copies, so data sets are split by time, not at random. The
order is the file name's (natural order of the digits, with the prefixes and suffixes labelling
tools add removed: Roboflow's ``train_`` / ``valid_`` / ``test_`` split prefix and ``.rf.<hash>``
suffix). Pure string work, here at the bottom so the simulated lab (real ball crops cut from a
labelled video) and the detector's data (``--time-range``) use the same order.
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["parse_range", "time_key"]

_SPLIT_PREFIX = re.compile(r"^(train|valid|val|test)_", re.IGNORECASE)
_ROBOFLOW_SUFFIX = re.compile(r"\.rf\.[0-9a-f]+$", re.IGNORECASE)


def time_key(path) -> tuple:
    """Sort key of an image file name as a time stamp: the stem without split prefix / Roboflow hash,
    digits compared as numbers (``f2`` before ``f10``)."""
    stem = _ROBOFLOW_SUFFIX.sub("", Path(path).stem)
    stem = _SPLIT_PREFIX.sub("", stem)
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", stem))


def parse_range(text: str, option: str = "--time-range") -> tuple[int | None, int | None]:
    """``"START:STOP"`` (either may be empty; negative counts from the end) -> (start, stop)."""
    parts = str(text).split(":")
    if len(parts) != 2:
        raise ValueError(f"{option} must be START:STOP (e.g. 0:58, 58:, -25:), got {text!r}")
    try:
        return tuple(int(p) if p.strip() else None for p in parts)  # type: ignore[return-value]
    except ValueError:
        raise ValueError(f"{option} must be START:STOP with integer bounds (e.g. 0:58, 58:, -25:), got {text!r}") from None
