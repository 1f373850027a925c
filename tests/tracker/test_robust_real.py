"""Real-data check: the ewand recordings (cogsys-tuebingen/ewand, Apache-2.0; see
../shared/data/real/README.md): four calibrated 1280x1024 cameras watching a wand with three balls.

Ground truth: consecutive ball spacings of 130 mm and 260 mm (end ball to end ball 390 mm). The
wand's own calibration code says so (``calibration_framework/src/BundleAdjustment.cpp``:
``marker_1_2_ = 0.13``, ``marker_2_3_ = 0.26``), and so does the data: triangulated, the three
distances are 130.5, 260.9 and 391.4 mm, all 0.36 % long (a scale error of the calibration), so the
balls sit 130 and 390 mm from the end ball. The data README's "130 mm and 260 mm from the end ball"
is wrong about the third ball; the issue's "130 mm and 390 mm" is right when read as distances from
the end ball.

Threshold: the calibration reprojects true detections with a median of 2.3 px and a 99th
percentile of 5.5 px (Algorithm 2 with a generous threshold), so these tests use eps_px = 10.
"""

from __future__ import annotations

import numpy as np
import pytest

from tracker import RobustTriangulator

EPS_PX = 10.0
SPACING_MM = (130.0, 260.0)  # ball 1-2, ball 2-3


@pytest.fixture(scope="module")
def wand_uv(ewand_dir) -> np.ndarray:
    """(n_frames, 4 cameras, 3 balls, 2) distorted pixels at the timestamps all cameras share."""
    tables = [np.loadtxt(ewand_dir / f"frame_{i}.csv", delimiter=";") for i in range(4)]
    common = np.array(sorted(set.intersection(*(set(t[:, 0]) for t in tables))))
    uv = np.empty((len(common), 4, 3, 2))
    for c, t in enumerate(tables):  # frame_0.csv is not sorted by time: look rows up by timestamp
        row_of = {ts: i for i, ts in enumerate(t[:, 0])}
        uv[:, c] = t[[row_of[ts] for ts in common], 1:].reshape(-1, 3, 2)
    uv[uv < 0] = np.nan  # -1 = not detected
    return uv


def triangulate_balls(est, uv):
    """Per ball: positions (n_frames, 3) and the batch info."""
    return [est.estimate_many(np.ascontiguousarray(uv[:, :, b])) for b in range(3)]


def spacings_mm(res):
    X = [r[0] for r in res]
    return np.linalg.norm(X[0] - X[1], axis=1) * 1e3, np.linalg.norm(X[1] - X[2], axis=1) * 1e3


def test_wand_spacings(ewand_rig, wand_uv):
    res = triangulate_balls(RobustTriangulator(ewand_rig, eps_px=EPS_PX), wand_uv)
    d12, d23 = spacings_mm(res)
    both = np.isfinite(d12) & np.isfinite(d23)
    assert both.sum() >= 600  # of 619 frames
    assert abs(np.median(d12[both]) - SPACING_MM[0]) < 1.0
    assert abs(np.median(d23[both]) - SPACING_MM[1]) < 1.0
    d13 = np.linalg.norm(res[0][0] - res[2][0], axis=1)[both] * 1e3
    assert abs(np.median(d13) - 390.0) < 1.5  # the third ball is 390 mm from the end ball, not 260
    assert abs(np.median(d23[both] / d12[both]) - 2.0) < 0.005  # scale-free: the geometry is right
    # every camera is consistent on clean data: no real detection is rejected at this threshold
    inl = np.concatenate([r[1].inliers[r[1].has_position] for r in res])
    seen = np.concatenate([~np.isnan(wand_uv[:, :, b, 0])[res[b][1].has_position] for b in range(3)])
    assert (inl == seen).mean() > 0.999


def test_survives_20_percent_random_detections(ewand_rig, wand_uv):
    rng = np.random.default_rng(2026)
    replaced = rng.random(wand_uv.shape[:3]) < 0.2
    random_px = rng.uniform(0, 1, wand_uv.shape) * np.array([1280, 1024]) - 0.5
    noisy = np.where(replaced[..., None], random_px, wand_uv)
    est = RobustTriangulator(ewand_rig, eps_px=EPS_PX)
    res = triangulate_balls(est, noisy)
    clean = triangulate_balls(est, wand_uv)
    for b in range(3):
        X, info = res[b]
        trusted = info.support >= 3
        assert trusted.sum() > 300
        # (a) no replaced detection is ever part of a trusted set, unless it fell on the ball itself
        Xc = clean[b][0]
        proj = np.swapaxes(ewand_rig.project(np.nan_to_num(Xc)), 0, 1)  # (n_frames, 4, 2)
        on_ball = np.linalg.norm(noisy[:, :, b] - proj, axis=2) < 2 * EPS_PX
        assert not (info.inliers & replaced[:, :, b] & ~on_ball)[trusted].any()
        # (b) a trusted estimate is exactly the clean estimate from the same cameras (where no
        # replaced pixel happened to land on the ball)
        same_cams = np.where(info.inliers[:, :, None], wand_uv[:, :, b], np.nan)
        X_same, _ = est.estimate_many(same_cams)
        genuine = trusted & ~(info.inliers & replaced[:, :, b]).any(axis=1)
        assert genuine.sum() >= trusted.sum() - 3
        assert np.allclose(X[genuine], X_same[genuine], atol=1e-6)
    # (c) spacings of trusted estimates. Where all three balls use the same cameras: within 10 mm.
    # Where they use different 3-camera subsets the calibration itself disagrees: clean detections
    # triangulated from different subsets are up to 17 mm apart in spacing, so the bound is 20 mm.
    d12, d23 = spacings_mm(res)
    trusted = np.min([r[1].support for r in res], axis=0) >= 3
    same = trusted & (res[0][1].inliers == res[1][1].inliers).all(1) & (res[1][1].inliers == res[2][1].inliers).all(1)
    assert same.sum() > 30
    assert np.abs(d12[same] - SPACING_MM[0]).max() < 10.0 and np.abs(d23[same] - SPACING_MM[1]).max() < 10.0
    assert np.abs(d12[trusted] - SPACING_MM[0]).max() < 20.0 and np.abs(d23[trusted] - SPACING_MM[1]).max() < 20.0
    assert np.median(np.abs(d12[trusted] - SPACING_MM[0])) < 2.0
