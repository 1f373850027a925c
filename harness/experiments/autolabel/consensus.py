"""Which frame sets the cameras agree on, and what that makes each camera's label.

Per frame set, the ``rt2`` tracker runs with permissive detection (full frame, no window, up to
``AutoOptions.max_candidates`` candidates per camera, thresholds ``t_high`` / ``t_low`` below a model's
usual ones, and a blob area range from the rig's ball sizes, not the model's: a model trained on
another camera's ball sizes would refuse the balls of this one) and forgets the motion first (every
frame set is judged on its own images). Permissive detection finds more wrong blobs too; the consensus
is what rejects them. A frame set is **kept** when:

1. the estimator's consistent set has at least ``min_support`` cameras (3: two cameras always "agree"
   on some point), each of them within ``max_reprojection_px`` of the position, and the tracker's 3D
   size test passed (status OK: the blobs are as wide as a ball at that depth, ``max_size_ratio``);
2. the flight is consistent (``flight_window`` > 0): the positions of the neighbouring kept-so-far frame
   sets (up to ``flight_window`` on each side, at least 2 of them, none farther in time than ``flight_window + 0.5``
   median frame intervals: a pause starts a new flight) predict this one within
   ``max_flight_residual_m`` (a line through 2, a parabola through 3 or more, fitted in time); an
   isolated agreement of three cameras on a wrong object does not move like a ball.

**The second look** (``second_look``, on with the flight test): a frame set without an agreement whose neighbours
(up to ``flight_window`` on each side, at least 2, pass 1's agreements and earlier second looks) give a flight
is searched again in windows around the flight's position at its time, each camera's detector at
``second_look_scale`` x its thresholds (:meth:`tracker.Tracker.process_with_info` ``prior_m``; no full-frame search).
The same rule 1 decides, and rule 2 then judges every agreement alike. A ball the full-frame search ranked below
the ``max_candidates`` best blobs, or scored just below the threshold, is found where the flight says it is; three
cameras must still agree on it and the flight must still predict it. Streaming: the frame sets wait for their
``flight_window`` successors (their images kept that long, no longer).

**Re-centring** (``recentre``): the consensus's position comes from the candidates' centres, each off the ball's
centre by a fraction of a pixel or more (a blob's flood fill, a network's heat), and every label inherits the error. So each
camera's image is measured again where the position projects, by the model's own centring (a model whose filter
sees the ball: the centroid of the ball's silhouette, the pixels of a disk of ``d / 2 + 3`` px where the filter's
probability reaches ``RECENTRE_SILHOUETTE`` (30 %) of its peak there, each pixel counted once, where the peak reaches
``t_low``; a learned stage the filter does not see, the white ball: the centroid of the grey image's silhouette,
:mod:`~harness.experiments.autolabel.silhouette`, where it is clear, else the edge fit of
:mod:`tracker.detection.edge_refine`; a learned stage with a filter of its ball's colour that does not refine it, the
real-camera orange model: the filter's silhouette where the filter sees the ball, else the edge fit), the ball
triangulated from those centres, twice. The silhouette, not the probability-weighted centroid: a lit ball is more probable on its lit side, and the weighted centroid moved towards
the light by up to a pixel on the caliscope frames' 35-100 px balls, differently in each camera. Kept only when at
least ``min_support`` cameras re-centre within ``max(2 px, d / 4)`` of the projection, the new position reprojects
within ``max_reprojection_px`` of them and lies within a ball radius of the consensus's; otherwise the consensus's
position stays (README, "Labels for free": on the caliscope frames with the drawn orange ball, labels within 1.5 px
of the truth 74 % from the first look alone, 90.1 % re-centred on the weighted centroid, 98.8 % on the silhouette).
A consistent set of ``min_support`` or more cameras that fails rule 1's ``max_reprojection_px`` (one camera's centre
off the ball's by more than that, with no spare camera to trim) is re-centred too: when re-centring holds (the
conditions above: at least ``min_support`` re-measured centres that agree within ``max_reprojection_px``), rule 1 is
passed on those centres and the frame set's labels come from them (counted as ``recentred_agreement``); a learned
stage's edge-fitted centres are looser than a filter's, and the real-camera orange model lost 44 of 400 caliscope
frame sets to the 3 px test before.

**The flight's smoothing** (``smooth_window``): what is left of each camera's centring error moves the position off
the flight, differently in each frame set. A ball in flight follows a smooth path, so each kept position is replaced
by the value at its time of a parabola fitted in time (per coordinate) to the kept positions of up to
``smooth_window`` frame sets on each side (within ``flight_span_s``: one flight), fitted once more without positions
farther than ``max(3 mm, 3 x the median)`` off the first fit; the window must hold at least 5 positions, the fit's RMS
residual stay within ``smooth_max_rms_m`` (a bounce inside the window does not fit a parabola: the position stays)
and the new position lie within a ball radius of the old. Measured on the caliscope frames with the rally's real white
balls (`rt2 eval autolabel --scene caliscope --ball white --crop-frames 58: --frames 400 --seed 0`), labels within
1.5 px of the truth: 92.6 % re-centred alone (``smooth_window=0``), 97.4 % smoothed over 5 frame sets on each side,
98.1 % over 8 (the drawn orange ball 98.8 -> 99.5 %; the simulated lab 100 % either way, p95 0.45 -> 0.42 px).

The label of each camera of a kept frame set is the position reprojected into it (distorted pixels),
its box a square of the ball's projected diameter (``2 r f / z``) about it; a camera where it falls
within half a diameter of the border gets none. Cameras whose detector missed the ball get a label too:
these are the hard positives. The candidates a camera reported farther than ``negative_distance``
diameters from the label are **hard negatives** (boxes of their blob's area). Every label carries the
frame set's support, its RMS reprojection error over the consistent set, the camera's own reprojection
error (NaN where it had no candidate) and a confidence ``support / cameras that see it x exp(-rms / 2 px)``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from harness.common.options import named_by_options

__all__ = ["AutoOptions", "FrameSetLabels", "auto_label", "centring", "flight_consistent", "flight_prediction", "flight_span_s", "labels_of", "max_ball_area_px", "moved", "recentred", "smoothed", "trimmed"]


_INTEGER_OPTIONS = frozenset({"min_support", "flight_window", "max_candidates", "smooth_window"})  #: of AutoOptions
#: the options of ``rt2 label --auto`` (and ``rt2 eval autolabel``), by the :class:`AutoOptions` field each fills
FLAGS = {"min_support": "--min-support", "max_reprojection_px": "--max-reprojection", "flight_window": "--flight-window",
         "max_flight_residual_m": "--max-flight-residual", "max_size_ratio": "--max-size-ratio", "trim_px": "--trim",
         "smooth_window": "--smooth-window", "second_look": "--second-look", "recentre": "--recentre"}


@dataclass(frozen=True)
class AutoOptions:
    """How ``rt2 label --auto`` decides (module docstring).

    min_support : cameras that must agree (>= 3)
    max_reprojection_px : every camera of the consistent set within this of the position, px
    flight_window : neighbouring frame sets on each side for the flight test (0 = off: frame sets that are not a sequence)
    max_flight_residual_m : the flight test's tolerance, metres
    max_candidates : candidates per camera (permissive detection; the consensus chooses)
    t_high, t_low : the detector's thresholds (probabilities; permissive)
    negative_distance : a candidate farther than this many ball diameters from the label is a hard negative
    ball_radius_m : the ball's radius, metres (the box and the size test)
    trim_px : an agreeing camera farther than this from the position is dropped and the ball triangulated again from the
        others, while more than ``min_support`` remain (:func:`trimmed`)
    recentre : measure each camera's ball again at the position's pixels and triangulate from those (module docstring)
    second_look : search again where the flight of the neighbouring agreements puts the ball (module docstring)
    second_look_scale : the second look's detector thresholds as a share of the first look's (``t_high``, ``t_low``, a
        learned stage's tracking threshold)
    smooth_window : kept frame sets on each side whose flight smooths each kept position (0 = off; :func:`smoothed`)
    smooth_max_rms_m : the smoothing's flight must fit its positions within this RMS, metres (a bounce or a wrong
        position in the window: the position stays)
    max_size_ratio : the tracker's 3D size test (``TrackerOptions.max_size_ratio``) for the consensus: 1.6, wider
        than the tracker's 1.3, because a learned stage's diameters are looser than the filter's blob widths (on the
        caliscope frames with the rally's real white balls, 1.3 kept 49.5 % of the frame sets, 1.6 and 2.0 65.1 %, with
        one wrong label of 953; the drawn orange ball's figures are the same at 1.3 and 1.6) and the flight test
        guards the auto labels besides
    """

    min_support: int = 3
    max_reprojection_px: float = 3.0
    flight_window: int = 3
    max_flight_residual_m: float = 0.03
    max_candidates: int = 8
    t_high: float = 0.5
    t_low: float = 0.25
    negative_distance: float = 2.0
    ball_radius_m: float = 0.02
    max_size_ratio: float = 1.6
    trim_px: float = 2.0
    recentre: bool = True
    second_look: bool = True
    second_look_scale: float = 0.5
    smooth_window: int = 8
    smooth_max_rms_m: float = 0.01

    @classmethod
    def from_flags(cls, **given) -> "AutoOptions":
        """The options of ``rt2 label --auto`` (and the study that measures it), ``given`` by field; a bad value's
        error names the command's option (``FLAGS``), not the field it fills."""
        with named_by_options("AutoOptions", FLAGS):
            return cls(**given)

    def __post_init__(self):
        checks = [("min_support", lambda v: v >= 3, "an integer >= 3 (two cameras always meet somewhere)"),
                  ("max_reprojection_px", lambda v: 0 < v <= 50, "in (0, 50] px"),
                  ("flight_window", lambda v: 0 <= v <= 50, "an integer in [0, 50]"),
                  ("max_flight_residual_m", lambda v: 0 < v <= 1, "in (0, 1] m"),
                  ("max_candidates", lambda v: 1 <= v <= 32, "an integer in [1, 32]"),
                  ("t_high", lambda v: 0 < v < 1, "a probability in (0, 1)"),
                  ("t_low", lambda v: 0 < v < self.t_high, "a probability in (0, t_high)"),
                  ("negative_distance", lambda v: 0 < v <= 100, "in (0, 100] diameters"),
                  ("ball_radius_m", lambda v: 0 < v < 1, "in (0, 1) m"),
                  ("max_size_ratio", lambda v: 1 <= v <= 10, "in [1, 10]"),
                  ("trim_px", lambda v: 0 < v <= 50, "in (0, 50] px"),
                  ("second_look_scale", lambda v: 0 < v <= 1, "in (0, 1]"),
                  ("smooth_window", lambda v: 0 <= v <= 50, "an integer in [0, 50]"),
                  ("smooth_max_rms_m", lambda v: 0 < v <= 1, "in (0, 1] m")]
        for name in ("second_look", "recentre"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"AutoOptions.{name} must be True or False, got {getattr(self, name)!r}")
        for name, ok, what in checks:  # t_high first: t_low's range is read from it
            value = getattr(self, name)
            kind = int if name in _INTEGER_OPTIONS else (int, float)
            if isinstance(value, bool) or not isinstance(value, kind) or not math.isfinite(value) or not ok(value):
                raise ValueError(f"AutoOptions.{name} must be {what}, got {value!r}")


@dataclass(frozen=True)
class FrameSetLabels:
    """A kept frame set: the ball and each camera's label (arrays per rig camera).

    index, frame_id, t_s : as the recording's :class:`~harness.experiments.autolabel.framesets.RecordedSet`
    position_m : (3,) world frame; support : cameras that agree; rms_reprojection_px : over them
    inliers : (n_cams,) bool; reprojection_px : (n_cams,) each camera's nearest candidate's error, NaN without one
    center_px : (n_cams, 2) the label's centre, rt2 pixels, NaN where the camera gets no label
    diameter_px : (n_cams,) the ball's projected diameter; confidence : in [0, 1]
    negatives : per camera the (k, 4) COCO boxes of its hard negatives
    """

    index: int
    frame_id: int
    t_s: float
    position_m: np.ndarray
    support: int
    rms_reprojection_px: float
    inliers: np.ndarray
    reprojection_px: np.ndarray
    center_px: np.ndarray
    diameter_px: np.ndarray
    confidence: float
    negatives: tuple

    def box_xywh(self, j: int) -> np.ndarray:
        """Camera ``j``'s label as a COCO box ``[x, y, w, h]`` (the pixel (0, 0) covers [0, 1] x [0, 1])."""
        d = self.diameter_px[j]
        u, v = self.center_px[j]
        return np.array([u + 0.5 - d / 2, v + 0.5 - d / 2, d, d])


def _projected(cam, position_m: np.ndarray, ball_radius_m: float) -> tuple:
    """The ball at ``position_m`` in ``cam``: ``(uv (2,), diameter px (NaN behind or too near), whether it gets a label:
    the ball inside the image by half a diameter)``."""
    z = float(cam.depth(position_m[None, :])[0])
    uv = cam.project(position_m[None, :])[0]
    d = 2.0 * ball_radius_m * float(cam.K[0, 0]) / z if z > 2 * ball_radius_m else math.nan
    return uv, d, math.isfinite(d) and bool(cam.in_image(uv[None, :], d / 2 + 1.0)[0])


def labels_of(rig, index, frame_id, t_s, position_m, estimate, uv_candidates_px, areas_px, options: AutoOptions):
    """The labels of one agreed frame set (module docstring), or None when no camera can hold one.

    estimate : the tracker's :class:`~tracker.robust.EstimateInfo`; uv_candidates_px : (n_cams, k, 2), areas_px : (n_cams, k)
    """
    n = len(rig)
    P = np.asarray(position_m, float)
    center = np.full((n, 2), np.nan)
    diam = np.full(n, np.nan)
    negatives = []
    for j, cam in enumerate(rig):
        uv, d, inside = _projected(cam, P, options.ball_radius_m)
        if inside:
            center[j], diam[j] = uv, d
        boxes = []
        if math.isfinite(d):
            uvc = np.asarray(uv_candidates_px[j], float).reshape(-1, 2)
            area = np.asarray(areas_px[j], float).reshape(-1) if areas_px is not None else np.full(len(uvc), d * d)
            w, h = cam.image_size
            for c, a in zip(uvc, area):
                if np.isfinite(c).all() and np.linalg.norm(c - uv) > options.negative_distance * d:
                    side = max(2.0, 2.0 * math.sqrt(max(a, 1.0) / math.pi))
                    x0, y0 = max(0.0, c[0] + 0.5 - side / 2), max(0.0, c[1] + 0.5 - side / 2)
                    x1, y1 = min(float(w), c[0] + 0.5 + side / 2), min(float(h), c[1] + 0.5 + side / 2)
                    if x1 - x0 >= 1 and y1 - y0 >= 1:
                        boxes.append([x0, y0, x1 - x0, y1 - y0])
        negatives.append(np.array(boxes, float).reshape(-1, 4))
    seen = np.isfinite(diam)
    if not seen.any():
        return None
    inl = np.asarray(estimate.inliers, bool)
    err = np.asarray(estimate.reproj_error_px, float)
    rms = float(np.sqrt(np.mean(err[inl] ** 2)))
    confidence = float(min(1.0, estimate.support / max(int(seen.sum()), estimate.support)) * math.exp(-rms / 2.0))
    return FrameSetLabels(index, frame_id, t_s, P, int(estimate.support), rms, inl.copy(), err.copy(), center, diam, confidence,
                          tuple(negatives))


def trimmed(position_m, uv_px, estimate, rig, options: AutoOptions):
    """``(position, estimate)`` with the consistent set's worst camera dropped and the ball triangulated again from the
    others, while that camera is farther than ``trim_px`` from the position and more than ``min_support`` cameras
    remain (rule 1's camera trimming): one off-centre blob inside the consensus's tolerance moves the position, and
    with it every camera's label. ``uv_px`` : (n_cams, 2) the chosen candidates (NaN elsewhere)."""
    from tracker.triangulation import reprojection_errors, triangulate

    X = np.asarray(position_m, float)
    inl = np.asarray(estimate.inliers, bool).copy()
    err = np.asarray(estimate.reproj_error_px, float)
    changed = False
    while inl.sum() > options.min_support:
        worst = int(np.argmax(np.where(inl, err, -np.inf)))
        if not err[worst] > options.trim_px:
            break
        inl[worst] = False
        uv = np.where(inl[:, None], np.asarray(uv_px, float), np.nan)
        X2, _ = triangulate(rig, uv)
        if not np.isfinite(X2).all():
            inl[worst] = True
            break
        X, changed = X2, True
        err = reprojection_errors(X, np.asarray(uv_px, float), rig)  # every camera's, the dropped ones too
    if not changed:
        return X, estimate
    return X, replace(estimate, inliers=inl, support=int(inl.sum()), reproj_error_px=err)


#: re-centring: the disk of the filter's centroid, px beyond the ball's radius; the rounds; a camera's centre this far
#: from the projection (px, or a quarter diameter) leaves it out
RECENTRE_MARGIN_PX, RECENTRE_ROUNDS, RECENTRE_MAX_SHIFT_PX = 3.0, 2, 2.0
RECENTRE_SILHOUETTE = 0.3  #: the ball's silhouette: where the filter's probability reaches this share of its peak


def centring(model, min_peak: float = AutoOptions.t_low):
    """``centre(image, uv (2,), diameter) -> (2,) or None``: the model's own way to find a ball's centre near ``uv``
    (module docstring, re-centring); the centroid of the filter's silhouette only where its probability reaches
    ``min_peak`` in the disk (None: no ball there)."""

    def centroid(image, uv, d):
        h, w = image.shape[:2]
        r = 0.5 * d + RECENTRE_MARGIN_PX
        x0, y0 = max(int(math.floor(uv[0] - r)), 0), max(int(math.floor(uv[1] - r)), 0)
        x1, y1 = min(int(math.ceil(uv[0] + r)) + 1, w), min(int(math.ceil(uv[1] + r)) + 1, h)
        if x1 - x0 < 2 or y1 - y0 < 2:
            return None
        p = model.probability(image, (x0, y0, x1, y1)).astype(np.float64)
        yy, xx = np.mgrid[y0:y1, x0:x1]
        p *= (xx - uv[0]) ** 2 + (yy - uv[1]) ** 2 <= r * r
        peak = p.max()
        if not peak >= min_peak:
            return None
        inside = p >= RECENTRE_SILHOUETTE * peak  # the silhouette, each pixel once: the lit side weighs no more
        return np.array([xx[inside].mean(), yy[inside].mean()])

    learned = model.learned
    if learned is None or learned.filter_refines:
        return centroid
    from harness.experiments.autolabel.silhouette import silhouette_centre
    from tracker.detection.edge_refine import chroma_for, refine_edges

    chroma = chroma_for(model.ball_colour)  # a saturated ball's edge is its chroma's, as the detector's

    def edge(image, uv, d):
        c, _, ok = refine_edges(image, np.asarray(uv, float)[None], np.array([d], float), chroma)
        return c[0] if ok[0] else None

    if model.ball_colour != "white":  # a filter of the ball's colour (the real-camera orange model): its silhouette

        def filter_or_edge(image, uv, d):  # where it sees the ball, else the ball's edge
            c = centroid(image, uv, d)
            return edge(image, uv, d) if c is None else c

        return filter_or_edge

    def silhouette_or_edge(image, uv, d):  # the white ball: its grey silhouette where clear, else its edge
        c = silhouette_centre(image, uv, d)
        return edge(image, uv, d) if c is None else c

    return silhouette_or_edge


def recentred_centres(images, position_m, rig, centre, options: AutoOptions):
    """``(position, uv)``: the ball triangulated from each camera's re-measured centre (module docstring,
    re-centring) and those centres ((n_cams, 2), NaN: a camera left out), or ``(position_m, None)`` when that does
    not hold. images : the frame set's, rig camera order; centre : :func:`centring`'s."""
    from tracker.triangulation import reprojection_errors, triangulate

    X0 = X = np.asarray(position_m, float)
    uv = None
    for _ in range(RECENTRE_ROUNDS):
        uv = np.full((len(rig), 2), np.nan)
        for j, cam in enumerate(rig):
            z = float(cam.depth(X[None, :])[0])
            if images[j] is None or not z > 2 * options.ball_radius_m:
                continue
            p = cam.project(X[None, :])[0]
            d = 2.0 * options.ball_radius_m * float(cam.K[0, 0]) / z
            if not bool(cam.in_image(p[None, :], d / 2 + 1.0)[0]):
                continue
            c = centre(images[j], p, d)
            if c is not None and np.all(np.isfinite(c)) and np.linalg.norm(c - p) <= max(RECENTRE_MAX_SHIFT_PX, d / 4):
                uv[j] = c
        if np.isfinite(uv[:, 0]).sum() < options.min_support:
            return X0, None
        X2, _ = triangulate(rig, uv)
        if not np.isfinite(X2).all() or np.nanmax(reprojection_errors(X2, uv, rig)) > options.max_reprojection_px:
            return X0, None
        X = X2
    return (X, uv) if np.linalg.norm(X - X0) <= options.ball_radius_m else (X0, None)


def recentred(images, position_m, rig, centre, options: AutoOptions) -> np.ndarray:
    """The position of :func:`recentred_centres` alone (``position_m`` when re-centring does not hold)."""
    return recentred_centres(images, position_m, rig, centre, options)[0]


def max_ball_area_px(rig, options: AutoOptions) -> int:
    """The largest blob area a ball can have in any camera of ``rig`` (its workspace's nearest point, x 1.5 in diameter
    for blur), px; without a workspace, a 1 m distance's."""
    from tracker.ball_size import ball_diameter_range_px

    if rig.workspace_m is not None:
        d = float(np.nanmax(ball_diameter_range_px(rig, ball_radius_m=options.ball_radius_m)[:, 1]))
    else:
        d = max(2.0 * options.ball_radius_m * float(cam.K[0, 0]) for cam in rig)
    return int(math.ceil(math.pi / 4 * (1.5 * d) ** 2))


def _positions(found) -> np.ndarray:
    """(n, 3) the agreed positions of ``found`` (FrameSetLabels or None), NaN rows where none."""
    return np.array([f.position_m if f is not None else [np.nan] * 3 for f in found], float).reshape(-1, 3)


def flight_span_s(t_s, window: int) -> float:
    """How far in time a neighbour of the flight test may lie: ``window + 0.5`` median intervals between consecutive
    frame sets (a pause in the recording, a new flight, is no neighbour); infinite without two increasing times."""
    d = np.diff(np.asarray(t_s, float))
    d = d[np.isfinite(d) & (d > 0)]
    return (window + 0.5) * float(np.median(d)) if len(d) else math.inf


def flight_prediction(t_s, positions_m: np.ndarray, have, i: int, window: int, span_s: float = math.inf) -> np.ndarray | None:
    """(3,) where the flight of frame sets ``i - window .. i + window`` (not ``i``) with ``have[j]`` and a time within
    ``span_s`` of frame set ``i``'s (:func:`flight_span_s`) puts the ball at ``t_s[i]``: a line through 2 of them, a
    parabola through 3 or more, fitted in time; None with fewer than 2 or all at one time."""
    n = len(t_s)
    nb = [j for j in range(max(0, i - window), min(n, i + window + 1))
          if j != i and have[j] and abs(t_s[j] - t_s[i]) <= span_s]
    if len(nb) < 2:
        return None
    t = np.asarray(t_s, float)[nb] - t_s[i]
    if np.ptp(t) <= 0:
        return None
    coef, *_ = np.linalg.lstsq(np.vander(t, 2 if len(nb) == 2 else 3), np.asarray(positions_m, float)[nb], rcond=None)
    return coef[-1]  # the fit at t = 0: frame set i's time


def flight_consistent(t_s: np.ndarray, positions_m: np.ndarray, kept: np.ndarray, options: AutoOptions) -> np.ndarray:
    """(n,) bool: kept frame sets whose neighbours' flight predicts them (module docstring, rule 2).

    t_s : (n,) times; positions_m : (n, 3), NaN where no agreement; kept : (n,) bool, the frame sets passing rule 1
    """
    if options.flight_window == 0:
        return kept.copy()
    out = np.zeros(len(t_s), bool)
    span = flight_span_s(t_s, int(options.flight_window))
    for i in np.flatnonzero(kept):
        predicted = flight_prediction(t_s, positions_m, kept, int(i), int(options.flight_window), span)
        out[i] = predicted is not None and np.linalg.norm(predicted - positions_m[i]) <= options.max_flight_residual_m
    return out


#: the smoothing: positions needed in a window; a position off the window's first fit by more than this (m, or
#: SMOOTH_TRIM x the median residual) is left out of the second; the share of the window the second must keep
SMOOTH_MIN_POSITIONS, SMOOTH_TRIM_M, SMOOTH_TRIM, SMOOTH_MIN_SHARE = 5, 0.003, 3.0, 0.8


def smoothed(kept: list, rig, options: AutoOptions) -> list:
    """``kept`` (FrameSetLabels in time order) with each position replaced by its flight's (module docstring, the
    flight's smoothing) and its labels projected again; a frame set whose window fails the test keeps its own."""
    w = int(options.smooth_window)
    if w == 0 or len(kept) < SMOOTH_MIN_POSITIONS:
        return list(kept)
    t = np.array([f.t_s for f in kept], float)
    P = _positions(kept)
    span = flight_span_s(t, w)
    index = np.array([f.index for f in kept])
    out = []
    for i, f in enumerate(kept):
        nb = np.flatnonzero((np.abs(index - f.index) <= w) & (np.abs(t - t[i]) <= span))
        X = _flight_fit(t[nb] - t[i], P[nb], options.smooth_max_rms_m)
        out.append(f if X is None or np.linalg.norm(X - P[i]) > options.ball_radius_m else moved(f, X, rig, options))
    return out


def _flight_fit(dt: np.ndarray, P: np.ndarray, max_rms_m: float) -> np.ndarray | None:
    """(3,) a parabola's value at ``dt = 0``, fitted in time to ``P`` (n, 3) at ``dt`` (n,) s, once more without the
    positions far off the first fit; None with fewer than ``SMOOTH_MIN_POSITIONS``, where fewer than
    ``SMOOTH_MIN_SHARE`` of the window fit, or where the fit's RMS residual exceeds ``max_rms_m`` (a bounce in the
    window: the position stays its own)."""
    use = np.ones(len(dt), bool)
    for _ in range(2):
        if use.sum() < SMOOTH_MIN_POSITIONS or np.ptp(dt[use]) <= 0:
            return None
        V = np.vander(dt, 3)
        coef, *_ = np.linalg.lstsq(V[use], P[use], rcond=None)
        res = np.linalg.norm(P - V @ coef, axis=1)
        use = res <= max(SMOOTH_TRIM_M, SMOOTH_TRIM * float(np.median(res[use])))
    if use.sum() < max(SMOOTH_MIN_POSITIONS, SMOOTH_MIN_SHARE * len(dt)) \
            or math.sqrt(float(np.mean(res[use] ** 2))) > max_rms_m:
        return None
    return coef[-1]


def moved(labels: FrameSetLabels, position_m, rig, options: AutoOptions) -> FrameSetLabels:
    """``labels`` with the ball at ``position_m``: every camera's label projected again (as :func:`labels_of`: none
    within half a diameter of the border); its support, errors, confidence and hard negatives stay."""
    P = np.asarray(position_m, float)
    center = np.full_like(labels.center_px, np.nan)
    diam = np.full_like(labels.diameter_px, np.nan)
    for j, cam in enumerate(rig):
        uv, d, inside = _projected(cam, P, options.ball_radius_m)
        if inside:
            center[j], diam[j] = uv, d
    return replace(labels, position_m=P, center_px=center, diameter_px=diam)


def auto_label(framesets, rig, model, options: AutoOptions = AutoOptions(), *, progress=None) -> tuple[list, dict]:
    """Run the consensus over ``framesets`` (an iterable of RecordedSet, rig camera order); returns (kept labels, counts).

    counts : ``frame_sets`` read, ``agreed`` (rule 1, both looks), ``second_look`` (of them by the second look),
    ``recentred_agreement`` (first-look frame sets that passed rule 1 on their re-centred centres), ``kept`` (rule 2 too),
    ``smoothed`` (kept positions the flight's smoothing moved), ``low_support`` / ``reprojection`` (why rule 1
    failed where the tracker had a position), ``size_rejected`` (frame sets where the size test dropped a position first)
    """
    from tracker import RobustOptions, Status
    from tracker.detection import DetectorOptions
    from tracker.pipeline import Tracker
    from tracker.triangulation import reprojection_errors

    from tracker.observation import FrameSet

    detector_options = DetectorOptions(method="ours", max_candidates=options.max_candidates, t_high=options.t_high, t_low=options.t_low,
                                       min_area_px=4, max_area_px=max_ball_area_px(rig, options))
    common = dict(model=model, workers=1, hypotheses=None, handover_max_age_s=None, ball_radius_m=options.ball_radius_m,
                  max_size_ratio=options.max_size_ratio, estimator_options=RobustOptions(max_candidates_per_camera=options.max_candidates))
    tracker = Tracker(rig, "rt2", roi=False, detector_options=detector_options, **common)
    second = None
    if options.second_look and options.flight_window > 0:
        scale = options.second_look_scale
        learned = tracker.engine.detector.options.learned_threshold  # the first look's (the stage's tracking threshold)
        second = Tracker(rig, "rt2", roi=True, retry_full_frame=False, **common,
                         detector_options=replace(detector_options, t_high=scale * options.t_high, t_low=scale * options.t_low,
                                                  learned_threshold=None if learned is None else scale * learned))
    centre = centring(tracker.engine.detector.model, options.t_low) if options.recentre else None
    found, times = [], []
    counts = {"frame_sets": 0, "agreed": 0, "second_look": 0, "size_rejected": 0, "low_support": 0, "reprojection": 0,
              "recentred_agreement": 0}
    waiting: deque = deque()  # (position in found, RecordedSet) without agreement, until their successors are in

    def agreement(trk, rs, prior=None, count=True):
        trk.reset()
        before = trk.stats.size_rejections
        obs, info = trk.process_with_info(FrameSet(rs.t_s, list(rs.images)), prior_m=prior)
        est = info.estimate
        if count:
            counts["size_rejected"] += int(trk.stats.size_rejections > before)  # a position redone without the wide blobs
        if obs.has_position and obs.status == Status.OK and est is not None and est.support >= options.min_support:
            X, est = trimmed(obs.position_m, obs.uv_px, est, rig, options)
            inl = np.asarray(est.inliers, bool)
            if np.all(np.asarray(est.reproj_error_px)[inl] <= options.max_reprojection_px):
                if centre is not None:
                    X = recentred(rs.images, X, rig, centre, options)
                return labels_of(rig, rs.index, rs.frame_id, rs.t_s, X, est, info.uv_candidates_px, info.areas_px, options)
            if centre is not None:  # a camera's centre off by more than the tolerance: each camera measured again
                X2, uv2 = recentred_centres(rs.images, X, rig, centre, options)
                if uv2 is not None:  # at least min_support of them agree within it there (rule 1 on the new centres)
                    use = np.isfinite(uv2[:, 0])
                    est2 = replace(est, inliers=use, support=int(use.sum()), reproj_error_px=reprojection_errors(X2, uv2, rig))
                    if count:
                        counts["recentred_agreement"] += 1
                    return labels_of(rig, rs.index, rs.frame_id, rs.t_s, X2, est2, info.uv_candidates_px, info.areas_px, options)
            if count:
                counts["reprojection"] += 1
        elif obs.has_position and count:
            counts["low_support"] += 1
        return None

    def look_again(k, rs):
        w = int(options.flight_window)
        lo = max(0, k - w)
        near = found[lo:k + w + 1]  # the window the flight is fitted in, not the whole recording
        have = [f is not None for f in near]
        prior = flight_prediction(times[lo:k + w + 1], _positions(near), have, k - lo, w, flight_span_s(times, w))
        if prior is None:
            return
        labels = agreement(second, rs, prior, count=False)
        if labels is not None:
            found[k] = labels
            counts["second_look"] += 1

    try:
        for rs in framesets:
            labels = agreement(tracker, rs)
            counts["frame_sets"] += 1
            times.append(rs.t_s)
            found.append(labels)
            if second is not None:
                if labels is None:
                    waiting.append((len(found) - 1, rs))
                while waiting and waiting[0][0] <= len(found) - 1 - options.flight_window:
                    look_again(*waiting.popleft())
            if progress is not None:
                progress(counts["frame_sets"])
        while waiting:  # the last frame sets: no more successors to wait for
            look_again(*waiting.popleft())
    finally:
        tracker.close()
        if second is not None:
            second.close()
    agreed = np.array([f is not None for f in found], bool)
    pos = _positions(found)
    keep = flight_consistent(np.array(times, float), pos, agreed, options)
    counts["agreed"] = int(agreed.sum())
    counts["kept"] = int(keep.sum())
    kept = [f for f, k in zip(found, keep) if k]
    out = smoothed(kept, rig, options)
    counts["smoothed"] = sum(a is not b for a, b in zip(out, kept))
    return out, counts
