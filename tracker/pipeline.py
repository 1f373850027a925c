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

Per frame set (rt2 kinds): validate the frame set (``ValueError`` for a wrong type or camera count),
flag cameras without a usable frame, predict the ball's pixels, one detector call per camera
(optionally on a thread pool), the robust estimate, and, when a window search did not confirm the
ball, a second full-frame search of the cameras that used a window; then the size test, the ball
hypotheses and the support hand-over (``rt2``).
See docs/pipeline.md.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from checks.arrays import describe
from tracker._pipeline_options import (
    DEFAULT_MODEL,
    KINDS,
    TRACKER_KINDS,
    PipelineInfo,
    TrackerOptions,
    TrackerStats,
    detector_options_for,
    estimator_options_for,
    load_model,
    with_overrides,
)
from tracker.ball_size import ball_diameter_range_px, rtblob_radius_floor_px, size_limits
from tracker.handover import SupportHandover
from tracker._pipeline_roi import MotionPredictor
from tracker.size_test import SizeTest
from tracker.hypotheses import BallHypotheses
from tracker._rtblob_detect import image_problem
from tracker.detection import BallDetector, DetectorOptions
from tracker.observation import BallObservation, FrameSet, Status
from tracker.rig import Rig
from tracker.robust import RobustOptions, RobustTriangulator
from tracker.rtblob import RTBlobOptions, RTBlobTracker

__all__ = ["DEFAULT_MODEL", "KINDS", "TRACKER_KINDS", "PipelineInfo", "Tracker", "TrackerOptions", "TrackerStats", "load_model", "make_tracker"]


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
        if kind not in KINDS:
            raise ValueError(f"unknown tracker kind {kind!r}; valid: {list(TRACKER_KINDS)}")
        options = with_overrides(options, overrides)
        det_method, est_method, roi_default = KINDS[kind]
        self.rig, self.kind, self.n_cams = rig, kind, len(rig)
        self.roi = roi_default if options.roi is None else bool(options.roi)
        self.stats = TrackerStats()
        self._names = rig.names
        self._sizes_wh = [tuple(c.image_size) for c in rig]
        self._wh = np.array(self._sizes_wh, np.int64)  # (n_cams, 2) width, height
        self._last_t_s: float | None = None
        self._closed = False
        self._pool = None
        self._rtblob = self._detector = self._estimator = None
        if kind == "rtblob":
            for name, given in (("model", model), ("detector_options", detector_options), ("estimator_options", estimator_options), ("eps_px", options.eps_px)):
                if given is not None:
                    raise ValueError(f"kind 'rtblob' takes no {name} (it has its own detector and stereo pairs); use rtblob_options")
            if options.roi:
                raise ValueError("kind 'rtblob' has no ROI search (RTBlob always searches the full frame); pass roi=False or None")
            if options.workers != 1:
                raise ValueError(f"kind 'rtblob' runs its cameras in its own loop; workers must be 1, got {options.workers}")
            rtblob_options = RTBlobOptions() if rtblob_options is None else rtblob_options
            if options.size_from_rig:
                rtblob_options = _rtblob_sized(rig, rtblob_options)
            self._rtblob = RTBlobTracker(rig, rtblob_options)
            self.options = options
            return
        if rtblob_options is not None:
            raise ValueError(f"rtblob_options apply to kind 'rtblob' only, got kind {kind!r}")
        self.options = options
        model = load_model(model)
        self._detector = BallDetector(model, detector_options_for(kind, det_method, detector_options))
        self._detectors = _sized_detectors(rig, self._detector) if options.size_from_rig else [self._detector] * len(rig)
        self._roi_half = np.array([d.options.roi_half_size_px for d in self._detectors], np.int64)[:, None]  # (n_cams, 1)
        self._estimator = RobustTriangulator(rig, estimator_options_for(estimator_options, options.eps_px), method=est_method)
        k = self._detector.options.k
        if k > self._estimator.options.max_candidates_per_camera:
            raise ValueError(
                f"detector_options.max_candidates ({k}) exceeds estimator_options.max_candidates_per_camera "
                f"({self._estimator.options.max_candidates_per_camera}); raise the latter or lower the former"
            )
        self._motion = MotionPredictor(rig, options.max_gap_s)
        self._size = SizeTest(rig, options.max_size_ratio if kind == "rt2" else None, options.ball_radius_m,
                              model.edge_loss_px if options.blob_edge_px is None else options.blob_edge_px)
        self._handover = None
        if kind == "rt2" and options.handover_max_age_s is not None:
            self._handover = SupportHandover(self._estimator, len(rig), max_age_s=options.handover_max_age_s)
        self._hyp = BallHypotheses(options.hypotheses) if kind == "rt2" and options.hypotheses is not None else None
        n = self.n_cams
        self._uv = np.full((n, k, 2), np.nan)  # the estimator's input, reused every frame set
        self._scores = np.full((n, k), np.nan)
        self._areas = np.full((n, k), np.nan)  # blob areas, px (the size test's input)
        self._dets = [None] * n
        if options.workers > 1:
            self._pool = ThreadPoolExecutor(options.workers - 1, thread_name_prefix="rt2-detect")

    def __repr__(self) -> str:
        return f"Tracker({self.kind!r}, {self.n_cams} cameras, roi={self.roi}, workers={self.options.workers})"

    # -- life cycle -------------------------------------------------------------------------------
    def reset(self, *, clear_stats: bool = False) -> None:
        """Forget the motion state and the last timestamp (a new rally or recording); keep the stats
        unless ``clear_stats``."""
        if self._detector is not None:
            self._forget_motion()
        self._last_t_s = None
        if clear_stats:
            self.stats = TrackerStats()

    def _forget_motion(self, *, hypotheses: bool = True) -> None:
        self._motion.reset()
        if self._handover is not None:
            self._handover.reset()
        if hypotheses and self._hyp is not None:
            self._hyp.reset()

    def close(self) -> None:
        """Stop the worker threads (``workers > 1``); the tracker refuses frame sets afterwards."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
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

    def process_with_info(self, frameset: FrameSet) -> tuple[BallObservation, PipelineInfo]:
        """The observation and the evidence behind it (:class:`PipelineInfo`)."""
        t0 = time.perf_counter()
        t_s, images = self._check_frameset(frameset)
        notes: list[str] = []
        self.stats.frames += 1
        if not math.isfinite(t_s):  # a broken clock mid-run: a note, never an exception
            notes.append(f"timestamp is not finite (t_s={t_s!r}); motion prediction reset, full frames searched")
            self.stats.non_monotonic += 1
            if self._detector is not None:
                self._forget_motion()
            t_s = math.nan  # (inf too) never kept as the last time; the motion model ignores it
        elif self._last_t_s is not None and not t_s > self._last_t_s:
            notes.append(f"non-monotonic timestamp: t_s={t_s!r} after {self._last_t_s!r}; motion prediction reset")
            self.stats.non_monotonic += 1
            if self._detector is not None:
                self._forget_motion()
        if math.isfinite(t_s):
            self._last_t_s = t_s
        usable = self._usable_frames(images, notes)
        if self._rtblob is not None:
            return self._process_rtblob(frameset, usable, images, notes, t0)
        return self._process_rt2(t_s, images, usable, notes, t0)

    # -- helpers ----------------------------------------------------------------------------------
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

    def _process_rt2(self, t_s: float, images, usable: list[int], notes: list, t0: float):
        n = self.n_cams
        self._images = images
        roi_px = self._motion.predict_pixels(t_s) if self.roi else None
        hyp = self._hyp
        if roi_px is not None and hyp is not None and hyp.wants_full_frame(t_s):
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
        self._detect(usable, roi_px, used_roi)  # Algorithm 1 per camera (paper Sec. 2.1)
        X, info, size_ratio = self._estimate(notes)  # Algorithm 2 (paper Sec. 2.2; "ours" extends it), then the 3D size test
        retried = False
        if self.options.retry_full_frame and info.status is not Status.OK and used_roi.any():
            # The full-frame fallback, only when the windows did not confirm the ball (also when the
            # size test rejected what they held). Every camera that searched a window is redone: with
            # two agreeing cameras, those two may be the ones whose windows hold the wrong object (any
            # two rays nearly meet).
            redo = [i for i in usable if used_roi[i]]
            if redo:
                retried = True
                self.stats.full_frame_retries += 1
                notes.append(f"window search gave {info.status.value}; full frame searched in {', '.join(self._names[i] for i in redo)}")
                self._uv[redo] = np.nan
                self._scores[redo] = np.nan
                self._areas[redo] = np.nan
                used_roi[redo] = False
                self._detect(redo, roi_px, used_roi)
                X, info, size_ratio = self._estimate(notes)
        withheld = False
        if hyp is not None and math.isfinite(t_s):
            X, info, size_ratio, withheld = self._choose_ball(t_s, X, info, size_ratio, usable, used_roi, notes)
        ok = info.status is Status.OK and not withheld
        cand = info.candidate_index
        uv_px = np.full((n, 2), np.nan)
        sel = np.flatnonzero(cand >= 0) if not withheld else np.zeros(0, np.int64)
        uv_px[sel] = self._uv[sel, cand[sel]]
        if X is not None and self._handover is not None and math.isfinite(t_s):
            X = self._hand_over(t_s, X, info, uv_px, ok, notes)
        if ok and math.isfinite(t_s):
            self._motion.update(t_s, X)  # only confirmed estimates feed the prediction
        self.stats.positions += X is not None
        self.stats.ok += ok
        pinfo = PipelineInfo(self._uv.copy(), self._scores.copy(), roi_px, used_roi, retried, info, size_ratio, self._areas.copy(),
                             *((hyp.positions(), hyp.in_play()) if hyp is not None else (None, None)))
        self._images = None  # do not keep the frames alive
        obs = BallObservation(
            t_s=t_s,
            position_m=X,
            covariance_m2=None if withheld else info.covariance_m2,
            support=0 if withheld else info.support,
            inliers=np.zeros(n, bool) if withheld else info.inliers,
            status=Status.NO_CONSENSUS if withheld else info.status,
            latency_s=time.perf_counter() - t0,  # entry to return
            tracker=self.kind,
            uv_px=uv_px,
            notes=tuple(notes),
        )
        return obs, pinfo

    def _hand_over(self, t_s: float, X: np.ndarray, info, uv_px: np.ndarray, ok: bool, notes: list) -> np.ndarray:
        """An estimate from fewer cameras than the last confirmed ones, moved by those cameras' offset
        from them (step 9, :mod:`tracker.handover`); unchanged otherwise."""
        X, d = self._handover.apply(t_s, X, uv_px, ok)
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
        hyp = self._hyp
        full = not used_roi[usable].any()
        if full:
            hyp.searched_full_frame(t_s)
        sets = [] if X is None else [(X, info, size_ratio)]
        if full and X is not None:
            uv = self._uv.copy()
            while len(sets) < hyp.options.max_hypotheses:
                cams = np.flatnonzero(sets[-1][1].candidate_index >= 0)
                uv[cams, sets[-1][1].candidate_index[cams]] = np.nan  # the next best set: without these candidates
                X2, info2 = self._estimator.estimate(uv)
                X2, info2, ratio2, _ = self._size.apply(self._estimator, uv, self._areas, X2, info2)
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
            self._forget_motion(hypotheses=False)  # the prediction and the hand-over belonged to the other ball
            notes.append(f"reported ball changed to one in play (set {row + 1} of {len(sets)} positions)")
        elif row > 0:
            notes.append(f"reported the ball in play, set {row + 1} of {len(sets)} positions")
        return (*sets[row], False)

    def _estimate(self, notes: list):
        """The robust estimate of the current candidates, then the 3D size test (the candidates it drops
        stay in ``self._uv``, which PipelineInfo reports). Returns (X, info, ratio)."""
        X, info = self._estimator.estimate(self._uv)
        X, info, ratio, rejections = self._size.apply(self._estimator, self._uv, self._areas, X, info, notes)
        self.stats.size_rejections += rejections
        return X, info, ratio

    def _detect(self, cams: list[int], roi_px: np.ndarray, use_window: np.ndarray) -> None:
        """One detector call per camera in ``cams``: in the window around ``roi_px[i]`` where
        ``use_window[i]``, else on the full frame. Fills the estimator's input rows and the stats."""
        boxes = self._search_boxes(roi_px, use_window)
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

    def _search_boxes(self, roi_px: np.ndarray, use_window: np.ndarray) -> np.ndarray:
        """(n_cams, 4) int ``[x0, y0, x1, y1]`` image region handed to the detector per camera: the
        window of half side ``h`` around the prediction plus a margin of ``h / 2`` (where the image
        has it), so the detector's own fallback (empty or truncated window) searches only that
        neighbourhood, never the full frame; ``[0, 0, W, H]`` for a full-frame search; ``x0 = -1``
        for a window entirely outside the image (nothing to search)."""
        half = self._roi_half
        margin = half // 2
        wh = self._wh
        boxes = np.zeros((self.n_cams, 4), np.int64)
        boxes[:, 2:] = wh
        if use_window.any():
            c = np.rint(np.where(use_window[:, None], roi_px, 0.0)).astype(np.int64)
            inside = ((c + half > 0) & (c - half < wh)).all(axis=1)
            lo = np.clip(c - half - margin, 0, wh)
            hi = np.clip(c + half + margin, 0, wh)
            sel = use_window & inside
            boxes[sel, :2], boxes[sel, 2:] = lo[sel], hi[sel]
            boxes[use_window & ~inside, 0] = -1
        return boxes

    def _detect_chunk(self, cams, roi_px, boxes) -> None:
        dets, images = self._dets, self._images
        for i in cams:
            det = self._detectors[i]
            x0, y0, x1, y1 = boxes[i]
            if x0 < 0:
                dets[i] = None  # the predicted window lies outside this camera's image
            elif x1 - x0 == self._wh[i, 0] and y1 - y0 == self._wh[i, 1]:
                dets[i] = det.detect(images[i])  # the full frame
            else:  # a view of the neighbourhood: the detector searches its window, then at most the view
                dets[i] = det.detect(images[i][y0:y1, x0:x1], roi_px[i] - boxes[i, :2])

    def _process_rtblob(self, frameset: FrameSet, usable: list[int], images, notes: list, t0: float):
        blanked = [i for i in range(self.n_cams) if images[i] is not None and i not in usable]
        t_s = float(frameset.t_s)
        if blanked or not math.isfinite(t_s):  # RTBlob raises on a non-image or a NaN time; we note them
            imgs = list(images)
            for i in blanked:
                imgs[i] = None
            frameset = FrameSet(t_s if math.isfinite(t_s) else 0.0, tuple(imgs), frameset.index)
        obs, info = self._rtblob.process_with_info(frameset)
        obs = obs if math.isfinite(t_s) else replace(obs, t_s=t_s)
        ours = set(notes)
        drop = {f"camera {self._names[i]}: no frame" for i in blanked} | ours
        notes.extend(s for s in obs.notes if s not in drop)
        n = self.n_cams
        pinfo = PipelineInfo(obs.uv_px[:, None, :].copy(), info.scores[:, None].copy(), np.full((n, 2), np.nan), np.zeros(n, bool), False, info)
        self.stats.positions += obs.position_m is not None
        self.stats.ok += obs.status is Status.OK
        return replace(obs, notes=tuple(notes), latency_s=time.perf_counter() - t0), pinfo


def _sized_detectors(rig: Rig, detector: BallDetector) -> list[BallDetector]:
    """One detector per camera with the size limits of the rig's workspace (``TrackerOptions.size_from_rig``,
    :mod:`tracker.ball_size`); ``detector`` itself for the cameras whose limits it already has."""
    if rig.workspace_m is None:
        return [detector] * len(rig)
    o = detector.options
    lim = size_limits(ball_diameter_range_px(rig), detector.area_range_px, o.roi_half_size_px, edge_loss_px=detector.model.edge_loss_px)
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


def _rtblob_sized(rig: Rig, options: RTBlobOptions) -> RTBlobOptions:
    """RTBlob's options with each camera's template raised to the farthest ball's radius where the
    ``expected_distance_m`` sizing is smaller (``TrackerOptions.size_from_rig``); unchanged when the
    rig has no workspace, the radii are given, or no camera needs it."""
    if rig.workspace_m is None or options.template_radius_px is not None:
        return options
    floor = rtblob_radius_floor_px(ball_diameter_range_px(rig, ball_radius_m=options.ball_radius_m))
    expected = [0.5 * (c.K[0, 0] + c.K[1, 1]) * options.ball_radius_m / options.expected_distance_m for c in rig]
    if not any(f > e for f, e in zip(floor, expected)):  # NaN floor (camera sees no workspace): keep
        return options
    return replace(options, template_radius_px=tuple(float(max(e, f)) if f > e else float(e) for f, e in zip(floor, expected)))


def make_tracker(kind: str, rig: Rig, **kwargs) -> Tracker:
    """The tracker of ``kind`` (one of ``TRACKER_KINDS``) on ``rig``; keyword arguments as :class:`Tracker`."""
    if kind not in KINDS:
        raise ValueError(f"unknown tracker kind {kind!r}; valid: {list(TRACKER_KINDS)}")
    return Tracker(rig, kind, **kwargs)
