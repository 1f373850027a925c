"""Scores of ball detections against labelled balls: the definitions of ``rt2 eval detector``
(:mod:`harness.experiments.studies.eval_detector`, whose docstring states them), shared with
``rt2 train``'s threshold choice, which scores its validation set the same way.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["DetectorScores", "OUTLIER_BOUNDS", "operating_points", "score_detections", "truth_of"]

#: the outlier rates :func:`operating_points` reports the best recall under (the goals' "<= 2 %", and 1 %)
OUTLIER_BOUNDS = (0.01, 0.02)


@dataclass(frozen=True)
class DetectorScores:
    """Detection quality of one method on one labelled set (see the module docstring)."""

    method: str
    recall: float
    outlier_rate: float
    median_center_error_px: float
    p95_center_error_px: float
    n_images: int = 0
    n_balls: int = 0  #: balls of at least min_diameter_px
    n_detections: int = 0
    n_outliers: int = 0
    n_outliers_with_ball: int = 0  #: outliers in images that show a labelled ball
    n_images_without_ball: int = 0
    n_false_alarm_images: int = 0  #: images without a labelled ball but with a detection
    per_camera: dict | None = None  #: {camera name: DetectorScores of its images} where the images name their camera
    #: with ``rt2 eval detector --motion-cue``: {"sequences", "images_without_cue", "candidates_dropped"} (else None)
    motion_cue: dict | None = None
    #: ``ours``: :func:`operating_points`, {outlier bound: {"recall", "outlier_rate", "threshold", "n_detections"}} (else None)
    operating_points: dict | None = None

    def as_json(self) -> dict:
        keys = ("method", "recall", "outlier_rate", "median_center_error_px", "p95_center_error_px")
        out = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items() if k in keys}
        if self.per_camera:
            out["per_camera"] = {name: {**s.as_json(), "n_balls": s.n_balls, "n_images": s.n_images, "n_detections": s.n_detections}
                                 for name, s in self.per_camera.items()}
        if self.motion_cue is not None:
            out["motion_cue"] = dict(self.motion_cue)
        if self.operating_points is not None:
            out["operating_points"] = {f"{bound:g}": dict(point) for bound, point in self.operating_points.items()}
        return out


def score_detections(method: str, truth_centers, truth_diameters, detections, *, min_diameter_px: float = 6.0) -> DetectorScores:
    """Score detections against labels, image by image.

    truth_centers : per image an (g, 2) array of exact ball centres, rt2 pixels
    truth_diameters : per image a (g,) array of ball diameters, px
    detections : per image an (k, 2) array of detected centres (k may be 0)
    """
    if not (len(truth_centers) == len(truth_diameters) == len(detections)):
        raise ValueError(
            f"need one entry per image, got {len(truth_centers)} truth centres, {len(truth_diameters)} diameters, {len(detections)} detections"
        )
    n_balls = n_hit = n_det = n_out = n_out_ball = n_empty = n_alarm = 0
    errors = []
    for c, d, uv in zip(truth_centers, truth_diameters, detections):
        c = np.asarray(c, float).reshape(-1, 2)
        d = np.asarray(d, float).reshape(-1)
        uv = np.asarray(uv, float).reshape(-1, 2)
        uv = uv[np.isfinite(uv).all(axis=1)]
        n_det += len(uv)
        if len(c) == 0:
            n_out += len(uv)
            n_empty += 1
            n_alarm += len(uv) > 0
            continue
        dist = np.linalg.norm(uv[:, None, :] - c[None, :, :], axis=2)  # (k, g)
        near = dist <= d[None, :]  # within two radii
        n_out += int(np.sum(~near.any(axis=1)))
        n_out_ball += int(np.sum(~near.any(axis=1)))
        big = d >= min_diameter_px
        n_balls += int(big.sum())
        for j in np.flatnonzero(big):
            if near[:, j].any():
                n_hit += 1
                errors.append(float(dist[near[:, j], j].min()))
    errors = np.asarray(errors)
    return DetectorScores(
        method=method,
        recall=n_hit / n_balls if n_balls else float("nan"),
        outlier_rate=n_out / n_det if n_det else 0.0,
        median_center_error_px=float(np.median(errors)) if len(errors) else float("nan"),
        p95_center_error_px=float(np.percentile(errors, 95)) if len(errors) else float("nan"),
        n_images=len(detections),
        n_balls=n_balls,
        n_detections=n_det,
        n_outliers=n_out,
        n_outliers_with_ball=n_out_ball,
        n_images_without_ball=n_empty,
        n_false_alarm_images=n_alarm,
    )


def operating_points(truth_centers, truth_diameters, firsts, first_scores, *, min_diameter_px: float = 6.0,
                     bounds=OUTLIER_BOUNDS) -> dict:
    """The best recall of one detection per image (its best candidate, ``ours``) kept where its score reaches a threshold,
    under each outlier rate of ``bounds``: what a stricter threshold than the one scored would give (the goals ask for
    recall at <= 2 % outliers). ``firsts``: per image a (k, 2) array of at most one centre; ``first_scores``: its score
    (ignored where there is none). Returns ``{bound: {"recall", "outlier_rate", "threshold", "n_detections"}}``: the
    highest threshold (a score; candidates at or above it kept) with the most balls found within the bound; recall 0
    and threshold None where no threshold keeps any ball within it."""
    rows = []  # (score, balls this detection recalls, is an outlier)
    n_balls = 0
    for c, d, uv, s in zip(truth_centers, truth_diameters, firsts, first_scores):
        c = np.asarray(c, float).reshape(-1, 2)
        d = np.asarray(d, float).reshape(-1)
        big = d >= min_diameter_px
        n_balls += int(big.sum())
        uv = np.asarray(uv, float).reshape(-1, 2)[:1]
        if len(uv) == 0 or not np.isfinite(uv).all() or s is None or not np.isfinite(s):
            continue
        near = np.linalg.norm(c - uv[0], axis=1) <= d if len(c) else np.zeros(0, bool)
        rows.append((float(s), int((near & big).sum()), not near.any()))
    rows.sort(key=lambda r: -r[0])
    out = {}
    for bound in bounds:
        best = {"recall": 0.0, "outlier_rate": 0.0, "threshold": None, "n_detections": 0}
        hits = outs = 0
        for i, (s, hit, is_out) in enumerate(rows):
            hits, outs = hits + hit, outs + is_out
            last = i + 1 == len(rows) or rows[i + 1][0] < s  # a threshold keeps every candidate of one score or none
            if last and outs <= bound * (i + 1) and n_balls and hits / n_balls > best["recall"]:
                below = rows[i + 1][0] if i + 1 < len(rows) else None
                best = {"recall": hits / n_balls, "outlier_rate": outs / (i + 1), "threshold": _short_between(below, s),
                        "n_detections": i + 1}
        out[bound] = best
    return out


def _short_between(lo: float | None, hi: float) -> float:
    """The number of fewest decimals in ``(lo, hi]``: a threshold that keeps the candidates scoring ``hi`` and none
    scoring ``lo``, short enough to type. Without ``lo`` (no lower score was seen: the run's own threshold is below
    ``hi``), ``hi`` at 6 decimals, rounded down."""
    for digits in range(1, 7) if lo is not None else ():
        v = math.floor(hi * 10**digits) / 10**digits
        if v > lo:
            return v
    return math.floor(hi * 1e6) / 1e6


def truth_of(labelled) -> tuple[np.ndarray, np.ndarray]:
    """(g, 2) exact centres and (g,) diameters (shorter box side) of a ``LabelledImage``."""
    return labelled.centers_px, np.minimum(labelled.boxes_xywh[:, 2], labelled.boxes_xywh[:, 3])
