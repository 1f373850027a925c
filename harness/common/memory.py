"""The memory this machine can give: what a training checks before it holds its images, and before it starts
worker processes (:func:`harness.experiments.detector.train.check_memory`,
:func:`harness.experiments.detector.learned_train.auto_workers`)."""

from __future__ import annotations

__all__ = ["available_memory_bytes"]


def available_memory_bytes() -> int | None:
    """The memory the system can give a new allocation without swapping (Linux ``MemAvailable``), or None where that
    is not known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None
