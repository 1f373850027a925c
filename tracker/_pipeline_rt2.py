"""The per-frame work of the segmentation kinds of :class:`tracker.Tracker` (``rt2``, ``rt2-paper``).

:class:`SegmentationEngine` gets a frame set whose images :class:`~tracker.pipeline.Tracker` has
already checked (``usable``: the cameras with a usable frame) and runs the steps of docs/pipeline.md:
predict the ball's pixels, one detector call per camera (window, neighbourhood or full frame:
:mod:`tracker._pipeline_search`), the consensus (the robust estimate with the 3D size test as its
last stage, :meth:`RobustTriangulator.estimate_checked`), the full-frame fallback when the windows
did not confirm the ball, the ball hypotheses and the support hand-over (``rt2``).
"""

from __future__ import annotations

import math
import time
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, replace

import numpy as np

from tracker._pipeline_options import PipelineInfo, TrackerKind, TrackerOptions, TrackerStats, detector_options_for, estimator_options_for, load_model
from tracker._pipeline_pyramid import PyramidSearch, pyramid_levels
from tracker._pipeline_roi import MotionPredictor
from tracker._pipeline_search import search_around, search_boxes
from tracker.ball_size import ball_diameter_range_px, size_limits
from tracker.detection import BallDetector, Detections
from tracker.handover import SupportHandover
from tracker.hypotheses import BallHypotheses
from tracker.motion import MotionCue
from tracker.observation import DEFERRED_NOTE, NOT_SEARCHED_NOTE, BallObservation, Status
from tracker.rig import Rig
from tracker.robust import EstimateInfo, RobustTriangulator
from tracker.size_test import SizeTest, size_threshold

__all__ = ["JUMP_M", "SegmentationEngine"]

#: a ball the full-frame fallback finds this far from the prediction (m) starts a new motion: a new serve,
#: or a ball the windows lost; a ball at 30 m/s moves 0.15 m in a 200 Hz period
JUMP_M = 0.25
#: a full-frame search in the regions that moved (``TrackerOptions.motion_cue``) searches each this much wider, pixels, and
#: keeps the candidates inside it, so that they are the full frame's: the filter's blobs need a few pixels around them;
#: the learned stage's network sees ~64 of its pixels around a cell (it found false peaks near the edge of a box
#: given with less), and its box is aligned to the full frame's grid (``LearnedStage.aligned_window``)
REGION_CONTEXT_PX = {"filter": 8, "learned": 56}


class SegmentationEngine:
    """The segmentation detector + robust estimator behind :class:`tracker.Tracker` (module docstring).

    rig : the tracker's rig; kind : its name; spec : its :class:`TrackerKind` (methods, ROI default,
    whether the size test, hand-over and hypotheses apply); options : :class:`TrackerOptions`;
    stats : the tracker's :class:`TrackerStats` (counted here); model, detector_options,
    estimator_options, rtblob_options : as :class:`tracker.Tracker` (``rtblob_options`` must be None)

    Attributes: ``roi``, ``detector`` (the kind's detector), ``detectors`` (per camera, sized from the
    rig), ``pyramid`` (per camera its reduced-resolution full-frame search or None), ``estimator``,
    ``candidates_per_camera`` (k of the estimator's input).
    """

    def __init__(self, rig: Rig, kind: str, spec: TrackerKind, options: TrackerOptions, stats: TrackerStats, *,
                 model=None, detector_options=None, estimator_options=None, rtblob_options=None):
        if rtblob_options is not None:
            raise ValueError(f"rtblob_options apply to kind 'rtblob' only, got kind {kind!r}")
        self.kind, self.n_cams, self.options, self.stats = kind, len(rig), options, stats
        self.roi = spec.roi_default if options.roi is None else bool(options.roi)
        self._names = rig.names
        self._rig = rig
        self._search_order = _search_order(rig)  # the full-frame fallback's order: most of the workspace first
        self._wh = np.array([tuple(c.image_size) for c in rig], np.int64)  # (n_cams, 2) width, height
        model = load_model(model)
        dopts = detector_options_for(kind, spec.detector_method, detector_options)
        if dopts.learned and dopts.learned_threshold is None and model.learned is not None and model.learned.track_threshold is not None:
            dopts = replace(dopts, learned_threshold=model.learned.track_threshold)  # the stage's operating point in a rig
        self.detector = BallDetector(model, dopts)
        self.detectors = _sized_detectors(rig, self.detector) if options.size_from_rig else [self.detector] * len(rig)
        self._roi_half = np.array([d.options.roi_half_size_px for d in self.detectors], np.int64)[:, None]  # (n_cams, 1)
        self.pyramid = _pyramid_searches(rig, self.detectors, options) if spec.extras else [None] * len(rig)
        self.estimator = RobustTriangulator(rig, estimator_options_for(estimator_options, options.eps_px), method=spec.estimator_method)
        k = self.candidates_per_camera = self.detector.options.k
        if k > self.estimator.options.max_candidates_per_camera:
            raise ValueError(
                f"detector_options.max_candidates ({k}) exceeds estimator_options.max_candidates_per_camera "
                f"({self.estimator.options.max_candidates_per_camera}); raise the latter or lower the former"
            )
        self._motion = MotionPredictor(rig, options.max_gap_s)
        self._retry_wait, self._retry_gap = 0, 1  # frame sets the next retry still waits; the wait after the next failed retry
        self._size = SizeTest(rig, size_threshold(options.max_size_ratio, self.detector.size_ratio, options.model_size_ratio) if spec.extras else None,
                              options.ball_radius_m,
                              self.detector.edge_loss_px if options.blob_edge_px is None else options.blob_edge_px)
        self.handover = None
        if spec.extras and options.handover_max_age_s is not None:
            self.handover = SupportHandover(self.estimator, len(rig), max_age_s=options.handover_max_age_s)
        self.hypotheses = BallHypotheses(options.hypotheses) if spec.extras and options.hypotheses is not None else None
        n = self.n_cams
        self._uv = np.full((n, k, 2), np.nan)  # the estimator's input, reused every frame set
        self._scores = np.full((n, k), np.nan)
        self._areas = np.full((n, k), np.nan)  # blob areas, px (the size test's input)
        self._size_stage = self._size.stage(self._areas)  # the consensus's last stage, on this workspace
        self._dets = [None] * n
        self._images = None
        # per camera its motion cue (TrackerOptions.motion_cue): full-frame candidates only where something moved
        # (their full-frame searches that ignore the cue come in the same frame sets: a still ball needs three cameras at once)
        self.cues = [MotionCue(int(w), int(h), options.motion_cue) for w, h in self._wh] if spec.extras and options.motion_cue is not None else None
        self._margin_px = _region_margins(rig, options.ball_radius_m) if self.cues else None  # a ball's radius around the moving cells
        self._still = np.zeros(n, np.int64)  # per camera the candidates its cue dropped in this detector call
        self._frame_no, self._t_s = 0, math.nan
        self._pool = None
        if options.workers > 1:
            self._pool = ThreadPoolExecutor(options.workers - 1, thread_name_prefix="rt2-detect")
        # TrackerOptions.defer_full_frame: the fallback after its frame set was reported, on this thread (which
        # shares the detector calls with the pool as the calling thread does); _Deferred of the one in flight
        self._deferrer = ThreadPoolExecutor(1, thread_name_prefix="rt2-deferred") if options.defer_full_frame and self.roi else None
        self._pending: _Deferred | None = None

    # -- life cycle -------------------------------------------------------------------------------
    def forget_motion(self, *, hypotheses: bool = True) -> None:
        """Forget the motion prediction, the hand-over's history and (``hypotheses``) the ball hypotheses (and a
        deferred full-frame search still running: its result is dropped)."""
        self._drop_deferred()
        self._motion.reset()
        self._retry_wait, self._retry_gap = 0, 1  # TrackerOptions.retry_backoff_sets
        if self.handover is not None:
            self.handover.reset()
        if hypotheses and self.hypotheses is not None:
            self.hypotheses.reset()
        if hypotheses and self.cues is not None:
            for cue in self.cues:
                cue.reset()

    def close(self) -> None:
        self._drop_deferred()
        if self._deferrer is not None:
            self._deferrer.shutdown(wait=True)
            self._deferrer = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    # -- per frame set ----------------------------------------------------------------------------
    def process(self, t_s: float, frameset, usable: list[int], notes: list, t0: float, *,
                prior_m=None) -> tuple[BallObservation, PipelineInfo]:
        """One frame set: ``t_s`` its time (NaN when not finite), ``usable`` the cameras with a usable
        frame, ``notes`` the notes so far (appended to), ``t0`` ``time.perf_counter()`` at entry; ``prior_m``
        a (3,) world point whose pixels are searched instead of the motion prediction's."""
        if self._pending is not None:  # an earlier frame set's full frames: their result first (it steers these windows)
            if not self._pending.future.done() and self.options.deferred_wait_s > 0:
                wait([self._pending.future], timeout=self.options.deferred_wait_s)  # TrackerOptions.deferred_wait_s
            if not self._pending.future.done():
                return self._not_searched(t_s, notes, t0)
            self._finish_deferred(notes)
        n = self.n_cams
        self._images = frameset.images
        self._frame_no += 1
        self._t_s = t_s
        if prior_m is not None:
            roi_px = self._project(prior_m, list(range(n)))
        else:
            roi_px = self._motion.predict_pixels(t_s) if self.roi else None
        hyp = self.hypotheses
        predicted = roi_px is not None
        if prior_m is None and roi_px is not None and hyp is not None and hyp.wants_full_frame(t_s):
            roi_px = None  # no ball in play: look at everything now and then (step 10)
            self.stats.hypothesis_full_frames += 1
        if roi_px is None:
            roi_px = np.full((n, 2), np.nan)
        else:
            self.stats.predictions += 1
        self._uv.fill(np.nan)
        self._scores.fill(np.nan)
        self._areas.fill(np.nan)
        used_roi = np.isfinite(roi_px[:, 0])
        used_roi[[i for i in range(n) if i not in usable]] = False
        searched = usable if prior_m is None else [i for i in usable if used_roi[i]]  # the prior behind a camera: not searched
        # no prediction (a new ball, or none in view): with defer_full_frame the full frames are searched after this
        # frame set is reported (the ball hypotheses' own full-frame sets, while a ball is followed, are not deferred)
        deferred = (searched and self._deferrer is not None and prior_m is None and math.isfinite(t_s) and not predicted)
        if deferred:
            self.stats.deferred_searches += 1
            notes.append(f"no predicted ball: full frames of {', '.join(self._names[i] for i in searched)} {DEFERRED_NOTE}, "
                         "until they confirm a ball (it steers the next frame set's windows)")
            job = (False, searched, roi_px.copy(), used_roi.copy(), Status.TOO_FEW_OBSERVATIONS)
        else:
            self._detect(searched, roi_px, used_roi)  # Algorithm 1 per camera (paper Sec. 2.1)
        X, info, size_ratio = self._estimate(notes)  # Algorithm 2 (paper Sec. 2.2; "ours" extends it), then the 3D size test
        retried = False
        if self.options.retry_full_frame and info.status is not Status.OK and used_roi.any() and not deferred:
            # The full-frame fallback, only when the windows did not confirm the ball (also when the
            # size test rejected what they held). Every camera that searched a window is redone: with
            # two agreeing cameras, those two may be the ones whose windows hold the wrong object (any
            # two rays nearly meet). After a retry that found no ball either, the next ones wait
            # (TrackerOptions.retry_backoff_sets).
            redo = [i for i in usable if used_roi[i]]
            if redo and self._retry_wait > 0:
                self._retry_wait -= 1
                self.stats.retries_held += 1
                notes.append(f"window search gave {info.status.value}; full-frame retry held back (the last one did not confirm the ball)")
            elif redo and self._deferrer is not None and prior_m is None and math.isfinite(t_s):
                deferred = True  # reported now without a position; the fallback runs once this frame set is out
                self.stats.full_frame_retries += 1
                self.stats.deferred_searches += 1
                notes.append(f"window search gave {info.status.value}; full frames of {', '.join(self._names[i] for i in redo)} {DEFERRED_NOTE}, "
                             "until they confirm a ball (it steers the next frame set's windows)")
                job = (True, redo, roi_px.copy(), used_roi.copy(), info.status)
            elif redo:
                retried = True
                self.stats.full_frame_retries += 1
                self._uv[redo] = np.nan
                self._scores[redo] = np.nan
                self._areas[redo] = np.nan
                X, info, size_ratio = self._retry(t_s, redo, roi_px, used_roi, info.status, notes)
                if info.status is not Status.OK and self.options.retry_backoff_sets > 0:
                    self._retry_wait = self._retry_gap
                    self._retry_gap = min(2 * self._retry_gap, self.options.retry_backoff_sets)
        if info.status is Status.OK:
            self._retry_wait, self._retry_gap = 0, 1
        withheld = False
        if deferred:
            X, size_ratio, withheld = None, math.nan, True  # the ball hypotheses take the full frames' positions instead
        elif hyp is not None and math.isfinite(t_s):
            X, info, size_ratio, withheld = self._choose_ball(t_s, X, info, size_ratio, usable, used_roi, notes)
        ok = info.status is Status.OK and not withheld
        cand = info.candidate_index
        uv_px = np.full((n, 2), np.nan)
        sel = np.flatnonzero(cand >= 0) if not withheld else np.zeros(0, np.int64)
        uv_px[sel] = self._uv[sel, cand[sel]]
        if X is not None and self.handover is not None and math.isfinite(t_s):
            X = self._hand_over(t_s, X, info, uv_px, ok, notes)
        if ok and math.isfinite(t_s):
            if retried and self._jumped(t_s, X):
                self._motion.reset()  # a new ball, or one far from where it was: no velocity across the jump
            self._motion.update(t_s, X)  # only confirmed estimates feed the prediction
        self.stats.positions += X is not None
        self.stats.ok += ok
        pinfo = PipelineInfo(self._uv.copy(), self._scores.copy(), roi_px, used_roi, retried, info, size_ratio, self._areas.copy(),
                             *((hyp.positions(), hyp.in_play()) if hyp is not None else (None, None)))
        if deferred:  # (after the evidence above was copied: the search refills the rows of these cameras)
            self._defer(t_s, usable, *job)
        else:
            self._images = None  # do not keep the frames alive
        obs = BallObservation(
            t_s=t_s,
            position_m=X,
            covariance_m2=None if withheld else info.covariance_m2,
            support=0 if withheld else info.support,
            inliers=np.zeros(n, bool) if withheld else info.inliers,
            # (a deferred frame set reports no position: the windows' low_support becomes no_consensus, as when withheld)
            status=info.status.unreported() if deferred else Status.NO_CONSENSUS if withheld else info.status,
            latency_s=time.perf_counter() - t0,  # entry to return
            tracker=self.kind,
            uv_px=uv_px,
            notes=tuple(notes),
        )
        return obs, pinfo

    def _retry(self, t_s: float, redo: list[int], roi_px: np.ndarray, used_roi: np.ndarray, window_status: Status, notes: list, *,
               first_confirmation: bool = False):
        """The full-frame fallback over the cameras ``redo`` (their rows cleared): a batch of
        ``2 * workers`` cameras at a time in :attr:`_search_order` (two per thread), until the consensus
        is ``OK`` with ``retry_confirm_support`` cameras; then, unless the ball hypotheses want every camera's
        full frame for it (:meth:`_windows_will_do`), the cameras left search windows around that position's pixels (``roi_px`` and ``used_roi`` updated), and the full frame only if they do not
        confirm it (``TrackerOptions.retry_confirm_support``); when the hypotheses want them, the cameras left search
        their full frames all at once (one parallel call, not batch by batch). ``first_confirmation`` (a deferred search:
        the next frame set's windows look at every camera): stop at the first batch that confirms the ball. Returns
        ``(X, info, ratio)``."""
        need = self.options.retry_confirm_support
        if need is None or len(redo) <= need + 1:  # every camera at once
            notes.append(f"window search gave {window_status.value}; full frame searched in {', '.join(self._names[i] for i in redo)}")
            used_roi[redo] = False
            self._detect(redo, roi_px, used_roi)
            return self._estimate(notes)
        batch = 2 * max(1, self.options.workers)  # two frames per thread: often enough for a confirmed position
        left = [i for i in self._search_order if i in redo]
        full: list[int] = []
        X = info = ratio = None
        while left:
            step, left = left[:batch], left[batch:]
            used_roi[step] = False
            self._detect(step, roi_px, used_roi)
            full += step
            X, info, ratio = self._estimate(notes)
            if left and first_confirmation and info.status is Status.OK and info.support >= need:
                break
            if left and info.status is Status.OK and info.support >= need and not self._windows_will_do(t_s, X):
                batch = len(left)  # every full frame is wanted: the rest at once, on every thread
            elif left and info.status is Status.OK and info.support >= need:
                roi_px[left] = self._project(X, left)
                used_roi[left] = np.isfinite(roi_px[left, 0])
                rest = [i for i in left if used_roi[i]]  # a camera the ball is behind is not searched
                self._detect(rest, roi_px, used_roi)
                X2, info2, ratio2 = self._estimate(notes)
                if info2.status is Status.OK:
                    notes.append(f"window search gave {window_status.value}; full frame searched in "
                                 f"{', '.join(self._names[i] for i in sorted(full))}, windows at the ball found in "
                                 f"{', '.join(self._names[i] for i in rest)}")
                    return X2, info2, ratio2
                self._uv[rest] = np.nan  # the windows did not confirm it: the rest in full as well
                self._scores[rest] = np.nan
                self._areas[rest] = np.nan
        notes.append(f"window search gave {window_status.value}; full frame searched in {', '.join(self._names[i] for i in sorted(full))}")
        return X, info, ratio

    # -- the deferred fallback (TrackerOptions.defer_full_frame) ------------------------------------
    def _defer(self, t_s: float, usable: list, retry: bool, cams: list, roi_px: np.ndarray, used_roi: np.ndarray,
               status: Status) -> None:
        """Start the full-frame search of the frame set just reported (``retry``: the windows' fallback, else a frame set
        without a prediction) on the deferred thread: :meth:`_retry` batch by batch until a batch confirms the ball (the
        next frame set's windows search every camera at it). Its images stay in ``self._images`` until
        :meth:`_finish_deferred`, and nothing else touches the engine's arrays meanwhile; its notes are not reported."""
        self._uv[cams] = np.nan
        self._scores[cams] = np.nan
        self._areas[cams] = np.nan
        future = self._deferrer.submit(self._retry, t_s, cams, roi_px, used_roi, status, [], first_confirmation=True)
        self._pending = _Deferred(future, t_s, list(usable), used_roi, retry)

    def _finish_deferred(self, notes: list) -> None:
        """Wait for the deferred search and let its result join the state as :meth:`process` does after a search in
        time: the retry back-off, the ball hypotheses and the motion prediction (which the next windows follow).
        One note in ``notes`` (the frame set being processed) says what it found."""
        p, self._pending = self._pending, None
        try:
            X, info, ratio = p.future.result()
        finally:
            self._images = None
        if info.status is Status.OK:
            self._retry_wait, self._retry_gap = 0, 1
        elif p.retry and self.options.retry_backoff_sets > 0:
            self._retry_wait = self._retry_gap
            self._retry_gap = min(2 * self._retry_gap, self.options.retry_backoff_sets)
        withheld = False
        if self.hypotheses is not None:  # as a full-frame search (it stops at the first batch that confirms the ball: the
            # next frame set's windows search every camera there, and a look for other balls waits for its period)
            full = np.zeros_like(p.used_roi)
            X, info, ratio, withheld = self._choose_ball(p.t_s, X, info, ratio, p.usable, full, [])  # (notes of the set reported)
        what = "the full-frame fallback" if p.retry else "the full-frame search"
        if info.status is Status.OK and not withheld:
            self.stats.deferred_found += 1
            if p.retry and self._jumped(p.t_s, X):
                self._motion.reset()  # a new ball, or one far from where it was (as after a fallback in time)
            self._motion.update(p.t_s, X)
            notes.append(f"{what} after the frame set at t={p.t_s:.6f} s found the ball with {info.support} cameras: windows at it")
        else:
            notes.append(f"{what} after the frame set at t={p.t_s:.6f} s gave {'no ball in play' if withheld else info.status.value}")

    def settle(self) -> None:
        """Wait for a deferred full-frame search still running (its result is taken up by the next frame set)."""
        p = self._pending
        if p is not None:
            wait([p.future])

    def _not_searched(self, t_s: float, notes: list, t0: float) -> tuple[BallObservation, PipelineInfo]:
        """The observation of a frame set that arrives while a deferred full-frame search still runs: not searched
        (the search uses the engine's arrays; the next frame set after it ends takes up its result), no position."""
        n, k = self.n_cams, self.candidates_per_camera
        self.stats.not_searched += 1
        notes.append(f"{NOT_SEARCHED_NOTE}the full-frame search after the frame set at t={self._pending.t_s:.6f} s still runs")
        info = EstimateInfo(Status.TOO_FEW_OBSERVATIONS, 0, np.zeros(n, bool), np.full(n, -1, np.int64), np.full(n, np.nan), None,
                            math.nan, 0, 0, self.estimator.method)
        hyp = self.hypotheses
        pinfo = PipelineInfo(np.full((n, k, 2), np.nan), np.full((n, k), np.nan), np.full((n, 2), np.nan), np.zeros(n, bool), False, info,
                             math.nan, np.full((n, k), np.nan), *((hyp.positions(), hyp.in_play()) if hyp is not None else (None, None)))
        obs = BallObservation(t_s=t_s, position_m=None, covariance_m2=None, support=0, inliers=np.zeros(n, bool), status=info.status,
                              latency_s=time.perf_counter() - t0, tracker=self.kind, uv_px=np.full((n, 2), np.nan), notes=tuple(notes))
        return obs, pinfo

    def _drop_deferred(self) -> None:
        """Wait for a deferred fallback still running and forget its result."""
        p, self._pending = self._pending, None
        if p is not None:
            try:
                p.future.result()
            finally:
                self._images = None

    def _windows_will_do(self, t_s: float, X: np.ndarray) -> bool:
        """Whether the cameras the fallback has not searched yet may search windows at ``X`` (3,): always without
        ball hypotheses; with them only for the ball in play found near its prediction (a new ball, or no ball in
        play: they search every camera's full frame for the balls in view, at the next frame set if not now)."""
        hyp = self.hypotheses
        return hyp is None or (hyp.lead_in_play and not self._jumped(t_s, X))

    def _jumped(self, t_s: float, X: np.ndarray) -> bool:
        """Whether ``X`` (3,), found by the full-frame fallback, lies more than :data:`JUMP_M` from the
        predicted position: the windows searched the wrong place, and the velocity from the estimate
        before to this one would place the next windows wrong too."""
        predicted = self._motion.predict(t_s)
        return predicted is not None and float(np.linalg.norm(X - predicted)) > JUMP_M

    def _project(self, X: np.ndarray, cams: list[int]) -> np.ndarray:
        """(len(cams), 2) distorted pixels of the world point ``X`` (3,) in the cameras ``cams``; NaN behind a camera."""
        out = np.full((len(cams), 2), np.nan)
        for j, i in enumerate(cams):
            cam = self._rig[i]
            if cam.depth(X[None])[0] > 0:
                out[j] = cam.project(X[None])[0]
        return out

    def _hand_over(self, t_s: float, X: np.ndarray, info, uv_px: np.ndarray, ok: bool, notes: list) -> np.ndarray:
        """An estimate from fewer cameras than the last confirmed ones, moved by those cameras' offset
        from them (step 9, :mod:`tracker.handover`); unchanged otherwise."""
        X, d = self.handover.apply(t_s, X, uv_px, ok)
        if d is not None:
            self.stats.handovers += 1
            notes.append(f"{info.support}-camera estimate moved {1e3 * float(np.linalg.norm(d)):.1f} mm by the offset of those cameras "
                         "from the last confirmed positions (support hand-over)")
        return X

    def _choose_ball(self, t_s: float, X, info, size_ratio: float, usable: list, used_roi: np.ndarray, notes: list):
        """Step 10 (:mod:`tracker.hypotheses`): the positions of this frame set join the hypotheses and
        the ball in play is reported. Positions: on a full-frame search every consistent set, best
        first, each through the size test (the second and later ones only with ``Status.OK``); else
        the one set the windows hold. Returns ``(X, info, size_ratio, withheld)``; ``withheld``:
        positions exist but none is reported (X None)."""
        hyp = self.hypotheses
        full = not used_roi[usable].any()
        if full:
            hyp.searched_full_frame(t_s)
        sets = [] if X is None else [(X, info, size_ratio)]
        if full and X is not None:
            uv = self._uv.copy()
            while len(sets) < hyp.options.max_hypotheses:
                cams = np.flatnonzero(sets[-1][1].candidate_index >= 0)
                uv[cams, sets[-1][1].candidate_index[cams]] = np.nan  # the next best set: without these candidates
                X2, info2, ratio2, _ = self.estimator.estimate_checked(uv, self._size_stage)
                if info2.status is not Status.OK:  # two rays nearly always meet: a second ball needs min_support cameras
                    break
                sets.append((X2, info2, ratio2))
        row = hyp.update(t_s, np.array([s[0] for s in sets]).reshape(-1, 3))
        if row < 0:
            if sets:
                self.stats.withheld += 1
                notes.append(f"{len(sets)} ball position(s), none in play (moving across the table) nor the ball reported before; no position reported")
            return None, info, math.nan, bool(sets)
        if hyp.switched:
            self.stats.lead_changes += 1
            self.forget_motion(hypotheses=False)  # the prediction and the hand-over belonged to the other ball
            notes.append(f"reported ball changed to one in play (set {row + 1} of {len(sets)} positions)")
        elif row > 0:
            notes.append(f"reported the ball in play, set {row + 1} of {len(sets)} positions")
        return (*sets[row], False)

    def _estimate(self, notes: list):
        """The consensus of the current candidates, the 3D size test its last stage (the candidates it
        drops stay in ``self._uv``, which PipelineInfo reports). Returns (X, info, ratio)."""
        X, info, ratio, rejected = self.estimator.estimate_checked(self._uv, self._size_stage)
        for cams, r in rejected:
            notes.append(self._size.rejection_note(cams, r))
        self.stats.size_rejections += len(rejected)
        return X, info, ratio

    def _detect(self, cams: list[int], roi_px: np.ndarray, use_window: np.ndarray) -> None:
        """One detector call per camera in ``cams``: in the window around ``roi_px[i]`` where
        ``use_window[i]``, else on the full frame. Fills the estimator's input rows and the stats."""
        boxes = search_boxes(roi_px, use_window, self._roi_half, self._wh)
        pool = self._pool
        if pool is not None and len(cams) > 1 and (self.options.threads_for_roi or not use_window[cams].all()):
            w = min(self.options.workers, len(cams))
            chunks = [cams[j::w] for j in range(w)]
            futures = [pool.submit(self._detect_chunk, c, roi_px, boxes) for c in chunks[1:]]
            self._detect_chunk(chunks[0], roi_px, boxes)  # the calling thread takes a share too
            for f in futures:
                f.result()
        else:
            self._detect_chunk(cams, roi_px, boxes)
        st = self.stats
        if self.cues is not None:
            st.still_candidates += int(self._still[cams].sum())
            self._still[cams] = 0
        for i in cams:
            d = self._dets[i]
            m = 0 if d is None else len(d)
            if m:
                self._uv[i, :m] = d.uv_px
                self._uv[i, :m] += boxes[i, :2]  # sub-image -> image pixels
                self._scores[i, :m] = d.scores
                self._areas[i, :m] = d.areas_px
            if use_window[i]:
                st.roi_searches += 1
                st.roi_misses += m == 0
            else:
                st.full_frame_searches += 1

    def _detect_chunk(self, cams, roi_px, boxes) -> None:
        dets, images, cues = self._dets, self._images, self.cues
        for i in cams:
            det = self.detectors[i]
            x0, y0, x1, y1 = boxes[i]
            full = x0 >= 0 and x1 - x0 == self._wh[i, 0] and y1 - y0 == self._wh[i, 1]
            if cues is not None:  # every frame it is given; the cells that moved where the full frame is searched
                cues[i].observe(images[i], self._t_s, frame=self._frame_no, need_mask=full)
            if x0 < 0:
                dets[i] = None  # the predicted window lies outside this camera's image
            elif full:
                whole = cues is None or cues[i].whole_frame_due(self._t_s)  # no cue, or a still ball's turn
                boxes_i = None if whole else cues[i].regions(self._margin_px[i])
                if boxes_i is not None:  # only where the frame moved (tracker.motion)
                    dets[i] = self._moving(i, self._in_regions(det, images[i], boxes_i))
                else:
                    d = det.detect(images[i]) if self.pyramid[i] is None else self.pyramid[i].detect(images[i])
                    dets[i] = d if whole else self._moving(i, d)
            else:  # the neighbourhood: its window first, then at most the whole neighbourhood
                dets[i] = search_around(det, images[i][y0:y1, x0:x1], roi_px[i] - boxes[i, :2], images[i].shape)

    def _in_regions(self, det: BallDetector, image: np.ndarray, regions: list) -> Detections:
        """A full-frame search of ``image`` in the boxes ``regions`` alone: each box's candidates, the best
        ``max_candidates`` of them all (an empty list: none)."""
        h, w = image.shape[:2]
        c = REGION_CONTEXT_PX["filter" if det.learned is None else "learned"]
        found = []
        for x0, y0, x1, y1 in regions:  # searched with more around it; the candidates inside the box kept
            win = (max(x0 - c, 0), max(y0 - c, 0), min(x1 + c, w), min(y1 + c, h))
            if det.learned is not None:
                win = det.learned.aligned_window(win, h, w)
            d = det.detect(image, win)
            if len(d):
                u, v = d.uv_px[:, 0], d.uv_px[:, 1]
                keep = (u > x0 - 0.5) & (u < x1 - 0.5) & (v > y0 - 0.5) & (v < y1 - 0.5)
                if keep.any():
                    found.append(Detections(d.uv_px[keep], d.scores[keep], d.boxes_xywh[keep], d.areas_px[keep], False))
        if not found:
            return Detections.empty()
        if len(found) == 1:
            d = found[0]
            return Detections(d.uv_px, d.scores, d.boxes_xywh, d.areas_px, False)
        scores = np.concatenate([d.scores for d in found])
        order = np.argsort(-scores, kind="stable")[: det.options.k]
        return Detections(np.concatenate([d.uv_px for d in found])[order], scores[order],
                          np.concatenate([d.boxes_xywh for d in found])[order], np.concatenate([d.areas_px for d in found])[order], False)

    def _moving(self, i: int, det: Detections) -> Detections:
        """The full-frame candidates of camera ``i`` on cells its motion cue saw move (all without a cue)."""
        if len(det) == 0:
            return det
        keep = self.cues[i].moved(det.uv_px, det.boxes_xywh[:, 2:].max(axis=1))
        if keep.all():
            return det
        self._still[i] = int((~keep).sum())  # (counted in _detect once the threads are done)
        return Detections(det.uv_px[keep], det.scores[keep], det.boxes_xywh[keep], det.areas_px[keep], det.used_roi)


@dataclass
class _Deferred:
    """A full-frame search in flight (``TrackerOptions.defer_full_frame``): its future (-> ``(X, info, ratio)``), the
    frame set's time, usable cameras and window mask (the fallback updates it) and its kind."""

    future: Future
    t_s: float
    usable: list
    used_roi: np.ndarray
    retry: bool  #: the windows' fallback (else a frame set without a prediction)


def _region_margins(rig: Rig, ball_radius_m: float) -> np.ndarray:
    """(n_cams,) the largest ball radius in each camera, pixels, over the rig's workspace (32 px without one,
    or where a camera sees none of it): how far a ball's centre may lie from the cells its edge moved."""
    out = np.full(len(rig), 32.0)
    if rig.workspace_m is not None:
        d = ball_diameter_range_px(rig, ball_radius_m=ball_radius_m)[:, 1]
        out = np.where(np.isfinite(d), 0.5 * d + 2.0, out)
    return out


def _search_order(rig: Rig) -> list[int]:
    """Camera indices, those that see most of the rig's workspace box first (a 5x5x5 grid of points whose
    pixel falls in the image, in front of the camera); rig order among equals and without a workspace."""
    if rig.workspace_m is None:
        return list(range(len(rig)))
    lo, hi = np.asarray(rig.workspace_m, float)
    axes = [np.linspace(a, b, 5) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    seen = []
    for cam in rig:
        uv = cam.project(grid)
        w, h = cam.image_size
        with np.errstate(invalid="ignore"):
            inside = (cam.depth(grid) > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        seen.append(int(inside.sum()))
    return sorted(range(len(rig)), key=lambda i: (-seen[i], i))


def _pyramid_searches(rig: Rig, detectors: list, options: TrackerOptions) -> list:
    """Per camera its :class:`PyramidSearch` of the full frame, or None for the full resolution
    (``TrackerOptions.full_frame_pyramid``, :mod:`tracker._pipeline_pyramid`)."""
    out: list = [None] * len(rig)
    if not (options.full_frame_pyramid and options.size_from_rig) or rig.workspace_m is None or detectors[0].learned is not None:
        return out
    levels = pyramid_levels(ball_diameter_range_px(rig, ball_radius_m=options.ball_radius_m)[:, 0])
    made: dict = {}
    for i, k in enumerate(levels):
        if k > 0:
            key = (id(detectors[i]), int(k))
            if key not in made:
                made[key] = PyramidSearch(detectors[i], int(k))
            out[i] = made[key]
    return out


def _sized_detectors(rig: Rig, detector: BallDetector) -> list[BallDetector]:
    """One detector per camera with the size limits of the rig's workspace (``TrackerOptions.size_from_rig``,
    :mod:`tracker.ball_size`); ``detector`` itself for the cameras whose limits it already has."""
    if rig.workspace_m is None:
        return [detector] * len(rig)
    o = detector.options
    lim = size_limits(ball_diameter_range_px(rig), detector.area_range_px, o.roi_half_size_px, edge_loss_px=detector.edge_loss_px)
    out, made = [], {}
    for i in range(len(rig)):
        (lo, hi), half = lim.area_px[i], int(lim.roi_half_size_px[i])
        if (lo, hi) == detector.area_range_px and half == o.roi_half_size_px:
            out.append(detector)
            continue
        key = (lo, hi, half)
        if key not in made:
            made[key] = BallDetector(detector.model, replace(o, roi_half_size_px=half,
                                                             min_area_px=int(lo) if lo != detector.area_range_px[0] else o.min_area_px,
                                                             max_area_px=int(hi) if hi != detector.area_range_px[1] else o.max_area_px))
        out.append(made[key])
    return out
