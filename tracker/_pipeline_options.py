"""Options, counters and evidence of :class:`tracker.Tracker`, and how it is put together.

Kept apart from :mod:`tracker.pipeline` (the per-frame code) so that both stay short. Public names
are re-exported by :mod:`tracker.pipeline`; see docs/pipeline.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Callable, Protocol

import numpy as np

from checks.arrays import describe
from tracker.detection import BallSegmentationModel, DetectorOptions
from tracker.hypotheses import HypothesisOptions
from tracker.motion import MotionOptions
from tracker.robust import RobustOptions

__all__ = ["DEFAULT_MODEL", "PipelineInfo", "TrackerEngine", "TrackerKind", "TrackerOptions", "TrackerStats", "detector_options_for", "estimator_options_for", "load_model", "with_overrides"]

#: the shipped segmentation model (``rt2 train`` writes it)
DEFAULT_MODEL = Path(__file__).resolve().parents[1] / "data" / "models" / "ball_seg_default.npz"


@dataclass(frozen=True)
class TrackerKind:
    """One entry of the registry of tracker kinds (``tracker.pipeline.KINDS``).

    engine : the class that does the kind's per-frame work (:class:`TrackerEngine`); built as
        ``engine(rig, name, kind, options, stats, model=, detector_options=, estimator_options=, rtblob_options=)``
    detector_method, estimator_method : ``DetectorOptions.method`` / ``RobustTriangulator`` method
        (None: the kind has its own detector and estimator)
    roi_default : searches a window around the predicted pixel unless ``TrackerOptions.roi`` says otherwise
    extras : the steps beyond the paper apply: the 3D size test, the support hand-over, the ball hypotheses
    """

    engine: Callable
    detector_method: str | None
    estimator_method: str | None
    roi_default: bool
    extras: bool


class TrackerEngine(Protocol):
    """What a tracker kind's engine does behind :class:`tracker.Tracker`, which has already checked the
    frame set, its time and its images (``usable``: cameras with a usable frame) and counted them."""

    roi: bool
    candidates_per_camera: int | None  #: k of the estimator's input (None: the kind has no candidates)

    def process(self, t_s: float, frameset, usable: list[int], notes: list, t0: float, *, prior_m=None) -> tuple:
        """``(BallObservation, PipelineInfo)`` of one frame set (``t_s`` NaN when not finite; ``t0`` the
        ``time.perf_counter()`` at the tracker's entry, for ``latency_s``; ``prior_m`` a checked (3,) point
        to search around, :meth:`tracker.Tracker.process_with_info`, never given to an engine without windows)."""

    def forget_motion(self) -> None:
        """Forget what was learnt from earlier frame sets (a new rally, a time that went backwards)."""

    def settle(self) -> None:
        """Wait for work the engine runs after a frame set was reported (:meth:`tracker.Tracker.settle`)."""

    def close(self) -> None:
        """Stop what the engine started (threads)."""


@dataclass(frozen=True)
class TrackerOptions:
    """Options of :class:`Tracker`; keyword arguments of ``Tracker(...)`` override single fields.

    roi : search a window around the predicted ball pixel first (None = the kind's default: on for
        ``rt2``, off for ``rt2-paper``; ``rtblob`` has no ROI). Window size:
        ``DetectorOptions.roi_half_size_px``
    max_gap_s : confirmed estimates older than this give no prediction, seconds (stretched while the frame sets
        the tracker is given are themselves far apart: ``tracker._pipeline_roi``)
    retry_full_frame : when the window search ends without a confirmed (``OK``) estimate, search the
        full frames of the cameras that searched a window, and estimate again
        (the full-frame fallback; off: windows only while a prediction exists)
    retry_backoff_sets : after a full-frame retry that did not confirm the ball either, the next
        retries wait: the fallback is skipped for the next 1, then 2, 4, ... frame sets whose windows
        fail (doubling, at most this many), until an estimate is confirmed again or the prediction
        ends (``max_gap_s``). A retry that found no ball rarely finds one a frame later (the ball is
        occluded, out of view or gone; measured: 1 of 141 retries on ``rt2 track --source sim``
        confirmed the ball, none right after a failed one), yet each costs the window pass plus full
        frames. 0 = retry at every such frame set
    retry_confirm_support : the full-frame fallback goes a batch of cameras at a time (``2 * workers``: two per
        thread), the cameras that see most of the rig's workspace first, and stops once the consensus is
        ``OK`` with at least this many cameras; the cameras left are searched in windows around that position's
        pixels (the windows' usual search, then the full frame if that does not confirm it). With at most
        ``retry_confirm_support + 1`` cameras, and with ``hypotheses`` unless the ball found is the ball in play
        near its prediction (else they want every camera's full frame), every camera is searched in full, as
        without it. None = every
        camera that searched a window is searched in full at once
    workers : threads that run the detector calls of one frame set (1 = the calling thread only)
    threads_for_roi : use the threads also when every camera searches a window (off: measured
        slower, the thread hand-off costs more than a 64x64 window, see docs/pipeline.md)
    eps_px : the estimator's consistency threshold, pixels (None = ``estimator_options.eps_px``)
    max_size_ratio : the 3D size test (``rt2`` only; ``rt2-paper`` never applies it): a position whose
        blobs are, by the median over its cameras, more than this many times as wide as a ball of
        ``ball_radius_m`` would look at that depth is an orange object several cameras agree on, not
        the ball; its candidates are dropped and the estimate is redone (until one passes or none is
        left; windows then fall back to the full frame, like any unconfirmed estimate). Blob width =
        ``sqrt(4 area / pi) + blob_edge_px``; on true balls the ratio is ~1 (median 0.98, at most 1.28
        over 3 x 1500 rendered lab4_vga frame sets). None = off
    model_size_ratio : the size test's threshold is raised to what the model's learned stage records it needs
        (``LearnedStage.size_ratio``, the spread of its diameters: a network's diameter spreads wider than a
        blob's; the shipped white stage: 1.54); False = ``max_size_ratio`` as it is. Models without that record
        (the filter's, and stages trained before it) are tested at ``max_size_ratio``
    ball_radius_m : the ball's radius for the size test, metres (0.02 = a 40 mm ball)
    blob_edge_px : the detector's edge loss for the size test, pixels: a ball's blob is this much
        narrower than the ball (its rim stays under ``T_l``), nearly whatever its size. None = the
        model's ``edge_loss_px`` (the shipped model: 2.8, measured on rendered frame sets by
        ``rt2 eval framesets`` as blob width = 0.98 ball width - 2.80 px; docs/pipeline.md, step 8); 0 = compare the raw blob width
    handover_max_age_s : the support hand-over (``rt2`` only): an estimate from fewer cameras than the
        last confirmed ones (the ball behind the arm in some cameras) is moved by the median offset
        between the confirmed positions of the last 50 ms and those cameras' own estimate then, while
        the newest confirmed position is at most this old (seconds); it removes the calibration error
        of a smaller camera set (:mod:`tracker.handover`, docs/pipeline.md). None = off
    hypotheses : several balls in view (``rt2`` only): :class:`HypothesisOptions` of the 3D hypotheses
        kept across frame sets; the ball reported is the one in play (moving across the table), other
        balls are kept as known objects, and the full frame is searched while no ball is in play
        (:mod:`tracker.hypotheses`, docs/pipeline.md step 10). None = off (one track: the estimator's
        best set)
    size_from_rig : the detectors' size limits follow from the rig when it has a workspace box
        (:mod:`tracker.ball_size`): per camera, rt2's accepted blob area is widened to the blobs of the
        ball at the workspace's nearest and farthest points, its search window grown to hold the
        nearest ball, and RTBlob's template raised to at least the farthest ball's radius; limits
        already wide enough are kept as they are (docs/pipeline.md, "Size limits from the rig").
        False = the model's trained area range, ``roi_half_size_px`` and RTBlob's
        ``expected_distance_m`` sizing on every rig
    full_frame_pyramid : ``rt2`` with a model without a learned stage, on a rig with a workspace: a camera whose
        smallest ball is at least 2^k x 5.5 px wide (k <= 2) searches its full frame reduced 2^k times, each
        candidate then found again in a window at full resolution (:mod:`tracker._pipeline_pyramid`; a nine-camera
        1440x1080 rig's full-frame search 3x faster). VGA rigs stay at full resolution. Off by default (the offline
        experiments' figures are the full resolution's: on the reduced frame the K best candidates can differ); the
        live service turns it on (``harness.live.config.TrackConfig.full_frame_pyramid``)
    defer_full_frame : ``rt2`` with ``roi``, live: a frame set that would search full frames (no predicted ball, or
        windows that did not confirm it: the fallback) is reported at once without a position, and those full frames
        are searched on a worker thread while the next frames arrive; at the start of the next frame set the result
        joins the tracker's state (the motion prediction, the ball hypotheses, the retry back-off) as if it had come
        in time, so that frame set's windows search where the ball was found. A new or lost ball is reported one
        frame set later, and no frame set waits for a full-frame search of its own (a new ball's frame set on eight
        VGA cameras took ~8 ms). A frame set that arrives while the search still runs (nine 1440x1080 cameras: longer
        than a period) is reported unsearched (``TrackerStats.not_searched``); the first one after it takes up its
        result. The ball hypotheses' own full-frame sets, while windows follow a ball, are not deferred. Off by default (offline runs report each full-frame result in its own frame set); the live service
        turns it on
        (``harness.live.config.TrackConfig.defer_full_frame``)
    deferred_wait_s : with ``defer_full_frame``: how long a frame set that arrives while the deferred search still
        runs waits for it before it is reported unsearched (0: not at once). The live service waits 0.4 of a frame
        period: a search that ends within it gives this frame set its windows at the ball (on eight VGA cameras a
        few frame sets per minute found the search just short of done), for that much latency on those frame sets
    motion_cue : fixed cameras (``rt2`` only): :class:`MotionOptions` of a per-camera background at reduced
        resolution (:mod:`tracker.motion`); a full-frame search keeps only the candidates on cells that moved (a new
        ball is one that moves: lamps, shelves and white objects do not), while a frame gives a cue (not the first
        one, nor one whose whole scene changed). Windows around a followed ball keep it when it stops. None = off
    """

    roi: bool | None = None
    max_gap_s: float = 0.05
    retry_full_frame: bool = True
    retry_backoff_sets: int = 4
    retry_confirm_support: int | None = 3
    workers: int = 1
    threads_for_roi: bool = False
    eps_px: float | None = None
    max_size_ratio: float | None = 1.3
    model_size_ratio: bool = True
    ball_radius_m: float = 0.02
    blob_edge_px: float | None = None
    handover_max_age_s: float | None = 0.25
    hypotheses: HypothesisOptions | None = HypothesisOptions()
    size_from_rig: bool = True
    full_frame_pyramid: bool = False
    defer_full_frame: bool = False
    deferred_wait_s: float = 0.0
    motion_cue: MotionOptions | None = None

    def __post_init__(self):
        if self.roi is not None and not isinstance(self.roi, (bool, np.bool_)):
            raise ValueError(f"TrackerOptions.roi must be True, False or None, got {self.roi!r}")
        for name in ("retry_full_frame", "threads_for_roi", "size_from_rig", "full_frame_pyramid", "model_size_ratio", "defer_full_frame"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"TrackerOptions.{name} must be True or False, got {getattr(self, name)!r}")
        g = self.max_gap_s
        if isinstance(g, bool) or not isinstance(g, (int, float, np.floating, np.integer)) or not (math.isfinite(g) and g > 0):
            raise ValueError(f"TrackerOptions.max_gap_s must be a positive number of seconds, got {g!r}")
        b = self.retry_backoff_sets
        if isinstance(b, bool) or not isinstance(b, (int, np.integer)) or b < 0:
            raise ValueError(f"TrackerOptions.retry_backoff_sets must be an integer >= 0 (0 = retry at every frame set), got {b!r}")
        c = self.retry_confirm_support
        if c is not None and (isinstance(c, bool) or not isinstance(c, (int, np.integer)) or c < 2):
            raise ValueError(f"TrackerOptions.retry_confirm_support must be an integer >= 2 or None (every camera at once), got {c!r}")
        w = self.workers
        if isinstance(w, bool) or not isinstance(w, (int, np.integer)) or w < 1:
            raise ValueError(f"TrackerOptions.workers must be an integer >= 1, got {w!r}")
        e = self.eps_px
        if e is not None and (isinstance(e, bool) or not isinstance(e, (int, float, np.floating, np.integer)) or not (math.isfinite(e) and e > 0)):
            raise ValueError(f"TrackerOptions.eps_px must be a positive number of pixels or None, got {e!r}")
        m = self.max_size_ratio
        if m is not None and (isinstance(m, bool) or not isinstance(m, (int, float, np.floating, np.integer)) or not (math.isfinite(m) and m > 0)):
            raise ValueError(f"TrackerOptions.max_size_ratio must be a positive number or None (off), got {m!r}")
        dw = self.deferred_wait_s
        if isinstance(dw, bool) or not isinstance(dw, (int, float, np.floating, np.integer)) or not (math.isfinite(dw) and dw >= 0):
            raise ValueError(f"TrackerOptions.deferred_wait_s must be a number of seconds >= 0, got {dw!r}")
        h = self.handover_max_age_s
        if h is not None and (isinstance(h, bool) or not isinstance(h, (int, float, np.floating, np.integer)) or not (math.isfinite(h) and h > 0)):
            raise ValueError(f"TrackerOptions.handover_max_age_s must be a positive number of seconds or None (off), got {h!r}")
        b = self.blob_edge_px
        if b is not None and (isinstance(b, bool) or not isinstance(b, (int, float, np.floating, np.integer)) or not (math.isfinite(b) and b >= 0)):
            raise ValueError(f"TrackerOptions.blob_edge_px must be a number of pixels >= 0 or None (the model's), got {b!r}")
        r = self.ball_radius_m
        if isinstance(r, bool) or not isinstance(r, (int, float, np.floating, np.integer)) or not (math.isfinite(r) and 0 < r < 1):
            raise ValueError(f"TrackerOptions.ball_radius_m must be a radius in metres in (0, 1), got {r!r}")
        if self.hypotheses is not None and not isinstance(self.hypotheses, HypothesisOptions):
            raise ValueError(f"TrackerOptions.hypotheses must be a HypothesisOptions or None (off), got {describe(self.hypotheses)}")
        if self.motion_cue is not None and not isinstance(self.motion_cue, MotionOptions):
            raise ValueError(f"TrackerOptions.motion_cue must be a MotionOptions or None (off), got {describe(self.motion_cue)}")


@dataclass
class TrackerStats:
    """Running counters of a :class:`Tracker` (cumulative; ``reset(clear_stats=True)`` zeroes them).

    frames : frame sets processed
    positions, ok : observations with a position; with ``Status.OK``
    predictions : frame sets that had a predicted ball position (ROI on)
    roi_searches : camera images searched in a window around the predicted pixel
    roi_misses : of those, windows without a ball candidate (incl. a prediction outside the image)
    full_frame_searches : camera images searched over the full frame (no prediction, or a retry)
    full_frame_retries : frame sets re-searched on full frames after the windows gave no OK estimate
    deferred_searches : frame sets whose full-frame search (no prediction, or the windows' fallback) ran after the set
        was reported (``TrackerOptions.defer_full_frame``)
    deferred_found : of those, searches that confirmed a ball (the next frame set's windows searched at it)
    not_searched : frame sets that arrived while a deferred search still ran: reported without a search or a position
    retries_held : frame sets whose windows gave no OK estimate and whose retry waited
        (``TrackerOptions.retry_backoff_sets``)
    size_rejections : positions rejected by the 3D size test (``TrackerOptions.max_size_ratio``)
    handovers : positions moved by the support hand-over (``TrackerOptions.handover_max_age_s``)
    lead_changes : frame sets whose reported ball changed from a hypothesis still kept to another one
        in play (``TrackerOptions.hypotheses``; the motion prediction restarts on it)
    withheld : frame sets with several ball hypotheses, none in play yet: no position reported
    hypothesis_full_frames : full-frame searches asked for by the hypotheses (no ball in play)
    still_candidates : full-frame candidates dropped because nothing moved there (``TrackerOptions.motion_cue``)
    missing_frames : camera images that were None (no frame delivered)
    bad_frames : camera images of the wrong size, dtype or channels (skipped)
    non_monotonic : frame sets whose time did not increase or was not finite (motion prediction reset)
    """

    frames: int = 0
    positions: int = 0
    ok: int = 0
    predictions: int = 0
    roi_searches: int = 0
    roi_misses: int = 0
    full_frame_searches: int = 0
    full_frame_retries: int = 0
    deferred_searches: int = 0
    deferred_found: int = 0
    not_searched: int = 0
    retries_held: int = 0
    size_rejections: int = 0
    handovers: int = 0
    lead_changes: int = 0
    withheld: int = 0
    hypothesis_full_frames: int = 0
    still_candidates: int = 0
    missing_frames: int = 0
    bad_frames: int = 0
    non_monotonic: int = 0

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def clear(self) -> None:
        """Every counter back to 0 (in place: the tracker's engine counts into this object)."""
        for f in fields(self):
            setattr(self, f.name, 0)

    @property
    def dropped_cameras(self) -> int:
        """Camera images not used because of a missing or bad frame."""
        return self.missing_frames + self.bad_frames


@dataclass(frozen=True, eq=False)
class PipelineInfo:
    """What :meth:`Tracker.process_with_info` knows beyond the observation (per rig camera).

    uv_candidates_px : (n_cams, k, 2) every candidate the detector reported, distorted pixels, NaN-padded
    scores : (n_cams, k) their scores (peak ball probability; RTBlob: the peak response), NaN-padded
    roi_center_px : (n_cams, 2) the predicted pixel each window was centred on, NaN where none
    used_roi : (n_cams,) bool, the camera's candidates come from the window search (not the full frame)
    retried : a full-frame retry happened
    estimate : the estimator's :class:`EstimateInfo` (rt2 kinds) or :class:`RTBlobInfo` (rtblob)
    size_ratio : (rt2 kinds) median over the position's cameras of blob width (plus the edge loss,
        ``TrackerOptions.blob_edge_px``) / the width a ball would have at that depth (NaN without a
        position; rtblob: NaN)
    areas_px : (n_cams, k) blob area of each candidate, pixels, NaN-padded (rtblob: None)
    hypotheses_m : (n_hypotheses, 3) newest position of each ball hypothesis kept after this frame set,
        world frame, metres (``rt2`` with ``TrackerOptions.hypotheses``; else None)
    hypotheses_in_play : (n_hypotheses,) bool, which of them are in play (else None)
    """

    uv_candidates_px: np.ndarray
    scores: np.ndarray
    roi_center_px: np.ndarray
    used_roi: np.ndarray
    retried: bool
    estimate: object
    size_ratio: float = math.nan
    areas_px: np.ndarray | None = None
    hypotheses_m: np.ndarray | None = None
    hypotheses_in_play: np.ndarray | None = None


def with_overrides(options, overrides: dict) -> TrackerOptions:
    if options is None:
        options = TrackerOptions()
    elif not isinstance(options, TrackerOptions):
        raise ValueError(f"options must be a TrackerOptions, got {describe(options)}")
    if overrides:
        valid = [f.name for f in fields(TrackerOptions)]
        unknown = sorted(set(overrides) - set(valid))
        if unknown:
            raise ValueError(f"unknown Tracker option(s) {unknown}; valid: {valid} and model, detector_options, estimator_options, rtblob_options")
        options = replace(options, **overrides)
    return options


def load_model(model=None) -> BallSegmentationModel:
    """A :class:`BallSegmentationModel` from itself, a path, or None (the shipped default model)."""
    if isinstance(model, BallSegmentationModel):
        return model
    path = DEFAULT_MODEL if model is None else model
    if not isinstance(path, (str, Path)):
        raise ValueError(f"model must be a BallSegmentationModel or a path to one (.npz), got {describe(model)}")
    if not Path(path).is_file():
        hint = " (the default model; train one with `rt2 train` or pass model=)" if model is None else ""
        raise FileNotFoundError(f"model file {str(path)!r} does not exist{hint}")
    return BallSegmentationModel.load(path)


def detector_options_for(kind: str, method: str, given) -> DetectorOptions:
    if given is None:  # a rig's cameras report the heat's candidates: the consensus is their second look
        return DetectorOptions(method=method, confirm=False)
    if not isinstance(given, DetectorOptions):
        raise ValueError(f"detector_options must be a DetectorOptions, got {describe(given)}")
    if given.method != method:
        raise ValueError(f"kind {kind!r} uses detector method {method!r}, got detector_options.method={given.method!r}")
    return given


def estimator_options_for(given, eps_px) -> RobustOptions:
    if given is None:
        given = RobustOptions()
    elif not isinstance(given, RobustOptions):
        raise ValueError(f"estimator_options must be a RobustOptions, got {describe(given)}")
    return given if eps_px is None else replace(given, eps_px=float(eps_px))
