"""Camera poses from a single ball moved through the volume (no wand): up to scale, fixed by world points.

``calibrate_ball(cameras, uv)``:

1. the best-supported camera pair: essential matrix (RANSAC) and pose, baseline 1 (arbitrary unit);
2. the ball triangulated with the cameras placed so far; the next camera (most 3D-2D matches) by
   ``cv2.solvePnPRansac``; repeat (the unit stays the first pair's baseline);
3. :func:`bundle_adjust` of all cameras and all ball positions (camera 0 fixed);
4. :func:`apply_similarity` maps the result onto >= 3 known world points (e.g. the table corners):
   a single ball has no length in it, so scale comes from there (or later from the robot).
"""

from __future__ import annotations

import cv2
import numpy as np

from tracker.calibration.bundle import BundleOptions, PointModel, bundle_adjust
from tracker.calibration.extrinsics import check_spread, pair_essential, triangulate_views, undistort_pixels
from tracker.calibration.poses import reframe_poses, rvec_to_R

__all__ = ["apply_similarity", "calibrate_ball"]


def calibrate_ball(cameras, uv, *, min_matches: int = 30, ransac_px: float = 2.0, planar_ratio: float = 0.05,
                   options: BundleOptions | None = None):
    """Poses of ``cameras`` (intrinsics used) from one ball: ``uv`` (n_cams, F, 2) distorted pixels, NaN = not seen.

    returns (R (n, 3, 3), t (n, 3) in the unit "first pair's baseline", the bundle adjustment's ``BundleResult``)
    """
    cams = list(cameras)
    names = [c.name for c in cams]
    uv = np.asarray(uv, float)
    n = len(cams)
    if uv.ndim != 3 or uv.shape[0] != n or uv.shape[2] != 2:
        raise ValueError(f"uv must have shape ({n} cameras, F frames, 2), got shape {uv.shape}")
    seen = ~np.isnan(uv).any(axis=-1)
    for c in range(n):
        if seen[c].sum() < min_matches:
            raise ValueError(f"camera {names[c]}: only {int(seen[c].sum())} ball detections, need >= {min_matches}")
    xn = np.stack([undistort_pixels(c, uv[i]) for i, c in enumerate(cams)])
    f_mean = float(np.mean([c.K[0, 0] for c in cams]))
    both = seen[:, None] & seen[None, :]
    shared = both.sum(axis=2)
    np.fill_diagonal(shared, 0)
    i, j = np.unravel_index(np.argmax(shared), shared.shape)
    i, j = min(i, j), max(i, j)
    if shared[i, j] < min_matches:
        raise ValueError(f"no camera pair shares {min_matches} ball detections (best: {names[i]}-{names[j]}, {shared[i, j]})")
    m = both[i, j]
    R_ij, t_ij, inl = pair_essential(xn[i, m], xn[j, m], ransac_px / f_mean)
    if R_ij is None:
        raise ValueError(f"cameras {names[i]}, {names[j]}: no essential matrix from {int(m.sum())} shared detections")
    R = np.full((n, 3, 3), np.nan)
    t = np.full((n, 3), np.nan)
    R[i], t[i] = np.eye(3), np.zeros(3)
    R[j], t[j] = R_ij, t_ij / np.linalg.norm(t_ij)
    placed = [i, j]
    while len(placed) < n:
        X = triangulate_views([cams[k] for k in placed], R[placed], t[placed], uv[placed])
        best, best_n = None, 0
        for c in range(n):
            if c in placed:
                continue
            k = int((seen[c] & np.isfinite(X).all(axis=1)).sum())
            if k > best_n:
                best, best_n = c, k
        if best is None or best_n < min_matches:
            missing = [names[c] for c in range(n) if c not in placed]
            raise ValueError(f"cameras {missing} share fewer than {min_matches} ball detections with {[names[c] for c in placed]}")
        ok = seen[best] & np.isfinite(X).all(axis=1)
        good, rvec, tvec, _ = cv2.solvePnPRansac(X[ok], xn[best, ok], np.eye(3), None, reprojectionError=ransac_px / f_mean,
                                                 flags=cv2.SOLVEPNP_EPNP)
        if not good:
            raise ValueError(f"camera {names[best]}: cannot place it from {best_n} triangulated ball positions")
        R[best], t[best] = rvec_to_R(rvec.ravel()), tvec.ravel()
        placed.append(best)
    # camera 0 as the world frame (gauge of the bundle adjustment)
    R0, t0 = R[0].copy(), t[0].copy()
    t = t - np.einsum("nij,j->ni", R @ R0.T, t0)
    R = R @ R0.T
    X = triangulate_views(cams, R, t, uv)
    check_spread(X, planar_ratio, what="ball")
    ok = np.isfinite(X).all(axis=1)
    K = np.stack([c.K for c in cams])
    d8 = np.stack([c.dist8 for c in cams])
    res = bundle_adjust(K, d8, R, t, uv[:, ok, None, :], PointModel(), X[ok], options or BundleOptions())
    return res.R, res.t, res


def apply_similarity(R: np.ndarray, t: np.ndarray, X_calib: np.ndarray, X_world: np.ndarray):
    """Re-frame and re-scale poses so ``X_calib`` (N >= 3, 3) land on ``X_world``: returns (R', t', scale, residual (N,) m)."""
    return reframe_poses(R, t, X_calib, X_world, scale=True)
