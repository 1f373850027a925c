"""Camera drivers: the error a source raises when it cannot open, and the checked import of a driver.

Its own module so the driver-backed sources (``opencv``, ``pylon``, ``genicam``) and
:func:`harness.live.sources.open_sources` share them without importing each other (no import cycle).
"""

from __future__ import annotations

import importlib

from harness.live.frames import SourceError

__all__ = ["CAMERAS_EXTRA", "SourceUnavailable", "require_driver"]

CAMERAS_EXTRA = "pip install 'rt2[cameras]'"


class SourceUnavailable(SourceError, ValueError):
    """A source cannot be opened: a driver is not installed or a device does not open. The message
    names the device or the extra to install. Also a ValueError, so the CLI reports it in one line."""


def require_driver(module: str, backend: str):
    """Import ``module`` for ``backend`` or raise :class:`SourceUnavailable` naming the extra to install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise SourceUnavailable(f"the {backend} camera source needs the Python package {module.split('.')[0]!r}, "
                                f"which is not installed ({exc}): {CAMERAS_EXTRA}") from None
