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
   sets (up to ``flight_window`` on each side, at least 2 of them) predict this one within
   ``max_flight_residual_m`` (a line through 2, a parabola through 3 or more, fitted in time); an
   isolated agreement of three cameras on a wrong object does not move like a ball.

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
from dataclasses import dataclass

import numpy as np

__all__ = ["AutoOptions", "FrameSetLabels", "auto_label", "flight_consistent", "labels_of", "max_ball_area_px"]


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

    def __post_init__(self):
        checks = [("min_support", self.min_support >= 3, "an integer >= 3 (two cameras always meet somewhere)"),
                  ("max_reprojection_px", 0 < self.max_reprojection_px <= 50, "in (0, 50] px"),
                  ("flight_window", 0 <= self.flight_window <= 50, "an integer in [0, 50]"),
                  ("max_flight_residual_m", 0 < self.max_flight_residual_m <= 1, "in (0, 1] m"),
                  ("max_candidates", 1 <= self.max_candidates <= 32, "an integer in [1, 32]"),
                  ("t_high", 0 < self.t_high < 1, "a probability in (0, 1)"),
                  ("t_low", 0 < self.t_low < self.t_high, "a probability in (0, t_high)"),
                  ("negative_distance", 0 < self.negative_distance <= 100, "in (0, 100] diameters"),
                  ("ball_radius_m", 0 < self.ball_radius_m < 1, "in (0, 1) m"),
                  ("max_size_ratio", 1 <= self.max_size_ratio <= 10, "in [1, 10]")]
        for name, ok, what in checks:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not ok:
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
        z = float(cam.depth(P[None, :])[0])
        uv = cam.project(P[None, :])[0]
        d = 2.0 * options.ball_radius_m * float(cam.K[0, 0]) / z if z > 2 * options.ball_radius_m else math.nan
        if math.isfinite(d) and bool(cam.in_image(uv[None, :], d / 2 + 1.0)[0]):
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


def max_ball_area_px(rig, options: AutoOptions) -> int:
    """The largest blob area a ball can have in any camera of ``rig`` (its workspace's nearest point, x 1.5 in diameter
    for blur), px; without a workspace, a 1 m distance's."""
    from tracker.ball_size import ball_diameter_range_px

    if rig.workspace_m is not None:
        d = float(np.nanmax(ball_diameter_range_px(rig, ball_radius_m=options.ball_radius_m)[:, 1]))
    else:
        d = max(2.0 * options.ball_radius_m * float(cam.K[0, 0]) for cam in rig)
    return int(math.ceil(math.pi / 4 * (1.5 * d) ** 2))


def flight_consistent(t_s: np.ndarray, positions_m: np.ndarray, kept: np.ndarray, options: AutoOptions) -> np.ndarray:
    """(n,) bool: kept frame sets whose neighbours' flight predicts them (module docstring, rule 2).

    t_s : (n,) times; positions_m : (n, 3), NaN where no agreement; kept : (n,) bool, the frame sets passing rule 1
    """
    n = len(t_s)
    if options.flight_window == 0:
        return kept.copy()
    out = np.zeros(n, bool)
    w = int(options.flight_window)
    for i in np.flatnonzero(kept):
        nb = [j for j in range(max(0, i - w), min(n, i + w + 1)) if j != i and kept[j]]
        if len(nb) < 2:
            continue
        t = np.asarray(t_s, float)[nb] - t_s[i]
        deg = 1 if len(nb) == 2 else 2
        if np.ptp(t) <= 0:
            continue
        A = np.vander(t, deg + 1)
        coef, *_ = np.linalg.lstsq(A, positions_m[nb], rcond=None)
        predicted = coef[-1]  # the fit at t = 0: this frame set's time
        out[i] = np.linalg.norm(predicted - positions_m[i]) <= options.max_flight_residual_m
    return out


def auto_label(framesets, rig, model, options: AutoOptions = AutoOptions(), *, progress=None) -> tuple[list, dict]:
    """Run the consensus over ``framesets`` (an iterable of RecordedSet, rig camera order); returns (kept labels, counts).

    counts : ``frame_sets`` read, ``agreed`` (rule 1), ``kept`` (rule 2 too), ``low_support`` / ``reprojection`` (why rule 1
    failed where the tracker had a position), ``size_rejected`` (frame sets where the size test dropped a position first)
    """
    from tracker import RobustOptions, Status
    from tracker.detection import DetectorOptions
    from tracker.pipeline import Tracker

    from tracker.observation import FrameSet

    tracker = Tracker(rig, "rt2", model=model, roi=False, workers=1, hypotheses=None, handover_max_age_s=None,
                      ball_radius_m=options.ball_radius_m, max_size_ratio=options.max_size_ratio,
                      detector_options=DetectorOptions(method="ours", max_candidates=options.max_candidates, t_high=options.t_high,
                                                       t_low=options.t_low, min_area_px=4, max_area_px=max_ball_area_px(rig, options)),
                      estimator_options=RobustOptions(max_candidates_per_camera=options.max_candidates))
    found, times, counts = [], [], {"frame_sets": 0, "agreed": 0, "size_rejected": 0, "low_support": 0, "reprojection": 0}
    try:
        for rs in framesets:
            tracker.reset()
            before = tracker.stats.size_rejections
            obs, info = tracker.process_with_info(FrameSet(rs.t_s, list(rs.images)))
            counts["frame_sets"] += 1
            times.append(rs.t_s)
            est = info.estimate
            labels = None
            counts["size_rejected"] += int(tracker.stats.size_rejections > before)  # a position redone without the wide blobs
            if obs.has_position and obs.status == Status.OK and est is not None and est.support >= options.min_support:
                inl = np.asarray(est.inliers, bool)
                if np.all(np.asarray(est.reproj_error_px)[inl] <= options.max_reprojection_px):
                    labels = labels_of(rig, rs.index, rs.frame_id, rs.t_s, obs.position_m, est, info.uv_candidates_px, info.areas_px, options)
                else:
                    counts["reprojection"] += 1
            elif obs.has_position:
                counts["low_support"] += 1
            found.append(labels)
            if progress is not None:
                progress(counts["frame_sets"])
    finally:
        tracker.close()
    agreed = np.array([f is not None for f in found], bool)
    pos = np.array([f.position_m if f is not None else [np.nan] * 3 for f in found], float).reshape(-1, 3)
    keep = flight_consistent(np.array(times, float), pos, agreed, options)
    counts["agreed"] = int(agreed.sum())
    counts["kept"] = int(keep.sum())
    return [f for f, k in zip(found, keep) if k], counts
