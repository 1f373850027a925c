"""Camera poses from a ChArUco board seen by several cameras at once.

``calibrate_board_rig(cameras, views, spec)``:

1. per camera and frame set, the board's pose by PnP (``cv2.solvePnP``, views with >= ``min_corners``);
2. per camera pair, the relative pose from every frame set both saw the board in (chordal rotation
   mean after dropping poses far from it, median translation);
3. camera poses along the maximum spanning tree of shared frame sets (camera 0 is the world frame);
4. :func:`bundle_adjust` of all camera poses and all board poses over the board corners (robust loss);
5. on held-out frame sets: corners triangulated from >= 2 cameras *without* the board model, and the
   distance of neighbouring corners compared with the square size (an independent scale check).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tracker.calibration.board import BoardSpec
from tracker.calibration.bundle import BoardModel, BundleOptions, BundleResult, bundle_adjust
from tracker.calibration.extrinsics import triangulate_views
from tracker.calibration.poses import chain_poses, mean_rotation, rotation_angle_deg, rvec_to_R

__all__ = ["BoardRigOptions", "BoardRigResult", "calibrate_board_rig"]


@dataclass(frozen=True)
class BoardRigOptions:
    """min_corners : corners for a view's PnP pose; max_pnp_px : views whose PnP RMS exceeds this are skipped
    min_shared : frame sets a camera pair needs in common; holdout_every : every n-th frame set held out"""

    min_corners: int = 6
    max_pnp_px: float = 3.0
    min_shared: int = 3
    holdout_every: int = 5
    bundle: BundleOptions = BundleOptions(f_scale_px=1.0, outlier_px=4.0)


@dataclass(frozen=True)
class BoardRigResult:
    """R (n, 3, 3), t (n, 3) world -> camera; bundle : :class:`BundleResult` on the fitted frame sets
    reproj_px : camera -> {rms_px, median_px, observations}; square_m : (K,) neighbouring-corner
    distances triangulated in held-out frame sets; shared : (i, j) -> frame sets both cameras posed"""

    R: np.ndarray
    t: np.ndarray
    bundle: BundleResult
    fit_frames: np.ndarray
    holdout_frames: np.ndarray
    reproj_px: dict
    square_m: np.ndarray
    shared: dict


def _pnp(view, spec, cam, opt):
    if len(view) < opt.min_corners:
        return None
    obj = spec.corners_board_m[view.ids]
    ok, r, t = cv2.solvePnP(obj, view.uv, cam.K, cam.dist8, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    proj = cv2.projectPoints(obj, r, t, cam.K, cam.dist8)[0].reshape(-1, 2)
    if np.sqrt(np.mean(np.sum((proj - view.uv) ** 2, axis=1))) > opt.max_pnp_px:
        return None
    return rvec_to_R(r.ravel()), t.ravel()


def calibrate_board_rig(cameras, views, spec: BoardSpec, options: BoardRigOptions | None = None) -> BoardRigResult:
    """Poses of ``cameras`` (intrinsics used) from ``views[c][f]``: :class:`CharucoCorners` of camera c in frame set f."""
    opt = options or BoardRigOptions()
    cams = list(cameras)
    names = [c.name for c in cams]
    n = len(cams)
    if n < 2 or len(views) != n:
        raise ValueError(f"board extrinsics need >= 2 cameras and one view list per camera; got {n} cameras, {len(views)} lists")
    F = len(views[0])
    if any(len(v) != F for v in views):
        raise ValueError(f"every camera needs the same number of frame sets, got {[len(v) for v in views]} for {names}")
    poses = [[_pnp(views[c][f], spec, cams[c], opt) for f in range(F)] for c in range(n)]
    frames = np.arange(F)
    hold = frames[(frames % opt.holdout_every) == opt.holdout_every - 1] if opt.holdout_every > 1 else frames[:0]
    fit = np.setdiff1d(frames, hold)
    for c in range(n):
        k = sum(poses[c][f] is not None for f in fit)
        if k == 0:
            raise ValueError(f"camera {names[c]}: the board is posed in none of the {len(fit)} fitted frame sets "
                             f"(needs >= {opt.min_corners} corners); check the board spec and that this camera sees it")
    edges, support = {}, {}
    for i in range(n):
        for j in range(i + 1, n):
            both = [f for f in fit if poses[i][f] is not None and poses[j][f] is not None]
            if len(both) < opt.min_shared:
                continue
            Rs = np.stack([poses[j][f][0] @ poses[i][f][0].T for f in both])
            ts = np.stack([poses[j][f][1] - Rs[k] @ poses[i][f][1] for k, f in enumerate(both)])
            Rm = mean_rotation(Rs)
            dev = rotation_angle_deg(Rs, np.broadcast_to(Rm, Rs.shape))
            keep = dev <= max(3 * np.median(dev), 1.0)
            edges[i, j] = (mean_rotation(Rs[keep]), np.median(ts[keep], axis=0))
            support[i, j] = int(keep.sum())
    R0, t0 = chain_poses(n, edges, support, names=names)
    M = spec.n_corners
    uv = np.full((n, F, M, 2), np.nan)
    for c in range(n):
        for f in range(F):
            v = views[c][f]
            if len(v):
                uv[c, f, v.ids] = v.uv
    # initial board pose per fitted frame set: from the camera with the most corners
    p0 = np.full((F, 6), np.nan)
    for f in fit:
        best = max(range(n), key=lambda c: len(views[c][f]) if poses[c][f] is not None else -1)
        if poses[best][f] is None:
            continue
        Rb, tb = poses[best][f]
        p0[f] = BoardModel.params_from_pose((R0[best].T @ Rb)[None], (R0[best].T @ (tb - t0[best]))[None])[0]
    fit = np.array([f for f in fit if np.isfinite(p0[f]).all()])
    model = BoardModel(spec.corners_board_m)
    K = np.stack([c.K for c in cams])
    d8 = np.stack([c.dist8 for c in cams])
    res = bundle_adjust(K, d8, R0, t0, uv[:, fit], model, p0[fit], opt.bundle)
    reproj = {}
    for c in range(n):
        e = res.residual_px[c][res.inlier[c]]
        reproj[names[c]] = {"rms_px": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan"),
                            "median_px": float(np.median(e)) if e.size else float("nan"), "observations": int(e.size)}
    square = _square_sizes(cams, res.R, res.t, uv[:, hold], spec)
    return BoardRigResult(res.R, res.t, res, fit, hold, reproj, square, support)


def _square_sizes(cams, R, t, uv, spec) -> np.ndarray:
    """Distances of horizontally / vertically neighbouring corners triangulated independently (>= 2 cameras)."""
    n, H, M, _ = uv.shape
    if H == 0:
        return np.zeros(0)
    X = triangulate_views(cams, R, t, uv.reshape(n, -1, 2)).reshape(H, M, 3)
    nx, ny = spec.columns - 1, spec.rows - 1
    g = X.reshape(H, ny, nx, 3)
    d = np.concatenate([np.linalg.norm(np.diff(g, axis=2), axis=-1).ravel(), np.linalg.norm(np.diff(g, axis=1), axis=-1).ravel()])
    return d[np.isfinite(d)]
