"""Types that leave ``tracker``: what a frame set is, and what a tracker reports for it.

These cross folder boundaries (harness, policies, logs), so they are small, immutable and
documented in docs/architecture.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

__all__ = ["BallObservation", "FrameSet", "Status"]


class Status(StrEnum):
    """Outcome of one robust estimate (and of one tracked frame set)."""

    OK = "ok"  #: a position confirmed by at least ``min_support`` cameras
    LOW_SUPPORT = "low_support"  #: a position, but fewer than ``min_support`` cameras agree
    NO_CONSENSUS = "no_consensus"  #: observations exist but no two cameras agree
    TOO_FEW_OBSERVATIONS = "too_few_observations"  #: fewer than two cameras saw a candidate

    @property
    def has_position(self) -> bool:
        return self in (Status.OK, Status.LOW_SUPPORT)


@dataclass(frozen=True)
class FrameSet:
    """Synchronised images of one instant, one per rig camera, in rig order.

    t_s : capture time, seconds (monotonic clock of the acquisition)
    images : per camera an (H, W, 3) uint8 RGB image, or None where the camera delivered no frame
    index : running frame-set number
    """

    t_s: float
    images: tuple
    index: int = 0


@dataclass(frozen=True)
class BallObservation:
    """One tracker output per frame set.

    t_s : capture time of the frame set, seconds
    position_m : (3,) ball centre in the world frame, metres, or None when no position is reported
    covariance_m2 : (3, 3) covariance of ``position_m`` propagated from pixel noise, or None
    support : number of cameras that agree on the position
    inliers : (n_cams,) bool, the cameras used
    status : :class:`Status`
    latency_s : processing time from frame-set arrival to this observation, seconds
    tracker : which tracker produced it (``rt2``, ``rt2-paper``, ``rtblob``)
    uv_px : (n_cams, 2) the pixel used per camera (NaN where none), distorted pixels
    notes : free-form flags, e.g. ``("camera cam2: no frame",)``
    """

    t_s: float
    position_m: np.ndarray | None
    covariance_m2: np.ndarray | None
    support: int
    inliers: np.ndarray
    status: Status
    latency_s: float
    tracker: str
    uv_px: np.ndarray | None = None
    notes: tuple = ()

    @property
    def has_position(self) -> bool:
        return self.position_m is not None
