"""Sparse bundle adjustment of camera poses and a rigid object seen in many frame sets.

The object (a wand of collinear balls at known spacings, a ChArUco board, or a single ball) has a
few parameters per frame (:class:`WandModel`: 5, :class:`BoardModel`: 6, :class:`PointModel`: 3);
its known geometry is a hard constraint, built into the parametrisation (the wand's balls are
``X0 + s_k u(theta, phi)``: known lengths, exactly collinear). Intrinsics stay fixed. The
residuals are distorted-pixel reprojection errors; ``scipy.optimize.least_squares`` solves with a
robust loss and the block-sparse Jacobian pattern (``jac_sparsity``: an observation depends on its
camera's 6 pose parameters and its frame's object parameters only). Camera ``fixed`` (default 0)
holds the gauge: its pose is not optimised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix

from tracker.calibration.poses import R_to_rvec, rvec_to_R
from tracker.distortion import distort

__all__ = ["BoardModel", "BundleOptions", "BundleResult", "PointModel", "WandModel", "bundle_adjust", "project_cameras"]


class WandModel:
    """Collinear balls at positions ``offsets_m`` (M,) along the wand (first 0): params (x, y, z, theta, phi)."""

    n_params = 5

    def __init__(self, offsets_m):
        self.offsets_m = np.asarray(offsets_m, float)

    @property
    def n_points(self) -> int:
        return len(self.offsets_m)

    def points(self, p: np.ndarray) -> np.ndarray:
        """(F, 5) -> (F, M, 3) world points."""
        th, ph = p[:, 3], p[:, 4]
        u = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
        return p[:, None, :3] + self.offsets_m[None, :, None] * u[:, None, :]

    def params_from_points(self, X: np.ndarray) -> np.ndarray:
        """(F, M, 3) triangulated balls -> (F, 5): first ball and the direction to the last."""
        d = X[:, -1] - X[:, 0]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.column_stack([X[:, 0], np.arccos(np.clip(d[:, 2], -1, 1)), np.arctan2(d[:, 1], d[:, 0])])


class BoardModel:
    """Planar board corners ``corners_m`` (M, 3) in the board frame: params (rvec, t) board -> world."""

    n_params = 6

    def __init__(self, corners_m):
        self.corners_m = np.asarray(corners_m, float)

    @property
    def n_points(self) -> int:
        return len(self.corners_m)

    def points(self, p: np.ndarray) -> np.ndarray:
        R = rvec_to_R(p[:, :3])
        return np.einsum("fij,mj->fmi", R, self.corners_m) + p[:, None, 3:]

    @staticmethod
    def params_from_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
        return np.column_stack([R_to_rvec(R), t])


class PointModel:
    """One point per frame (a single ball): params (x, y, z)."""

    n_params = 3
    n_points = 1

    def points(self, p: np.ndarray) -> np.ndarray:
        return p[:, None, :]

    def params_from_points(self, X: np.ndarray) -> np.ndarray:
        return X[:, 0].copy()


@dataclass(frozen=True)
class BundleOptions:
    """loss : scipy robust loss (``soft_l1``, ``huber``, ``cauchy``, ``linear``); f_scale_px : its inlier scale
    max_nfev : evaluation budget; outlier_px : after a first solve, observations above this error are
    dropped and the problem solved again (0: keep all)."""

    loss: str = "soft_l1"
    f_scale_px: float = 1.0
    max_nfev: int = 100
    outlier_px: float = 6.0

    def __post_init__(self):
        valid = ("linear", "soft_l1", "huber", "cauchy", "arctan")
        if self.loss not in valid:
            raise ValueError(f"unknown loss {self.loss!r}; valid: {list(valid)}")
        if not self.f_scale_px > 0 or self.outlier_px < 0:
            raise ValueError(f"f_scale_px must be > 0 and outlier_px >= 0, got {self.f_scale_px}, {self.outlier_px}")


@dataclass(frozen=True)
class BundleResult:
    """R (n, 3, 3), t (n, 3) world -> camera; params (F, p) object per frame; points (F, M, 3) world
    residual_px (n, F, M) reprojection error, NaN where not observed; inlier (n, F, M) kept observations
    cost_initial / cost_final : robust cost; nfev : evaluations"""

    R: np.ndarray
    t: np.ndarray
    params: np.ndarray
    points: np.ndarray
    residual_px: np.ndarray
    inlier: np.ndarray
    cost_initial: float
    cost_final: float
    nfev: int


def project_cameras(K, dist8, R, t, X, cam_idx) -> np.ndarray:
    """Distorted pixels of points ``X`` (N, 3) in cameras ``cam_idx`` (N,); K (n, 3, 3), dist8 (n, 8), R, t world->cam."""
    Xc = np.einsum("nij,nj->ni", R[cam_idx], X) + t[cam_idx]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = Xc[:, :2] / Xc[:, 2:3]
    out = np.empty_like(xn)
    for c in np.unique(cam_idx):
        m = cam_idx == c
        xd = distort(xn[m], dist8[c])
        k = K[c]
        out[m, 0] = k[0, 0] * xd[:, 0] + k[0, 1] * xd[:, 1] + k[0, 2]
        out[m, 1] = k[1, 1] * xd[:, 1] + k[1, 2]
    return out


def bundle_adjust(K, dist8, R0, t0, uv, model, params0, options: BundleOptions | None = None, *, fixed: int = 0) -> BundleResult:
    """Refine camera poses and per-frame object parameters.

    K : (n, 3, 3), dist8 : (n, 8) fixed intrinsics
    R0 : (n, 3, 3), t0 : (n, 3) initial world -> camera poses (metres)
    uv : (n, F, M, 2) distorted pixel observations, NaN where not seen
    model : :class:`WandModel`, :class:`BoardModel` or :class:`PointModel`; params0 : (F, model.n_params)
    """
    opt = options or BundleOptions()
    n, F, M, _ = uv.shape
    seen = ~np.isnan(uv).any(axis=-1)
    res = _solve(K, dist8, R0, t0, uv, seen, model, params0, opt, fixed)
    if opt.outlier_px > 0:
        err = _errors(K, dist8, res[0], res[1], uv, model, res[2])
        keep = seen & ~(err > opt.outlier_px)
        if (keep != seen).any():
            res = _solve(K, dist8, res[0], res[1], uv, keep, model, res[2], opt, fixed, cost0=res[3])
            seen = keep
    R, t, params, c0, c1, nfev = res
    err = _errors(K, dist8, R, t, uv, model, params)
    return BundleResult(R, t, params, model.points(params), err, seen, c0, c1, nfev)


def _errors(K, dist8, R, t, uv, model, params) -> np.ndarray:
    n, F, M, _ = uv.shape
    X = model.points(params)  # (F, M, 3)
    cam = np.repeat(np.arange(n), F * M)
    pts = np.tile(X.reshape(-1, 3), (n, 1))
    proj = project_cameras(K, dist8, R, t, pts, cam).reshape(n, F, M, 2)
    return np.linalg.norm(proj - uv, axis=-1)


def _solve(K, dist8, R0, t0, uv, seen, model, params0, opt, fixed, cost0=None):
    n, F, M, _ = uv.shape
    free = [c for c in range(n) if c != fixed]
    p = model.n_params
    cam_i, frame_i, point_i = np.nonzero(seen)
    obs = uv[cam_i, frame_i, point_i]
    n_cam_par = 6 * len(free)
    x0 = np.concatenate([np.column_stack([R_to_rvec(R0[free]), t0[free]]).ravel(), params0.ravel()])
    slot = np.full(n, -1)
    slot[free] = np.arange(len(free))

    def unpack(x):
        cp = x[:n_cam_par].reshape(-1, 6)
        R = R0.copy()
        t = t0.copy()
        R[free] = rvec_to_R(cp[:, :3])
        t[free] = cp[:, 3:]
        return R, t, x[n_cam_par:].reshape(F, p)

    def fun(x):
        R, t, prm = unpack(x)
        X = model.points(prm)[frame_i, point_i]
        return (project_cameras(K, dist8, R, t, X, cam_i) - obs).ravel()

    # Jacobian pattern: rows 2k, 2k+1 (observation k) depend on its camera's 6 and its frame's p columns
    rows, cols = [], []
    k = np.arange(len(cam_i))
    has_cam = slot[cam_i] >= 0
    for r in (0, 1):
        for j in range(6):
            rows.append(2 * k[has_cam] + r)
            cols.append(6 * slot[cam_i[has_cam]] + j)
        for j in range(p):
            rows.append(2 * k + r)
            cols.append(n_cam_par + p * frame_i + j)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    sparsity = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(2 * len(k), len(x0))).tocsr()
    sol = least_squares(fun, x0, jac_sparsity=sparsity, loss=opt.loss, f_scale=opt.f_scale_px, max_nfev=opt.max_nfev,
                        x_scale="jac", method="trf", tr_solver="lsmr")
    R, t, prm = unpack(sol.x)
    c0 = cost0 if cost0 is not None else float(_robust_cost(fun(x0), opt))
    return R, t, prm, c0, float(sol.cost), int(sol.nfev)


def _robust_cost(r: np.ndarray, opt: BundleOptions) -> float:
    z = (r / opt.f_scale_px) ** 2
    rho = {"linear": z, "soft_l1": 2 * (np.sqrt(1 + z) - 1), "huber": np.where(z <= 1, z, 2 * np.sqrt(z) - 1),
           "cauchy": np.log1p(z), "arctan": np.arctan(z)}[opt.loss]
    return 0.5 * opt.f_scale_px ** 2 * float(np.sum(rho))
