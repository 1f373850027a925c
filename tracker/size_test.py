"""The 3D size test of the ``rt2`` pipeline: is what the cameras agree on as wide as a ball at that depth?

A position fixes each inlier camera's depth ``z``, so a ball there is ``2 r f / z`` pixels wide
(``r`` the ball's radius, ``f`` the camera's mean focal length). The blob a candidate came from is
``sqrt(4 area / pi)`` wide, less the detector's edge loss: the pixels at the rim that stay under
``T_l`` make a ball's blob a nearly constant ``edge_px`` narrower than the ball, whatever its size
(shipped model, rendered lab: blob width = 0.98 ball width - 2.8 px). The measured width is thus
``sqrt(4 area / pi) + edge_px``; when the median over the inliers of measured width / ball width
exceeds ``max_ratio``, the cameras agree on an orange object too big to be the ball: its candidates
are dropped and the estimate is redone, until a position passes or none is left (docs/pipeline.md,
step 8). Without the edge loss (``edge_px=0``) the ratio of a true ball falls with its distance
(0.45-0.95 over the lab's 6-13 px wide balls) and a far orange sphere 1.5 times the ball's radius
looks ball-sized; with it a ball's ratio is ~1 at every distance.

Kept apart from :mod:`tracker.pipeline` so that re-evaluation from logged detections
(``harness.experiments.accuracy.reevaluate``) applies exactly the same test.
"""

from __future__ import annotations

import math
import statistics

import numpy as np

__all__ = ["SizeTest"]


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
        x, y, z = (float(v) for v in X)
        edge = self.edge_px
        ratios = []
        for i, c in enumerate(candidate_index.tolist()):  # plain Python: a few cameras, ~10x cheaper than numpy calls
            if c >= 0:
                a, b, d, t = self._depth_rows[i]
                ratios.append((math.sqrt(4.0 / math.pi * float(areas_px[i, c])) + edge) * (a * x + b * y + d * z + t) / self._ball_px_m[i])
        return statistics.median(ratios)

    def apply(self, estimator, uv, areas_px, X, info, notes: list | None = None):
        """Test the estimate ``(X, info)`` of ``estimator`` on candidates ``uv``; while it fails, drop the
        used candidates (from a copy made at the first rejection: ``uv`` itself is never changed) and
        estimate again.

        Returns ``(X, info, ratio, rejections)``: the final estimate, its ratio (NaN without a position)
        and how many positions were rejected; each rejection appends a note to ``notes``.
        """
        ratio, rejections = math.nan, 0
        while X is not None:
            ratio = self.ratio(X, info.candidate_index, areas_px)
            if self.max_ratio is None or not ratio > self.max_ratio:
                break
            if rejections == 0:
                uv = uv.copy()  # the common case (nothing rejected) allocates nothing
            rejections += 1
            cams = np.flatnonzero(info.candidate_index >= 0)
            if notes is not None:
                notes.append(
                    f"rejected the position seen by {', '.join(self.names[i] for i in cams)}: its blobs are {ratio:.2f} times as wide "
                    f"as a ball at that depth (max_size_ratio {self.max_ratio:g}); estimated again without them"
                )
            uv[cams, info.candidate_index[cams]] = np.nan
            X, info = estimator.estimate(uv)
            ratio = math.nan
        return X, info, ratio, rejections
