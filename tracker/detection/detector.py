"""Ball detection per camera: the segmentation model + Algorithm 1, full frame or around a predicted pixel.

``BallDetector.detect(image, window)`` turns one RGB image, or one box of it, into ball candidates.
It trusts its inputs: images are checked once where a frame set comes in (:mod:`tracker.images`,
:class:`~tracker.pipeline.Tracker`), and which box to search, and what to do when a box holds no
ball, is the pipeline's decision (``tracker._pipeline_roi.search_around``). The pipeline packs the
candidates of a frame set into the estimator's ``(n_cams, k, 2)`` layout.

Methods (``DetectorOptions.method``):

* ``"paper"`` — the paper's Algorithm 1 as published: argmax, ``T_h`` test, flood fill above
  ``T_l``; one candidate, no shape test.
* ``"ours"`` — the top-K variant: up to ``max_candidates`` blobs (each a connected component of
  ``{B > T_l}`` with peak ``>= T_h``, best first), each passing a shape test (area, fill ratio,
  aspect). The robust estimator then picks the candidate the other cameras agree with. When the
  model carries a :class:`~tracker.detection.verifier.CandidateVerifier` (and ``verify`` is on),
  every accepted blob among the first ``max_seeds`` is scored by it on its crop; candidates below
  its threshold are dropped, the rest are ordered by its probability (which becomes the score) and
  their centres refined, and the first ``max_candidates`` are reported. When the model carries a
  :class:`~tracker.detection.learned.LearnedStage` (and ``learned`` is on), the heatmap network finds the
  candidates instead of the filter and Algorithm 1 (the local maxima of its heat, best first, with a
  sub-pixel centre and the ball's diameter); "paper" always uses the filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from checks.arrays import describe
from checks.per_thread import PerThread
from tracker.detection._correlate import blob_frontier, coarse_grid, grid_boxes
from tracker.detection.blobs import find_blobs
from tracker.detection.edge_refine import chroma_for, refine_edges
from tracker.detection.model import BallSegmentationModel, LogitWorkspace, logit, sigmoid

__all__ = ["BallDetector", "DetectorOptions", "Detections", "METHODS"]

#: detection methods (see the module docstring)
METHODS = ("paper", "ours")
#: what the edge fit of ``refine_edges`` looks at (``DetectorOptions.edge_channel``)
EDGE_CHANNELS = ("auto", "grey", "chroma")
#: the filter's blob refines a learned centre only when its centroid is within this share of the ball's diameter ...
REFINE_MAX_SHIFT = 0.3
#: ... and it covers at least this share of the ball's disk (a ball of the filter's colour, not an edge beside one)
REFINE_MIN_AREA = 0.25
#: the learned stage's candidates have no area limit of their own: the largest area accepted unless the options set one
LEARNED_MAX_AREA_PX = 10**7


@dataclass(frozen=True)
class DetectorOptions:
    """Options of :class:`BallDetector`.

    method : "paper" (Algorithm 1, one candidate) or "ours" (top-K with a shape test)
    t_high, t_low : Algorithm 1 thresholds ``T_h``, ``T_l`` as probabilities; ``None`` = the model's
        recommended values (chosen on its training validation split)
    max_candidates : K, candidates reported per image by "ours" ("paper" reports at most 1)
    max_seeds : blobs grown per image at most by "ours", accepted or not (bounds the time per image)
    roi_half_size_px : half side of the search window around a predicted pixel
    min_area_px, max_area_px : accepted blob area ("ours"); ``None`` = the model's recommended
        ``area_range_px`` (from the ball sizes it was trained on)
    min_fill_ratio : accepted blob area / box area ("ours"; a disk fills pi/4 ~ 0.79 of its box)
    max_aspect : accepted box long side / short side ("ours"; motion blur stretches the ball)
    backend : flood-fill implementation, "numba" or "python" (reference)
    verify : run the model's candidate verifier ("ours" only; ignored when the model has none)
    learned : find the candidates with the model's learned stage ("ours" only; ignored when the model has
        none): the heatmap network instead of the filter and Algorithm 1
    learned_threshold : the learned stage's threshold, a probability (of the confirmation network on a whole frame
        where the stage has one, else of the heat); ``None`` = the stage's own
    confirm : on a whole frame, the learned stage's confirmation network looks again at its best candidates
        (:mod:`tracker.detection.confirm`; ignored when the stage has none); False: the heat alone ranks them
    refine_with_filter : the learned stage's centres refined by the model's filter where it sees the ball: in a box of
        the candidate's diameter (plus 3 px) around it, Algorithm 1's blob (the model's thresholds), when its
        weighted centroid lies within 0.3 diameters of the candidate and it covers a quarter of the ball's disk, gives the centre (sub-pixel to a few
        hundredths of a pixel on balls of the filter's colour), for a stage whose filter sees its balls
        (``LearnedStage.filter_refines``)
    coarse_full_frame : "ours" searches a full frame coarse to fine: approximate logits first on every other pixel
        of every other row, from those pixels alone (a 3x3 kernel made of the 5x5 one: about a sixteenth of the work),
        then the exact logits only in the 16x16-pixel blocks within 2 pixels of a coarse logit above
        ``logit(T_l) - COARSE_MARGIN_LOGIT``, the rest of the frame below any threshold; Algorithm 1 then runs as on
        the full frame, and finds the full search's candidates wherever the coarse pass reached them
        (docs/detector.md, "Coarse to fine", measures how often); False computes every pixel ("paper" always does)
    refine_edges : where the stage's filter does not see its balls (a white ball, an orange filter), the centre of
        each candidate from a circle fitted to its radial edge (:mod:`tracker.detection.edge_refine`; on the
        semi-real caliscope frames' real white balls the median centre error 4.0 -> 0.6 px); its diameter stays
        the network's; False keeps the network's centre
    edge_channel : the image the edge fit looks at: "grey" (OpenCV's luminance), "chroma" (``255 (R - B) / (R + G +
        B + 30)``: a saturated ball's colour, which its shaded side keeps where its brightness falls off; on drawn
        orange balls in real frames the median centre error 3.1 -> 0.7 px, docs/detector.md "Centres from the ball's
        edge"), or "auto": chroma for a model of orange balls (``BallSegmentationModel.ball_colour``), grey otherwise
    """

    method: str = "ours"
    t_high: float | None = None
    t_low: float | None = None
    max_candidates: int = 4
    max_seeds: int = 16
    roi_half_size_px: int = 32
    min_area_px: int | None = None
    max_area_px: int | None = None
    min_fill_ratio: float = 0.3
    max_aspect: float = 4.0
    backend: str = "numba"
    verify: bool = True
    learned: bool = True
    learned_threshold: float | None = None
    confirm: bool = True
    refine_with_filter: bool = True
    refine_edges: bool = True
    coarse_full_frame: bool = True
    edge_channel: str = "auto"

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"DetectorOptions.method must be one of {METHODS}, got {self.method!r}")
        for name in ("t_high", "t_low"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and 0.0 < v < 1.0):
                raise ValueError(f"DetectorOptions.{name} must be a probability in (0, 1) or None, got {v!r}")
        if self.t_high is not None and self.t_low is not None and not self.t_low < self.t_high:
            raise ValueError(f"DetectorOptions: need t_low < t_high, got t_low={self.t_low}, t_high={self.t_high}")
        for name in ("max_candidates", "max_seeds", "roi_half_size_px", "min_area_px", "max_area_px"):
            v = getattr(self, name)
            if v is None and name in ("min_area_px", "max_area_px"):
                continue
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"DetectorOptions.{name} must be a positive integer, got {v!r}")
        if self.max_seeds < self.max_candidates:
            raise ValueError(f"DetectorOptions: max_seeds ({self.max_seeds}) must be >= max_candidates ({self.max_candidates})")
        if self.min_area_px is not None and self.max_area_px is not None and self.min_area_px > self.max_area_px:
            raise ValueError(f"DetectorOptions: min_area_px ({self.min_area_px}) > max_area_px ({self.max_area_px})")
        if not 0.0 <= self.min_fill_ratio <= 1.0:
            raise ValueError(f"DetectorOptions.min_fill_ratio must be in [0, 1], got {self.min_fill_ratio!r}")
        if not self.max_aspect >= 1.0:
            raise ValueError(f"DetectorOptions.max_aspect must be >= 1, got {self.max_aspect!r}")
        for name in ("verify", "learned", "confirm", "refine_with_filter", "refine_edges", "coarse_full_frame"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"DetectorOptions.{name} must be True or False, got {getattr(self, name)!r}")
        v = self.learned_threshold
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < v < 1.0):
            raise ValueError(f"DetectorOptions.learned_threshold must be a probability in (0, 1) or None, got {v!r}")
        if self.edge_channel not in EDGE_CHANNELS:
            raise ValueError(f"DetectorOptions.edge_channel must be one of {EDGE_CHANNELS}, got {self.edge_channel!r}")
        if self.backend not in ("numba", "python"):
            raise ValueError(f"DetectorOptions.backend must be 'numba' or 'python', got {self.backend!r}")

    @property
    def k(self) -> int:
        """Candidates per image in the estimator's ``(n_cams, k, 2)`` layout."""
        return 1 if self.method == "paper" else self.max_candidates


@dataclass(frozen=True, eq=False)
class Detections:
    """Ball candidates in one image, best first.

    uv_px : (k, 2) sub-pixel centres, distorted pixels (u = column, v = row; (0, 0) = centre of the top-left pixel)
    scores : (k,) peak ball probability of each candidate, in [T_h, 1]
    boxes_xywh : (k, 4) boxes around each candidate's pixels, COCO convention ``[x, y, w, h]``
        (the top-left pixel spans [0, 1] x [0, 1]), so they compare directly with COCO labels
    areas_px : (k,) pixels per candidate
    used_roi : True when the candidates come from a window (``detect(image, window)``), not the whole image
    """

    uv_px: np.ndarray
    scores: np.ndarray
    boxes_xywh: np.ndarray
    areas_px: np.ndarray
    used_roi: bool = False

    def __len__(self) -> int:
        return len(self.scores)

    @classmethod
    def empty(cls, used_roi: bool = False) -> "Detections":
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 4)), np.zeros(0, dtype=np.int64), used_roi)


class BallDetector:
    """The segmentation model plus Algorithm 1, per image.

    model : :class:`BallSegmentationModel`
    options : :class:`DetectorOptions` (thresholds default to the model's recommended ones)
    """

    def __init__(self, model: BallSegmentationModel, options: DetectorOptions | None = None):
        if not isinstance(model, BallSegmentationModel):
            raise ValueError(f"model must be a BallSegmentationModel, got {describe(model)}")
        options = DetectorOptions() if options is None else options
        if not isinstance(options, DetectorOptions):
            raise ValueError(f"options must be a DetectorOptions, got {describe(options)}")
        t_high = model.t_high if options.t_high is None else options.t_high
        t_low = model.t_low if options.t_low is None else options.t_low
        if not t_low < t_high:
            raise ValueError(f"need t_low < t_high, got t_low={t_low} and t_high={t_high} (options and model defaults combined)")
        self.model = model
        self.options = options
        self.t_high, self.t_low = float(t_high), float(t_low)
        self._th_logit, self._tl_logit = logit(self.t_high), logit(self.t_low)  # B > T  <=>  logit(B) > logit(T)
        self._tl_frontier = _float32_at_or_below(self._tl_logit)  # the coarse-to-fine search's blob edge test
        self.learned = model.learned if options.method == "ours" and options.learned else None
        self._edge_chroma = options.edge_channel == "chroma" or (options.edge_channel == "auto" and chroma_for(model.ball_colour))
        # the learned stage reports each ball's diameter; its area range is open unless the options set one
        own_area = (1.0, float(LEARNED_MAX_AREA_PX)) if self.learned is not None else model.area_range_px
        min_area = own_area[0] if options.min_area_px is None else options.min_area_px
        max_area = own_area[1] if options.max_area_px is None else options.max_area_px
        if not min_area <= max_area:
            raise ValueError(f"need min_area_px <= max_area_px, got {min_area} and {max_area} (options and model defaults combined)")
        self.area_range_px = (float(min_area), float(max_area))
        if options.method == "paper":
            self._blob_kw = dict(max_blobs=1, max_seeds=1)
        else:
            self._blob_kw = dict(
                max_blobs=options.max_candidates,
                max_seeds=options.max_seeds,
                min_area_px=min_area,
                max_area_px=max_area,
                min_fill_ratio=options.min_fill_ratio,
                max_aspect=options.max_aspect,
            )
        self._blob_kw["backend"] = options.backend
        self._coarse = options.method == "ours" and options.coarse_full_frame
        self._work = PerThread(_Work)  # each thread's buffers of the full-frame search (not pickled)
        self.verifier = model.verifier if options.method == "ours" and options.verify else None
        if self.verifier is not None:  # every accepted blob goes to the verifier, which picks the K best
            self._blob_kw["max_blobs"] = options.max_seeds

    def __repr__(self) -> str:
        stage = ", learned stage" if self.learned is not None else ""
        return f"BallDetector(method={self.options.method!r}, t_high={self.t_high}, t_low={self.t_low}{stage})"

    @property
    def edge_loss_px(self) -> float:
        """How much narrower than the ball a candidate's width is, pixels (the 3D size test adds it back):
        the model's ``edge_loss_px`` for the filter's blobs, 0 for the learned stage (it reports the ball's diameter)."""
        return 0.0 if self.learned is not None else self.model.edge_loss_px

    @property
    def size_ratio(self) -> float | None:
        """The 3D size test's threshold this detector's candidate widths need (``LearnedStage.size_ratio``), or None
        (the tracker's own ``max_size_ratio``): the learned stage's record when it finds the candidates."""
        return None if self.learned is None else self.learned.size_ratio

    # -- one image -------------------------------------------------------------------------------
    def detect(self, image: np.ndarray, window=None, frame_shape=None) -> Detections:
        """Ball candidates in one image, or in one box of it.

        image : (H, W, 3) uint8 RGB, trusted (checked where it came in: :func:`tracker.images.check_image`)
        window : None = the whole image; else ``(x0, y0, x1, y1)`` integers, a non-empty box inside the
            image (``0 <= x0 < x1 <= W``, same for y): only its pixels are searched (the filter still
            sees the image's pixels around it)
        frame_shape : when ``image`` is a part of a camera frame (the pipeline's neighbourhood view), the frame's
            shape: the learned stage searches the part at the frame's scale (the filter needs no such hint)
        returns :class:`Detections` in the image's pixels, best first (``used_roi`` = a window was given)
        """
        if self.learned is not None:
            return self._detect_learned(image, window, frame_shape)
        work = self._work.get()  # a detector may serve several cameras on several threads
        if window is None:
            x0 = y0 = 0
            if self._coarse:
                logits, boxes = self._coarse_to_fine(image, work.logits)
                if logits is None:
                    return Detections.empty(False)
            else:
                logits, boxes = self.model.logits_trusted(image, work.logits), None  # into this thread's buffers: no allocation
        else:
            x0, y0, x1, y1 = window
            logits, boxes = np.ascontiguousarray(self.model.logits_window_trusted(image, x0, y0, x1, y1)), None
        blobs = find_blobs(logits, self._th_logit, self._tl_logit, overwrite=True, queues=work.queues(logits.size), seed_boxes=boxes, **self._blob_kw)
        return self._verified(image, _to_detections(blobs, x0, y0, window is not None))

    def _coarse_to_fine(self, image, work: LogitWorkspace):
        """``(logits, boxes)``: the full frame's logits where they can matter (``DetectorOptions.coarse_full_frame``),
        -inf outside the (n, 4) boxes ``boxes`` computed (the whole frame's and None when the blocks would cover most
        of it); ``(None, None)`` when no coarse logit reaches the coarse threshold (no ball). The blocks grow until no
        blob above T_l reaches the edge of the computed region: Algorithm 1's flood fills are the full frame's (a blob
        cut at a block's edge would be smaller, its centre moved, or pass an area limit the whole blob fails)."""
        coarse = self.model.logits_coarse_trusted(image, work)
        on = coarse_grid(coarse >= self._tl_logit - COARSE_MARGIN_LOGIT)
        h, w = image.shape[:2]
        blocks = grid_boxes(on, h, w)
        if len(blocks) == 0:
            return None, None
        room = COARSE_MAX_SHARE * h * w - _box_area(blocks)
        if room < 0:
            return self.model.logits_trusted(image, work), None
        logits = self.model.logits_blocks_trusted(image, blocks, work)
        while True:
            new = blob_frontier(logits, on, self._tl_frontier)
            more = grid_boxes(new, h, w)
            if len(more) == 0:
                return logits, work.filled_boxes
            room -= _box_area(more)
            if room < 0:
                return self.model.logits_trusted(image, work), None
            on |= new
            logits = self.model.logits_more_blocks_trusted(image, more, work)

    def _detect_learned(self, image, window, frame_shape) -> Detections:
        """The learned stage's candidates as :class:`Detections`: boxes of the predicted diameter around the
        sub-pixel centre, areas of the disk, the area range of the options applied."""
        o = self.options
        uv, scores, d = self.learned.candidates(image, window, k=o.max_seeds if o.min_area_px or o.max_area_px else o.max_candidates,
                                                threshold=o.learned_threshold, frame_shape=frame_shape, confirm=o.confirm)
        if len(d) == 0:
            return Detections.empty(window is not None)
        areas = np.pi / 4 * d * d
        lo, hi = self.area_range_px
        keep = (areas >= lo) & (areas <= hi)  # a NaN diameter is never kept
        if not keep.all():
            uv, scores, d, areas = uv[keep], scores[keep], d[keep], areas[keep]
        if len(d) > o.max_candidates:
            m = o.max_candidates
            uv, scores, d, areas = uv[:m], scores[:m], d[:m], areas[:m]
        if len(d) and self.learned.filter_refines:
            if o.refine_with_filter:
                uv = self._refined(image, uv, d)
        elif len(d) and o.refine_edges:  # the filter does not see this ball: its edge gives the centre
            uv = refine_edges(image, uv, d, self._edge_chroma)[0]  # (the diameter stays the network's: tracker.detection.edge_refine)
        boxes = np.empty((len(d), 4))
        boxes[:, :2] = uv + 0.5 - 0.5 * d[:, None]
        boxes[:, 2] = boxes[:, 3] = d
        return Detections(uv, scores, boxes, np.rint(areas).astype(np.int64), window is not None)

    def _refined(self, image, uv, d) -> np.ndarray:
        """The learned candidates' centres, each replaced by the filter's blob centroid where the filter sees the ball."""
        h, w = image.shape[:2]
        out = uv.copy()
        for i, ((u, v), dd) in enumerate(zip(uv, d)):
            r = 0.5 * dd + 3.0
            x0, y0 = max(int(math.floor(u - r)), 0), max(int(math.floor(v - r)), 0)
            x1, y1 = min(int(math.ceil(u + r)) + 1, w), min(int(math.ceil(v + r)) + 1, h)
            if x1 - x0 < 2 or y1 - y0 < 2:
                continue
            lg = self.model.logits_window_trusted(image, x0, y0, x1, y1)
            blobs = find_blobs(lg, self._th_logit, self._tl_logit, max_blobs=1, max_seeds=2, backend=self.options.backend, overwrite=True)
            if len(blobs.areas_px) == 0:
                continue
            c = blobs.centers_px[0] + (x0, y0)
            if math.hypot(c[0] - u, c[1] - v) <= REFINE_MAX_SHIFT * dd and blobs.areas_px[0] >= REFINE_MIN_AREA * math.pi / 4 * dd * dd:
                out[i] = c
        return out

    def _verified(self, image, det: Detections) -> Detections:
        """The verifier's choice among the candidates (unchanged without a verifier)."""
        if self.verifier is None or len(det) == 0:
            return det
        prob, uv = self.verifier.verify(image, det.uv_px, det.boxes_xywh[:, 2:].max(axis=1))
        keep = np.flatnonzero(prob >= self.verifier.threshold)
        keep = keep[np.argsort(-prob[keep], kind="stable")][: self.options.max_candidates]
        return Detections(uv[keep], prob[keep], det.boxes_xywh[keep], det.areas_px[keep], det.used_roi)


def _box_area(boxes: np.ndarray) -> int:
    return int(((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])).sum())


def _float32_at_or_below(x: float) -> np.float32:
    """The largest float32 not above ``x``: a float32 logit at or above it includes every one above ``x``."""
    f = np.float32(x)
    return f if float(f) <= x else np.nextafter(f, np.float32(-np.inf))


#: the coarse pass's threshold is this far below logit(T_l): its approximation may fall short of the exact logits
#: (the least margin seen at the full search's candidates on the simulated lab's renders: 0.58; docs/detector.md)
COARSE_MARGIN_LOGIT = 1.0
#: when the blocks would cover more than this share of the frame, the whole frame is computed (as fast, and exact)
COARSE_MAX_SHARE = 0.5


class _Work:
    """One thread's reusable buffers: the full-frame logits (:class:`LogitWorkspace`) and the flood
    fill's queue (grown to the largest image searched). The detections never refer to them."""

    def __init__(self):
        self.logits = LogitWorkspace()
        self._queues = (np.empty(0, np.int64), np.empty(0, np.int64))

    def queues(self, n_px: int) -> tuple[np.ndarray, np.ndarray]:
        if len(self._queues[0]) < n_px:
            self._queues = (np.empty(n_px, np.int64), np.empty(n_px, np.int64))
        return self._queues


def _to_detections(blobs, x0: int, y0: int, used_roi: bool) -> Detections:
    """The blobs of a window whose top-left pixel is (x0, y0), in the image's pixels; boxes ``[x, y, w, h]``."""
    uv = blobs.centers_px + np.array([x0, y0], dtype=np.float64)
    boxes = blobs.boxes.astype(np.float64)  # x_min, y_min, x_max, y_max (integers: exact in float64)
    boxes[:, 2:] -= boxes[:, :2] - 1
    boxes[:, :2] += (x0, y0)
    return Detections(uv, sigmoid(blobs.peak_logits), boxes, blobs.areas_px, used_roi)

