"""The real-time tracking pipeline: one frame set in, one trustworthy ball observation out.

    tracker = Tracker(rig, "rt2")                  # or make_tracker("rt2-paper", rig), "rtblob"
    obs = tracker.process(FrameSet(t_s, images))   # BallObservation: position, covariance, status, ...
    tracker.reset()                                # forget the motion (new rally, new recording)

Kinds (``TRACKER_KINDS``):

* ``rt2`` (ours): the segmentation detector with top-K candidates per camera (``method="ours"``),
  searched first in a window around the predicted ball pixel (ROI, ``tracker._pipeline_roi``),
  then :class:`RobustTriangulator` ``method="ours"`` (Algorithm 2 extended), then the 3D size test
  (``TrackerOptions.max_size_ratio``: a position whose blobs are too wide for a ball at its depth
  is dropped and the estimate redone), the ball hypotheses (``TrackerOptions.hypotheses``: several
  balls in view are tracked in 3D and the one in play is reported, ``tracker.hypotheses``), then the
  support hand-over (``TrackerOptions.handover_max_age_s``: an estimate left with too few cameras is
  moved by those cameras' offset from the last confirmed positions, ``tracker.handover``).
* ``rt2-paper``: the paper's system: Algorithm 1 as published (argmax, one candidate) on the full
  frame, Algorithm 2 as published (``method="paper"``), no ROI.
* ``rtblob``: the RTBlob baseline (:class:`RTBlobTracker`), with the same fault handling.

Kinds are a registry (``KINDS``: name -> :class:`TrackerKind`), each with an engine behind one
protocol (:class:`TrackerEngine`): :class:`~tracker._pipeline_rt2.SegmentationEngine` for the rt2
kinds, :class:`~tracker._pipeline_rtblob.RTBlobEngine` for rtblob. An unknown kind raises
``ValueError`` listing the valid ones.

Per frame set, :class:`Tracker` itself checks the frame set (``ValueError`` for a wrong type or
camera count), its time (not finite or not increasing: a note, the motion forgotten) and every image
once (:func:`tracker.images.image_problem`: a camera without a usable frame is skipped and named in
the notes); the engine then does the kind's work on the usable cameras, trusting its inputs
(rt2: predict the ball's pixels, one detector call per camera, optionally on a thread pool, the
consensus with the size test as its last stage, a full-frame search of the cameras that used a
window when it did not confirm the ball, the ball hypotheses and the support hand-over).
See docs/pipeline.md and docs/architecture.md ("The path of one frame").
"""

from __future__ import annotations

import math
import time

import numpy as np

from checks.arrays import describe
from tracker._pipeline_options import (
    DEFAULT_MODEL,
    PipelineInfo,
    TrackerEngine,
    TrackerKind,
    TrackerOptions,
    TrackerStats,
    load_model,
    with_overrides,
)
from tracker._pipeline_rt2 import SegmentationEngine
from tracker._pipeline_rtblob import RTBlobEngine
from tracker.detection import DetectorOptions
from tracker.images import image_problem
from tracker.observation import BallObservation, FrameSet
from tracker.rig import Rig
from tracker.robust import RobustOptions
from tracker.rtblob import RTBlobOptions

__all__ = ["DEFAULT_MODEL", "KINDS", "TRACKER_KINDS", "PipelineInfo", "Tracker", "TrackerEngine", "TrackerKind", "TrackerOptions",
           "TrackerStats", "check_kind", "load_model", "make_tracker"]

#: the tracker kinds: name -> :class:`TrackerKind` (engine, detector and estimator method, ROI default, extras)
KINDS = {
    "rt2": TrackerKind(SegmentationEngine, "ours", "ours", roi_default=True, extras=True),
    "rt2-paper": TrackerKind(SegmentationEngine, "paper", "paper", roi_default=False, extras=False),
    "rtblob": TrackerKind(RTBlobEngine, None, None, roi_default=False, extras=False),
}
TRACKER_KINDS = tuple(KINDS)


def check_kind(kind) -> TrackerKind:
    """The registry entry of ``kind``; ``ValueError`` listing the valid kinds for anything else."""
    if not isinstance(kind, str) or kind not in KINDS:
        raise ValueError(f"unknown tracker kind {kind!r}; valid: {list(TRACKER_KINDS)}")
    return KINDS[kind]


class Tracker:
    """One ball observation per frame set, by the RT2 pipeline or a baseline (module docstring).

    rig : :class:`Rig`; ``frameset.images`` come in its camera order
    kind : one of ``TRACKER_KINDS``: "rt2" (ours), "rt2-paper" (the paper's system), "rtblob"
    options : :class:`TrackerOptions`; keyword arguments (``roi=``, ``workers=``, ``eps_px=``,
        ``max_gap_s=``, ...) override single fields
    model : :class:`BallSegmentationModel` or a path to one (default ``data/models/ball_seg_default.npz``)
    detector_options : :class:`DetectorOptions` (default: the kind's detector method)
    estimator_options : :class:`RobustOptions` (``eps_px`` overrides its ``eps_px``)
    rtblob_options : :class:`RTBlobOptions` for kind "rtblob"

    Attributes: ``kind``, ``rig``, ``options``, ``roi``, ``stats`` (:class:`TrackerStats`),
    ``engine`` (the kind's :class:`TrackerEngine`), ``candidates_per_camera`` (k of the estimator's
    input; None for rtblob).
    Not thread-safe: one tracker per acquisition thread (it keeps the motion state and workspaces).
    With ``workers > 1`` it owns a thread pool; ``close()`` it (or use ``with``) when done.
    """

    def __init__(
        self,
        rig: Rig,
        kind: str = "rt2",
        options: TrackerOptions | None = None,
        *,
        model=None,
        detector_options: DetectorOptions | None = None,
        estimator_options: RobustOptions | None = None,
        rtblob_options: RTBlobOptions | None = None,
        **overrides,
    ):
        if not isinstance(rig, Rig):
            raise ValueError(f"rig must be a tracker.Rig, got {describe(rig)}")
        spec = check_kind(kind)
        options = with_overrides(options, overrides)
        self.rig, self.kind, self.n_cams, self.options = rig, kind, len(rig), options
        self.stats = TrackerStats()
        self._names = rig.names
        self._sizes_wh = [tuple(c.image_size) for c in rig]
        self._last_t_s: float | None = None
        self._closed = False
        self.engine: TrackerEngine = spec.engine(rig, kind, spec, options, self.stats, model=model, detector_options=detector_options,
                                                 estimator_options=estimator_options, rtblob_options=rtblob_options)
        self.roi = self.engine.roi
        self.candidates_per_camera = self.engine.candidates_per_camera

    def __repr__(self) -> str:
        return f"Tracker({self.kind!r}, {self.n_cams} cameras, roi={self.roi}, workers={self.options.workers})"

    # -- life cycle -------------------------------------------------------------------------------
    def reset(self, *, clear_stats: bool = False) -> None:
        """Forget the motion state and the last timestamp (a new rally or recording); keep the stats
        unless ``clear_stats``."""
        self.engine.forget_motion()
        self._last_t_s = None
        if clear_stats:
            self.stats.clear()

    def settle(self) -> None:
        """Wait until a full-frame search deferred by the last frame set (``TrackerOptions.defer_full_frame``) has
        ended, so the next frame set takes up its result rather than being reported unsearched: a replay or a test
        that wants the live tracker's answers without its timing. Returns at once when none runs."""
        self.engine.settle()

    def close(self) -> None:
        """Stop the worker threads (``workers > 1``); the tracker refuses frame sets afterwards."""
        self.engine.close()
        self._closed = True

    def __enter__(self) -> "Tracker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- per frame set ----------------------------------------------------------------------------
    def process(self, frameset: FrameSet) -> BallObservation:
        """One :class:`BallObservation` (``tracker`` = the kind) for one frame set.

        frameset : :class:`FrameSet` with one (H, W, 3) uint8 RGB image (or None) per rig camera
        A camera without a usable frame (None, wrong size, dtype or channels) is left out and named in
        ``notes``; a time that does not increase, or is NaN or infinite, is flagged in ``notes`` and
        resets the motion prediction. A frame set of the wrong type or camera count raises ``ValueError``.
        """
        return self.process_with_info(frameset)[0]

    def process_with_info(self, frameset: FrameSet, *, prior_m=None) -> tuple[BallObservation, PipelineInfo]:
        """The observation and the evidence behind it (:class:`PipelineInfo`).

        prior_m : None, or a (3,) world point, metres, where the caller knows the ball to be near (an offline pass that
            has the flight from the frame sets around this one, ``rt2 label --auto``'s second look): the rt2 kinds search
            windows around its pixels in every camera, as around a motion prediction, whether or not ``roi`` is on (the
            full-frame fallback follows ``TrackerOptions.retry_full_frame``); ``rtblob`` has no windows and refuses it
        """
        t0 = time.perf_counter()
        t_s, images = self._check_frameset(frameset)
        if prior_m is not None:
            prior_m = self._check_prior(prior_m)
        notes: list[str] = []
        self.stats.frames += 1
        if not math.isfinite(t_s):  # a broken clock mid-run: a note, never an exception
            notes.append(f"timestamp is not finite (t_s={t_s!r}); motion prediction reset, full frames searched")
            self.stats.non_monotonic += 1
            self.engine.forget_motion()
            t_s = math.nan  # (inf too) never kept as the last time; the motion model ignores it
        elif self._last_t_s is not None and not t_s > self._last_t_s:
            notes.append(f"non-monotonic timestamp: t_s={t_s!r} after {self._last_t_s!r}; motion prediction reset")
            self.stats.non_monotonic += 1
            self.engine.forget_motion()
        if math.isfinite(t_s):
            self._last_t_s = t_s
        usable = self._usable_frames(images, notes)
        if prior_m is not None:
            return self.engine.process(t_s, frameset, usable, notes, t0, prior_m=prior_m)
        return self.engine.process(t_s, frameset, usable, notes, t0)

    # -- the frame-set boundary: everything checked once here, trusted after ----------------------
    def _check_frameset(self, frameset) -> tuple[float, tuple]:
        if not isinstance(frameset, FrameSet):
            raise ValueError(f"frameset must be a tracker.FrameSet, got {describe(frameset)}")
        if self._closed:
            raise ValueError("this Tracker was closed; build a new one")
        t = frameset.t_s
        if isinstance(t, bool) or not isinstance(t, (int, float, np.floating, np.integer)):
            raise ValueError(f"frameset.t_s must be a number of seconds, got {describe(t)}")
        images = frameset.images
        if not isinstance(images, (tuple, list)) or len(images) != self.n_cams:
            got = f"{len(images)} images" if isinstance(images, (tuple, list)) else describe(images)
            raise ValueError(f"frameset.images must hold one image (or None) per camera, {self.n_cams} for {self._names}; got {got}")
        return float(t), images

    def _check_prior(self, prior_m) -> np.ndarray:
        if self.kind == "rtblob":
            raise ValueError("prior_m: the rtblob tracker searches no windows; a prior applies to the rt2 kinds")
        try:
            X = np.asarray(prior_m, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"prior_m must be a (3,) world point in metres, got {describe(prior_m)}") from None
        if X.shape != (3,) or not np.isfinite(X).all():
            raise ValueError(f"prior_m must be a (3,) finite world point in metres, got {describe(prior_m)}")
        return X

    def _usable_frames(self, images, notes: list) -> list[int]:
        """Indices of cameras with a usable frame; notes and counts the others."""
        usable = []
        for i, image in enumerate(images):
            if image is None:
                notes.append(f"camera {self._names[i]}: no frame")
                self.stats.missing_frames += 1
                continue
            problem = image_problem(image, self._sizes_wh[i], "frame")
            if problem is not None:
                notes.append(f"camera {self._names[i]}: {problem[1]}; camera skipped")
                self.stats.bad_frames += 1
                continue
            usable.append(i)
        return usable


def make_tracker(kind: str, rig: Rig, **kwargs) -> Tracker:
    """The tracker of ``kind`` (one of ``TRACKER_KINDS``) on ``rig``; keyword arguments as :class:`Tracker`."""
    check_kind(kind)
    return Tracker(rig, kind, **kwargs)
