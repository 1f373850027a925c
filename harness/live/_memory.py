"""The live service keeps the memory of freed frames for the next ones (glibc only).

Every frame set allocates megabytes that are freed a few milliseconds later: the frames copied out of
a camera's buffer (0.9 MB per VGA image) and whatever the tracker allocates per set. glibc hands
blocks this large out as fresh memory maps, or trims the top of the heap after they are freed, so
every frame set touches new pages: ~200-1200 page faults and 0.3-3 ms of CPU per set on the 2-core
machine, more when it is busy. :func:`keep_freed_memory` raises glibc's map and trim thresholds, so
freed blocks stay in the process and are reused; the process's memory is then its peak, not its
current use. Process-wide and not undone: the live service's process (``rt2 track``,
``rt2 bench live``) calls it once in :func:`harness.live.run.open_service`.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["MMAP_THRESHOLD_BYTES", "TRIM_THRESHOLD_BYTES", "keep_freed_memory"]

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  #: blocks below this come from the heap (glibc's maximum)
TRIM_THRESHOLD_BYTES = 512 * 1024 * 1024  #: free memory kept at the heap's top before returning it
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)
_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Raise glibc's thresholds (module docstring) once per process; True if they are in effect
    (False on other C libraries and systems, where nothing is changed)."""
    global _applied
    if _applied is None:
        _applied = False
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                mallopt = libc.mallopt
            except (OSError, AttributeError):  # not glibc (e.g. musl has no mallopt)
                return False
            mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return _applied
