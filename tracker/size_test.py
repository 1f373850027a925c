"""The 3D size test of the ``rt2`` pipeline: is what the cameras agree on as wide as a ball at that depth?

A position fixes each inlier camera's depth ``z``, so a ball there is ``2 r f / z`` pixels wide
(``r`` the ball's radius, ``f`` the camera's mean focal length). The blob a candidate came from is
``sqrt(4 area / pi)`` wide, less the detector's edge loss: the pixels at the rim that stay under
``T_l`` make a ball's blob a nearly constant ``edge_px`` narrower than the ball, whatever its size
(shipped model, rendered lab: blob width = 0.98 ball width - 2.80 px, :func:`fit_edge_loss` as
``rt2 eval framesets`` runs it; docs/pipeline.md, step 8). The measured width is thus
``sqrt(4 area / pi) + edge_px``; when the median over the inliers of measured width / ball width
exceeds ``max_ratio``, the cameras agree on an orange object too big to be the ball: its candidates
are dropped and the estimate is redone, until a position passes or none is left (docs/pipeline.md,
step 8). The test is the last stage of the consensus (:meth:`SizeTest.stage` given to
:meth:`tracker.robust.RobustTriangulator.estimate_checked`); it never calls the estimator itself. Without the edge loss (``edge_px=0``) the ratio of a true ball falls with its distance
(0.45-0.95 over the lab's 6-13 px wide balls) and a far orange sphere 1.5 times the ball's radius
looks ball-sized; with it a ball's ratio is ~1 at every distance.

Kept apart from :mod:`tracker.pipeline` so that re-evaluation from logged detections
(``harness.experiments.accuracy.reevaluate_accuracy``) applies exactly the same test.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import numpy as np

__all__ = ["EdgeLossFit", "SizeTest", "fit_edge_loss", "size_threshold"]


def size_threshold(max_ratio: float | None, model_ratio: float | None, use_model: bool = True) -> float | None:
    """The size test's threshold: ``max_ratio`` (None: off), raised to ``model_ratio`` when ``use_model`` and the
    model records one (a learned stage's ``size_ratio``: its diameters spread wider than a blob's)."""
    if max_ratio is None or model_ratio is None or not use_model:
        return max_ratio
    return max(float(max_ratio), float(model_ratio))


class SizeTest:
    """The size test for one rig.

    rig : :class:`~tracker.rig.Rig`; max_ratio : the threshold (None: measure, never reject);
    ball_radius_m : the ball's radius, metres; edge_px : the detector's edge loss, pixels added to
    every blob's width (module docstring; 0 = the raw blob width)
    """

    def __init__(self, rig, max_ratio: float | None, ball_radius_m: float = 0.02, edge_px: float = 0.0):
        self.max_ratio = max_ratio
        self.edge_px = float(edge_px)
        self.names = rig.names
        self._depth_rows = [(*map(float, c.R_world_to_cam[2]), float(c.t_world_to_cam_m[2])) for c in rig]
        self._ball_px_m = [2.0 * ball_radius_m * 0.5 * float(c.K[0, 0] + c.K[1, 1]) for c in rig]

    def ratio(self, X, candidate_index, areas_px) -> float:
        """Median over the cameras with ``candidate_index >= 0`` of measured blob width (with the edge
        loss) / ball width at ``X``.

        X : (3,) position; candidate_index : (n_cams,) int; areas_px : (n_cams, k) blob areas, pixels
        """
        edge = self.edge_px
        return statistics.median([(w + edge) * z / k for w, z, k in self._inlier_terms(X, candidate_index, areas_px)])

    def widths_px(self, X, candidate_index, areas_px) -> tuple[np.ndarray, np.ndarray]:
        """The two widths the test compares, per camera with ``candidate_index >= 0`` (in camera order):
        ``(blob_px, ball_px)``, the raw blob width ``sqrt(4 area / pi)`` (without the edge loss) and the
        width ``2 r f / z`` of a ball at ``X``'s depth ``z``, pixels. :func:`fit_edge_loss` measures the
        edge loss from many of them.

        X : (3,) position, world frame, metres; candidate_index : (n_cams,) int; areas_px : (n_cams, k)
        blob areas, pixels
        """
        terms = self._inlier_terms(X, candidate_index, areas_px)
        return np.array([w for w, _, _ in terms], float), np.array([k / z for _, z, k in terms], float)

    def _inlier_terms(self, X, candidate_index, areas_px) -> list[tuple[float, float, float]]:
        """Per camera with a candidate: (raw blob width px, depth of ``X`` m, ``2 r f`` px m)."""
        x, y, z = (float(v) for v in X)
        terms = []
        for i, c in enumerate(candidate_index.tolist()):  # plain Python: a few cameras, ~10x cheaper than numpy calls
            if c >= 0:
                a, b, d, t = self._depth_rows[i]
                terms.append((math.sqrt(4.0 / math.pi * float(areas_px[i, c])), a * x + b * y + d * z + t, self._ball_px_m[i]))
        return terms

    def check(self, X, candidate_index, areas_px) -> tuple[float, bool]:
        """The test of one position: ``(ratio, passed)``; ``passed`` is always True without a threshold.

        X : (3,) position, world frame, metres; candidate_index : (n_cams,) int; areas_px : (n_cams, k)
        blob areas, pixels
        """
        ratio = self.ratio(X, candidate_index, areas_px)
        return ratio, self.max_ratio is None or not ratio > self.max_ratio

    def stage(self, areas_px):
        """The test as the last stage of the consensus (:meth:`RobustTriangulator.estimate_checked`) on
        the candidates whose blob areas are ``areas_px`` ((n_cams, k) pixels; read at each call, so a
        workspace refilled every frame set needs one stage)."""
        return lambda X, candidate_index: self.check(X, candidate_index, areas_px)

    def rejection_note(self, cams, ratio: float) -> str:
        """The note of a position seen by cameras ``cams`` (indices) that failed with ``ratio``."""
        return (f"rejected the position seen by {', '.join(self.names[i] for i in cams)}: its blobs are {ratio:.2f} times as wide "
                f"as a ball at that depth (max_size_ratio {self.max_ratio:g}); estimated again without them")


@dataclass(frozen=True)
class EdgeLossFit:
    """The least-squares line ``blob width = slope * ball width - edge_loss_px`` (:func:`fit_edge_loss`).

    slope : dimensionless; edge_loss_px : the detector's edge loss, pixels (the model's ``edge_loss_px``);
    residual_px : root mean square of the fit's residuals, pixels; cameras : the (blob, ball) width
    pairs fitted, one per inlier camera of each position
    """

    slope: float
    edge_loss_px: float
    residual_px: float
    cameras: int

    def as_json(self) -> dict:
        return {"slope": round(self.slope, 6), "edge_loss_px": round(self.edge_loss_px, 6), "residual_px": round(self.residual_px, 6), "cameras": self.cameras}

    def __str__(self) -> str:
        return f"blob width = {self.slope:.2f} x ball width - {self.edge_loss_px:.2f} px, residual {self.residual_px:.2f} px, {self.cameras} cameras"


def fit_edge_loss(blob_px, ball_px) -> EdgeLossFit:
    """Fit ``blob_px = slope * ball_px - edge_loss_px`` by least squares (docs/pipeline.md, step 8).

    blob_px : (n,) raw blob widths ``sqrt(4 area / pi)``, pixels; ball_px : (n,) the widths of a ball at
    the same cameras' depths, pixels (both from :meth:`SizeTest.widths_px` over right positions).
    Raises ``ValueError`` for mismatched shapes, non-finite widths, fewer than 2 pairs or ball widths
    that are all equal (no line through them).
    """
    blob_px = np.asarray(blob_px, float)
    ball_px = np.asarray(ball_px, float)
    if blob_px.ndim != 1 or blob_px.shape != ball_px.shape:
        raise ValueError(f"blob_px and ball_px must be two (n,) arrays of the same length, got shapes {blob_px.shape} and {ball_px.shape}")
    if not (np.isfinite(blob_px).all() and np.isfinite(ball_px).all()):
        raise ValueError("blob_px and ball_px must be finite widths, pixels; got NaN or inf")
    if len(blob_px) < 2 or np.ptp(ball_px) == 0.0:
        raise ValueError(f"fitting the edge loss needs >= 2 cameras with different ball widths, got {len(blob_px)}")
    A = np.column_stack([ball_px, -np.ones_like(ball_px)])
    (slope, edge), *_ = np.linalg.lstsq(A, blob_px, rcond=None)
    residual = float(np.sqrt(np.mean((A @ (slope, edge) - blob_px) ** 2)))
    return EdgeLossFit(float(slope), float(edge), residual, len(blob_px))
