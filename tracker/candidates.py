"""The rt2 pipeline after detection, from candidates and their blob areas: what re-evaluation from a
session log's detections runs to reproduce a tracker's positions without its images.

    est = CandidateEstimator(rig, "rt2", edge_px=model.edge_loss_px)   # or "rt2-paper"; eps_px= as Tracker
    X, info = est.estimate(t_s, uv_px, areas_px)         # per frame set, in time order

Per frame set: the robust estimate (:class:`~tracker.robust.RobustTriangulator` with the kind's
method), the 3D size test (:class:`~tracker.size_test.SizeTest`, when the areas are known) and, for
``rt2``, the support hand-over (:class:`~tracker.handover.SupportHandover`, with the tracker's time
rule: a time that does not increase forgets the history). The parts are built with
:class:`~tracker.pipeline.TrackerOptions`' defaults, as :class:`~tracker.pipeline.Tracker` builds
them (docs/pipeline.md steps 6-9).
"""

from __future__ import annotations

import math

import numpy as np

from tracker.pipeline import KINDS, TrackerOptions
from tracker.handover import SupportHandover
from tracker.observation import Status
from tracker.robust import EstimateInfo, RobustOptions, RobustTriangulator
from tracker.size_test import SizeTest, size_threshold

__all__ = ["CandidateEstimator", "ESTIMATOR_KINDS"]

#: the tracker kinds with a robust estimator (``rtblob`` has its own fixed pairs)
ESTIMATOR_KINDS = tuple(k for k, spec in KINDS.items() if spec.estimator_method is not None)


class CandidateEstimator:
    """Estimator, size test and hand-over of tracker ``kind`` on ``rig``.

    kind : one of :data:`ESTIMATOR_KINDS` ("rt2", "rt2-paper"); eps_px : the estimator's
        consistency threshold, pixels (None: ``RobustOptions.eps_px``); edge_px : the detector's edge loss
        for the size test, pixels (the ``edge_loss_px`` of the model that made the candidates); size_ratio : the
        size test's threshold that model records (``BallDetector.size_ratio``; None: the tracker's default)
    Attributes ``estimator``, ``size_test`` and ``handover`` (None unless ``rt2``) are the parts. A new
    recording takes a new CandidateEstimator; within one, a time that does not increase forgets the
    hand-over's history.
    """

    def __init__(self, rig, kind: str = "rt2", *, eps_px: float | None = None, edge_px: float = 0.0, size_ratio: float | None = None):
        if kind not in ESTIMATOR_KINDS:
            raise ValueError(f"tracker {kind!r} has no robust estimator to re-run; valid: {sorted(ESTIMATOR_KINDS)}")
        self.kind = kind
        options = RobustOptions() if eps_px is None else RobustOptions(eps_px=float(eps_px))
        self.estimator = RobustTriangulator(rig, options, method=KINDS[kind].estimator_method)
        defaults = TrackerOptions()
        extras = KINDS[kind].extras  # the size test's threshold and the hand-over: rt2's steps beyond the paper
        self.size_test = SizeTest(rig, size_threshold(defaults.max_size_ratio, size_ratio, defaults.model_size_ratio) if extras else None,
                                  defaults.ball_radius_m, edge_px)
        age = defaults.handover_max_age_s
        self.handover = (SupportHandover(self.estimator, len(rig), max_age_s=age)
                         if extras and age is not None else None)

    def estimate(self, t_s: float, uv_px: np.ndarray, areas_px: np.ndarray | None = None) -> tuple[np.ndarray | None, EstimateInfo]:
        """One frame set's position from its candidates.

        t_s : the frame set's time, seconds (frame sets in time order); uv_px : (n_cams, k, 2)
            distorted pixels, NaN-padded; areas_px : (n_cams, k) their blob areas, pixels, or None
            when unknown (the size test is then skipped)
        returns (X_world (3,) metres or None, :class:`~tracker.robust.EstimateInfo`)
        """
        if areas_px is None:
            X, info = self.estimator.estimate(uv_px)
        else:  # the size test as the consensus's last stage, as the tracker runs it
            X, info, _, _ = self.estimator.estimate_checked(uv_px, self.size_test.stage(areas_px))
        if self.handover is not None:
            self.handover.step(t_s)
            if X is not None and math.isfinite(t_s):
                used = np.full((uv_px.shape[0], 2), np.nan)
                sel = np.flatnonzero(info.candidate_index >= 0)
                used[sel] = uv_px[sel, info.candidate_index[sel]]
                X, _ = self.handover.apply(t_s, X, used, info.status is Status.OK)
        return X, info
