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

    def unreported(self) -> "Status":
        """The status of a frame set reported without the position its estimate held (its full frames deferred):
        a status with a position becomes ``no_consensus``."""
        return Status.NO_CONSENSUS if self.has_position else self


#: the note of a frame set whose full frames were searched after it was reported (``TrackerOptions.defer_full_frame``):
#: reported without a position, its windows' candidates (if any) logged as searched
DEFERRED_NOTE = "searched after this frame set was reported"
#: the note (its beginning) of a frame set that came while a deferred full-frame search still ran: not searched at all
NOT_SEARCHED_NOTE = "not searched: "


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

    @property
    def full_frames_deferred(self) -> bool:
        """Whether this frame set's full frames were searched after it was reported (:data:`DEFERRED_NOTE`)."""
        return any(DEFERRED_NOTE in n for n in self.notes)

    @property
    def not_searched(self) -> bool:
        """Whether this frame set came while a deferred full-frame search ran and was not searched (:data:`NOT_SEARCHED_NOTE`)."""
        return any(n.startswith(NOT_SEARCHED_NOTE) for n in self.notes)
