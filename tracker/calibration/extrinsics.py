"""Camera poses from a wand moved through the volume: pairwise essential matrices, then bundle adjustment.

``calibrate_wand(cameras, uv, offsets_m)``:

1. hold out every ``holdout_every``-th frame set (never used to fit; the wand-length check uses them);
2. for each camera pair, the essential matrix of the shared ball detections (RANSAC on undistorted
   normalised coordinates, ``cv2.findEssentialMat``) and its pose (``cv2.recoverPose``), scaled so
   the triangulated wand has its known lengths;
3. camera poses along the maximum spanning tree of pair support (camera 0 is the world frame);
4. each frame's wand from the triangulated balls, then :func:`bundle_adjust` of all cameras and
   all wand poses with a robust loss (the wand's lengths and collinearity are hard constraints);
5. on the held-out frames: balls triangulated with the result, the wand's lengths compared with the
   known ones, and the reprojection error per camera.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import cv2
import numpy as np

from tracker.calibration.bundle import BundleOptions, BundleResult, WandModel, bundle_adjust, project_cameras
from tracker.calibration.poses import chain_poses, reframe_poses
from tracker.camera import Camera
from tracker.triangulation import triangulate_linear

__all__ = ["WandOptions", "WandResult", "apply_world", "calibrate_wand", "check_spread", "order_wand_points", "pair_essential", "triangulate_views", "undistort_pixels"]


@dataclass(frozen=True)
class WandOptions:
    """min_pair_points : ball correspondences a camera pair needs to estimate its essential matrix
    min_camera_obs : wand detections each camera needs in the fitted frames
    ransac_px : RANSAC threshold of the essential matrix, pixels
    holdout_every : every n-th frame set is held out for the checks (0: none)
    planar_ratio : the wand's motion is degenerate when its balls' extent across the thinnest
        direction is below this share of the largest
    bundle : :class:`BundleOptions`"""

    min_pair_points: int = 30
    min_camera_obs: int = 30
    ransac_px: float = 2.0
    holdout_every: int = 5
    planar_ratio: float = 0.05
    bundle: BundleOptions = field(default_factory=BundleOptions)

    def __post_init__(self):
        if self.min_pair_points < 8 or self.min_camera_obs < 6 or not self.ransac_px > 0 or self.holdout_every < 0:
            raise ValueError(f"invalid WandOptions: {self}")


@dataclass(frozen=True)
class WandResult:
    """R (n, 3, 3), t (n, 3): world -> camera (world = camera 0 unless re-framed with :func:`apply_world`)
    bundle : the :class:`BundleResult` on the fitted frames
    fit_frames, holdout_frames : frame indices (into the input's F)
    reproj_px : camera name -> dict(rms, median) on the fitted frames (inliers) and holdout (median)
    lengths_m : (H, M-1) consecutive ball spacings triangulated in held-out frames (NaN if not)
    total_m : (H,) first-to-last ball distance in held-out frames
    pair_support : (i, j) -> inlier correspondences of the pair's essential matrix"""

    R: np.ndarray
    t: np.ndarray
    bundle: BundleResult
    fit_frames: np.ndarray
    holdout_frames: np.ndarray
    reproj_px: dict
    lengths_m: np.ndarray
    total_m: np.ndarray
    pair_support: dict


def pair_essential(xn_a: np.ndarray, xn_b: np.ndarray, threshold: float):
    """Relative pose of camera b to camera a from (N, 2) normalised correspondences.

    returns (R_ab, t_ab unit, inlier mask (N,)); ``X_b = R_ab X_a + t_ab * scale``
    """
    E, mask = cv2.findEssentialMat(xn_a, xn_b, np.eye(3), method=cv2.RANSAC, prob=0.9999, threshold=threshold)
    if E is None or E.shape != (3, 3):
        E = None if E is None else E[:3]
    if E is None:
        return None, None, np.zeros(len(xn_a), bool)
    _, R, t, mpose = cv2.recoverPose(E, xn_a, xn_b, np.eye(3), mask=mask.copy())
    return R, t.ravel(), (mpose.ravel() > 0)


def triangulate_views(cams, R, t, uv: np.ndarray) -> np.ndarray:
    """Linear triangulation of (n, P, 2) distorted pixels (NaN: not seen) with poses R, t -> (P, 3)."""
    xn = np.stack([undistort_pixels(c, uv[i]) for i, c in enumerate(cams)], axis=1)  # (P, n, 2)
    P = np.concatenate([R, t[:, :, None]], axis=2)
    return triangulate_linear(xn, P)


def undistort_pixels(cam: Camera, uv: np.ndarray) -> np.ndarray:
    """(..., 2) distorted pixels of ``cam`` -> (..., 2) normalised coordinates; NaN stays NaN."""
    out = np.full(uv.shape, np.nan)
    ok = ~np.isnan(uv).any(axis=-1)
    if ok.any():
        out[ok] = cam.undistort(uv[ok])
    return out


def check_spread(X: np.ndarray, planar_ratio: float, what: str = "wand") -> None:
    """Raise when points (N, 3) are (nearly) on a line or in a plane."""
    X = X[~np.isnan(X).any(axis=1)]
    if len(X) < 4:
        raise ValueError(f"{what}: only {len(X)} triangulated points; the cameras need more shared views")
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False) / np.sqrt(len(X))
    if s[2] < planar_ratio * s[0]:
        raise ValueError(f"{what} motion is degenerate: the points spread {2 * s[0]:.3g} across but only {2 * s[2]:.3g} "
                         f"out of their best plane (ratio {s[2] / s[0]:.3f} < {planar_ratio}); move it through the whole volume")


def calibrate_wand(cameras, uv, offsets_m, options: WandOptions | None = None) -> WandResult:
    """Poses of ``cameras`` (intrinsics used, extrinsics ignored) from wand detections.

    uv : (n_cams, F, M, 2) distorted pixels of the M balls, NaN where not detected; ball m of a frame
         is the same ball in every camera
    offsets_m : (M,) ball positions along the wand from the first ball (0, ...), metres
    """
    opt = options or WandOptions()
    cams = list(cameras)
    names = [c.name for c in cams]
    uv = np.asarray(uv, float)
    offsets = np.asarray(offsets_m, float)
    n, F, M = len(cams), uv.shape[1] if uv.ndim == 4 else 0, len(offsets)
    if uv.ndim != 4 or uv.shape[0] != n or uv.shape[2] != M or uv.shape[3] != 2:
        raise ValueError(f"uv must have shape ({n} cameras, F frames, {M} balls, 2), got shape {uv.shape}")
    if n < 2:
        raise ValueError(f"extrinsic calibration needs at least two cameras, got {names}")
    if M < 2 or offsets[0] != 0 or (np.diff(offsets) <= 0).any():
        raise ValueError(f"wand offsets must start at 0 and increase (at least two balls), got {offsets.tolist()}")
    frames = np.arange(F)
    hold = frames[(frames % opt.holdout_every) == opt.holdout_every - 1] if opt.holdout_every > 1 else frames[:0]
    fit = np.setdiff1d(frames, hold)
    seen = ~np.isnan(uv).any(axis=-1)  # (n, F, M)
    for c in range(n):
        k = int(seen[c, fit].sum())
        if k < opt.min_camera_obs:
            raise ValueError(f"camera {names[c]}: only {k} ball detections in the fitted frames, need >= {opt.min_camera_obs}")
    xn = np.stack([undistort_pixels(c, uv[i]) for i, c in enumerate(cams)])  # (n, F, M, 2)
    f_mean = float(np.mean([c.K[0, 0] for c in cams]))
    edges, support, degenerate = {}, {}, {}
    model = WandModel(offsets)
    for i in range(n):
        for j in range(i + 1, n):
            both = seen[i, fit] & seen[j, fit]
            if both.sum() < opt.min_pair_points:
                continue
            a, b = xn[i, fit][both], xn[j, fit][both]
            R, tu, inl = pair_essential(a, b, opt.ransac_px / f_mean)
            if R is None or inl.sum() < opt.min_pair_points:
                continue
            scale, ratio = _wand_scale(xn[i, fit], xn[j, fit], R, tu, model)
            if ratio < opt.planar_ratio:
                degenerate[names[i], names[j]] = ratio
                continue
            if not np.isfinite(scale):
                continue
            edges[i, j] = (R, tu * scale)
            support[i, j] = int(inl.sum())
    try:
        R0, t0 = chain_poses(n, edges, support, names=names)
    except ValueError as exc:
        if degenerate:
            worst = max(degenerate.values())
            raise ValueError(f"wand motion is degenerate: seen from camera pairs {sorted(degenerate)} the balls stay close to "
                             f"a plane (thickness / extent <= {worst:.3f} < {opt.planar_ratio}); move the wand through the "
                             f"whole volume, tilting it ({exc})") from None
        raise
    X = triangulate_views(cams, R0, t0, uv[:, fit].reshape(n, -1, 2)).reshape(len(fit), M, 3)
    check_spread(X.reshape(-1, 3), opt.planar_ratio)
    ok = ~np.isnan(X).any(axis=(1, 2))
    fit = fit[ok]
    if len(fit) < 10:
        raise ValueError(f"only {len(fit)} frame sets have every ball seen by two cameras; need >= 10")
    K = np.stack([c.K for c in cams])
    d8 = np.stack([c.dist8 for c in cams])
    res = bundle_adjust(K, d8, R0, t0, uv[:, fit], model, model.params_from_points(X[ok]), opt.bundle)
    for c in range(n):
        n_seen, n_in = int(seen[c, fit].sum()), int(res.inlier[c].sum())
        if n_in < 0.5 * n_seen:
            raise ValueError(f"camera {names[c]}: only {n_in} of its {n_seen} detections fit the solution within "
                             f"{opt.bundle.outlier_px} px; wrong intrinsics, mislabelled balls or too little wand motion")
    lengths, total, hold_err = _holdout(cams, res.R, res.t, uv[:, hold], offsets)
    reproj = {}
    for c in range(n):
        e = res.residual_px[c][res.inlier[c]]
        reproj[names[c]] = {"rms_px": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan"),
                            "median_px": float(np.median(e)) if e.size else float("nan"),
                            "observations": int(e.size), "outliers": int((seen[c, fit] & ~res.inlier[c]).sum()),
                            "holdout_median_px": float(np.nanmedian(hold_err[c])) if np.isfinite(hold_err[c]).any() else float("nan")}
    return WandResult(res.R, res.t, res, fit, hold, reproj, lengths, total, support)


def _wand_scale(xa, xb, R, tu, model) -> tuple[float, float]:
    """Median ratio known / triangulated wand length for a pair's unit-baseline reconstruction,
    and the reconstruction's spread ratio (thinnest / largest principal extent; ~0 = planar)."""
    F, M, _ = xa.shape
    Rs = np.stack([np.eye(3), R])
    ts = np.stack([np.zeros(3), tu])
    xn = np.stack([xa.reshape(-1, 2), xb.reshape(-1, 2)], axis=1)
    X = triangulate_linear(xn, np.concatenate([Rs, ts[:, :, None]], axis=2)).reshape(F, M, 3)
    meas = np.linalg.norm(X[:, -1] - X[:, 0], axis=1)
    ratio = (model.offsets_m[-1] - model.offsets_m[0]) / meas
    ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
    pts = X.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 8 or len(ratio) < 5:
        return float("nan"), 1.0
    sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    return float(np.median(ratio)), float(sv[2] / sv[0])


def _holdout(cams, R, t, uv, offsets):
    n, H, M, _ = uv.shape
    if H == 0:
        return np.zeros((0, M - 1)), np.zeros(0), np.full((n, 1), np.nan)
    X = triangulate_views(cams, R, t, uv.reshape(n, -1, 2))  # (H*M, 3)
    err = np.full((n, H * M), np.nan)
    flat = uv.reshape(n, -1, 2)
    good = ~np.isnan(X).any(axis=1)
    for c, cam in enumerate(cams):
        proj = project_cameras(cam.K[None], cam.dist8[None], R[c][None], t[c][None], np.where(good[:, None], X, 0.0), np.zeros(len(X), int))
        e = np.linalg.norm(proj - flat[c], axis=1)
        e[~good] = np.nan
        err[c] = e
    X = X.reshape(H, M, 3)
    return np.linalg.norm(np.diff(X, axis=1), axis=2), np.linalg.norm(X[:, -1] - X[:, 0], axis=1), err


def apply_world(R: np.ndarray, t: np.ndarray, X_calib: np.ndarray, X_world: np.ndarray):
    """Re-frame poses so points ``X_calib`` (N >= 3, 3) land on their known ``X_world`` (rigid fit, no scale).

    returns (R', t', fit residual (N,) metres)
    """
    Rn, tn, _, resid = reframe_poses(R, t, X_calib, X_world)
    return Rn, tn, resid


def order_wand_points(uv: np.ndarray, offsets_m, *, max_candidates: int = 8, max_ratio_error: float = 0.2,
                      max_line_frac: float = 0.02) -> np.ndarray:
    """Label one camera's unlabelled detections of a wand: (k, 2) pixels -> (M, 2) in wand order, NaN if none fits.

    The balls are sorted along their best-fit image line; of the two directions the one whose
    spacing ratios are closer to the wand's (``offsets_m``) wins (perspective keeps 130:260 far from 260:130).
    With more than M candidates (other things the detector found; at most ``max_candidates``), every
    M-subset is tried and the one that is straightest and best matches the spacing ratios is kept, if
    its points lie within ``max_line_frac`` of its length of a line and its ratios within ``max_ratio_error``.
    """
    offsets = np.asarray(offsets_m, float)
    M = len(offsets)
    uv = np.asarray(uv, float).reshape(-1, 2)
    uv = uv[~np.isnan(uv).any(axis=1)]
    out = np.full((M, 2), np.nan)
    if len(uv) < M or len(uv) > max_candidates:
        return out
    if M == 1:  # a single ball: only an unambiguous detection counts
        return uv if len(uv) == 1 else out
    want = np.diff(offsets) / (offsets[-1] - offsets[0])
    best, best_score = None, np.inf
    for subset in combinations(range(len(uv)), M):
        pts = uv[list(subset)]
        c = pts - pts.mean(axis=0)
        _, sv, vt = np.linalg.svd(c, full_matrices=False)
        s = c @ vt[0]
        order = np.argsort(s)
        gaps = np.diff(s[order])
        length = max(gaps.sum(), 1e-12)
        fwd = gaps / length
        err_f, err_b = np.abs(fwd - want).sum(), np.abs(fwd[::-1] - want).sum()
        if err_b < err_f:
            order, err_f = order[::-1], err_b
        line = sv[1] / np.sqrt(M) / length if M > 2 else 0.0
        if len(uv) > M and (line > max_line_frac or err_f > max_ratio_error):
            continue
        score = err_f + line
        if score < best_score:
            best, best_score = pts[order], score
    return out if best is None else best
