"""The types that cross between camera sources, the frame-set assembler and the tracking service.

One :class:`FrameSource` per camera yields :class:`Frame` objects; the assembler groups them into
:class:`AssembledFrameSet` objects (a :class:`tracker.FrameSet` plus what the network and the log
need to know about how it was put together).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from tracker import FrameSet

__all__ = ["AssembledFrameSet", "Frame", "FrameSource", "SourceError"]


class SourceError(RuntimeError):
    """A camera source cannot be opened or has failed; the message names the camera and the cause."""


@dataclass(frozen=True)
class Frame:
    """One image from one camera.

    camera : index of the camera in the rig (rig order)
    frame_id : the camera's own running frame number (hardware-triggered cameras share it), or the
        source's count where the camera gives none
    t_device_s : the camera's own timestamp, seconds on the camera's clock, or None where it gives none
        (emulated cameras report 0: backends turn that into None)
    t_host_s : ``time.monotonic()`` when the frame arrived on this host, seconds
    image : (H, W, 3) uint8 RGB
    """

    camera: int
    frame_id: int
    t_device_s: float | None
    t_host_s: float
    image: np.ndarray


@runtime_checkable
class FrameSource(Protocol):
    """One camera. ``read`` blocks at most ``timeout_s`` and returns None on a timeout;
    it raises :class:`SourceError` when the camera has failed for good and StopIteration-like end of
    a finite recording is reported by ``exhausted``."""

    camera: int
    name: str

    def start(self) -> None: ...

    def read(self, timeout_s: float) -> Frame | None: ...

    @property
    def exhausted(self) -> bool: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class AssembledFrameSet:
    """A frame set as the assembler built it.

    frameset : what the tracker consumes; images of cameras without a frame in time are None
    frame_id : the frame id the set was matched on (or the running set number when matching by time)
    t_host_s : (n_cams,) arrival stamps, NaN where no frame
    t_device_s : (n_cams,) device stamps, NaN where none
    t_assembled_s : ``time.monotonic()`` when the set was complete or timed out
    notes : e.g. ``("camera 2: no frame in time",)``
    """

    frameset: FrameSet
    frame_id: int
    t_host_s: np.ndarray
    t_device_s: np.ndarray
    t_assembled_s: float
    notes: tuple = field(default=())
