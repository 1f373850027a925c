"""Multi-view triangulation: linear N-view, batched two-view, and pixel-space refinement.

The linear solvers work on *normalised* (undistorted) image coordinates and the normalised
projections ``P = [R | t]`` of :meth:`tracker.Rig.stacked`; they solve the DLT equations of every
view, ``x P_3 X - P_1 X = 0`` and ``y P_3 X - P_2 X = 0`` (Hartley & Zisserman, sec. 12.2), with
``X = (X_world, 1)``: the inhomogeneous linear least-squares form, through its 3x3 normal equations.
This is the ``stereo`` function of the paper (Sec. 2.2, Algorithm 2 line 4).

:func:`refine_point` then minimises the paper's re-projection loss ``L(X)`` (Sec. 2.2) in
*distorted pixels* with Levenberg-Marquardt and the analytic Jacobian of the full camera model.

All functions are batched numpy; the per-frame hot path lives in :mod:`tracker._robust_kernels`
(numba), and the tests check both agree.
"""

from __future__ import annotations

import numpy as np

from checks.arrays import check_finite
from tracker.distortion import distort_jacobian

__all__ = [
    "camera_pairs",
    "project_points",
    "projection_jacobian",
    "refine_point",
    "reprojection_errors",
    "triangulate",
    "triangulate_linear",
    "triangulate_pairs",
]

#: Normal matrices with ``det(H) <= _DEGENERATE * trace(H)**3`` are treated as singular
#: (parallel rays, a single view): the point is reported as NaN.
_DEGENERATE = 1e-12


def camera_pairs(n_cams: int) -> np.ndarray:
    """(n_pairs, 2) all index pairs ``i < j`` in the order of Algorithm 2's two outer loops."""
    i, j = np.triu_indices(int(n_cams), 1)
    return np.stack([i, j], axis=1)


def _solve_normal(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Batched solve of ``H X = g`` (H (..., 3, 3) symmetric); NaN where H is (nearly) singular."""
    tr = np.trace(H, axis1=-2, axis2=-1)
    det = np.linalg.det(H)
    ok = det > _DEGENERATE * tr**3
    H_safe = np.where(ok[..., None, None], H, np.eye(3))
    X = np.linalg.solve(H_safe, g[..., None])[..., 0]
    X[~ok] = np.nan
    return X


def _dlt_rows(xn: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DLT rows of each view: A (..., n, 2, 3), b (..., n, 2) with ``A X = b``."""
    x, y = xn[..., 0, None], xn[..., 1, None]
    A = np.stack([x * P[..., 2, :3] - P[..., 0, :3], y * P[..., 2, :3] - P[..., 1, :3]], axis=-2)
    b = np.stack([P[..., 0, 3] - xn[..., 0] * P[..., 2, 3], P[..., 1, 3] - xn[..., 1] * P[..., 2, 3]], axis=-1)
    return A, b


def triangulate_linear(xn, P, weights=None) -> np.ndarray:
    """Linear N-view triangulation on normalised coordinates (the paper's ``stereo``).

    xn : (..., n_views, 2) undistorted normalised coordinates; NaN rows are views without a point
    P : (n_views, 3, 4) or (..., n_views, 3, 4) normalised projections ``[R_world_to_cam | t]``
    weights : optional (..., n_views) non-negative weight per view (0 drops the view)
    returns (..., 3) X_world, metres; NaN where fewer than two views or the rays are parallel
    """
    xn = np.asarray(xn, dtype=float)
    P = np.asarray(P, dtype=float)
    if xn.ndim < 2 or xn.shape[-1] != 2:
        raise ValueError(f"xn must have shape (..., n_views, 2), got shape {xn.shape}")
    if P.ndim < 3 or P.shape[-2:] != (3, 4) or P.shape[-3] != xn.shape[-2]:
        raise ValueError(f"P must have shape (..., {xn.shape[-2]}, 3, 4) to match xn {xn.shape}, got shape {P.shape}")
    check_finite(xn, "xn", allow_nan=True)
    check_finite(P, "P")
    w = np.ones(xn.shape[:-1]) if weights is None else np.asarray(weights, dtype=float)
    if weights is not None:
        try:
            w = np.broadcast_to(w, xn.shape[:-1]).copy()
        except ValueError:
            raise ValueError(f"weights must broadcast to {xn.shape[:-1]}, got shape {np.shape(weights)}") from None
        if not np.isfinite(w).all() or (w < 0).any():
            raise ValueError("weights must be finite and non-negative")
    valid = ~np.isnan(xn).any(axis=-1) & (w > 0)
    w = np.where(valid, w, 0.0)
    A, b = _dlt_rows(np.where(valid[..., None], xn, 0.0), P)
    Aw = A * w[..., None, None]
    H = np.einsum("...nri,...nrj->...ij", Aw, A)  # sum over views and rows
    g = np.einsum("...nri,...nr->...i", Aw, b)
    X = _solve_normal(H, g)
    X[valid.sum(axis=-1) < 2] = np.nan
    return X


def triangulate_pairs(xn_a, xn_b, P_a, P_b) -> np.ndarray:
    """Batched two-view triangulation: one point per pair of views.

    xn_a, xn_b : (M, 2) normalised coordinates in the first and second view
    P_a, P_b : (M, 3, 4) or (3, 4) their normalised projections (broadcast)
    returns (M, 3) X_world; NaN for parallel rays or NaN input
    """
    xn = np.stack(np.broadcast_arrays(np.asarray(xn_a, float), np.asarray(xn_b, float)), axis=-2)
    Pa, Pb = np.broadcast_arrays(np.asarray(P_a, float), np.asarray(P_b, float))
    P = np.stack([Pa, Pb], axis=-3)
    if P.ndim == 3:
        P = np.broadcast_to(P, xn.shape[:-2] + (2, 3, 4))
    return triangulate_linear(xn, P)


# -- the full camera model, batched over points and cameras -------------------------------------
def _camera_arrays(rig) -> dict:
    s = rig.stacked()
    return {"K": s["K"], "dist8": s["dist8"], "R": s["R"], "t": s["t"]}


def _project(X_world: np.ndarray, cams: dict, jacobian: bool = False):
    """X_world (M, 3) -> uv (M, n, 2) distorted pixels (NaN at/behind a camera), depth (M, n),
    and optionally J (M, n, 2, 3) = d uv / d X_world."""
    K, R, t = cams["K"], cams["R"], cams["t"]
    Xc = np.einsum("nij,mj->mni", R, X_world) + t  # (M, n, 3)
    z = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = np.where(z > 0, 1.0 / z, np.nan)
    xn = Xc[..., :2] * iz[..., None]
    xd, Jd = distort_jacobian(xn, cams["dist8"], jacobian=jacobian)
    fx, s, cx, fy, cy = K[:, 0, 0], K[:, 0, 1], K[:, 0, 2], K[:, 1, 1], K[:, 1, 2]
    uv = np.stack([fx * xd[..., 0] + s * xd[..., 1] + cx, fy * xd[..., 1] + cy], axis=-1)
    if not jacobian:
        return uv, z
    Kd = K[:, :2, :2] @ Jd  # (M, n, 2, 2) d uv / d xn
    dxn = np.zeros(xn.shape[:-1] + (2, 3))  # d xn / d Xc
    dxn[..., 0, 0] = iz
    dxn[..., 1, 1] = iz
    dxn[..., :, 2] = -xn * iz[..., None]
    J = Kd @ dxn @ R  # (M, n, 2, 3)
    return uv, z, J


def project_points(X_world, rig) -> np.ndarray:
    """(M, 3) world points -> (M, n_cams, 2) distorted pixels in every rig camera (NaN behind)."""
    X = np.atleast_2d(np.asarray(X_world, dtype=float))
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"X_world must have shape (M, 3) or (3,), got shape {np.shape(X_world)}")
    return _project(X, _camera_arrays(rig))[0]


def projection_jacobian(X_world, rig) -> np.ndarray:
    """(3,) world point -> (n_cams, 2, 3) derivative of its distorted pixels w.r.t. X_world."""
    X = np.asarray(X_world, dtype=float).reshape(1, 3)
    return _project(X, _camera_arrays(rig), jacobian=True)[2][0]


def reprojection_errors(X_world, uv, rig) -> np.ndarray:
    """(3,) point, (n_cams, 2) distorted pixels -> (n_cams,) pixel distances (NaN where uv is NaN)."""
    uv_hat = project_points(X_world, rig)[0]
    return np.linalg.norm(uv_hat - np.asarray(uv, dtype=float), axis=-1)


def refine_point(X0_world, uv, rig, mask=None, *, max_iterations: int = 10, tol_m: float = 1e-10):
    """Levenberg-Marquardt on the pixel re-projection error ``sum_k |x_k - project(X, P_k)|^2``.

    X0_world : (3,) starting point, metres
    uv : (n_cams, 2) distorted pixels (NaN where a camera has none)
    mask : optional (n_cams,) bool, cameras to use (default: all with a pixel)
    returns (X_world (3,), cost_px2) with cost the final sum of squared pixel errors
    """
    X = np.asarray(X0_world, dtype=float).copy()
    uv = np.asarray(uv, dtype=float)
    use = ~np.isnan(uv).any(axis=1)
    if mask is not None:
        use &= np.asarray(mask, bool)
    cams = {k: v[use] for k, v in _camera_arrays(rig).items()}
    obs = uv[use]

    def residual(Xw, jac=False):
        out = _project(Xw[None], cams, jacobian=jac)
        r = (out[0][0] - obs).ravel()
        return (r, out[2][0].reshape(-1, 3)) if jac else r

    r, J = residual(X, True)
    cost = float(r @ r)
    if not np.isfinite(cost):  # a camera of the set sees the point from behind: keep X0
        return X, cost
    lam = 1e-3
    for _ in range(max_iterations):
        H, g = J.T @ J, J.T @ r
        step = _solve_normal(H + lam * np.diag(np.diag(H)), -g)
        if np.isnan(step).any():
            break
        X_new = X + step
        r_new = residual(X_new)
        cost_new = float(r_new @ r_new)
        if np.isfinite(cost_new) and cost_new <= cost:
            X, cost, lam = X_new, cost_new, lam * 0.1
            r, J = residual(X, True)
            if np.linalg.norm(step) < tol_m:
                break
        else:
            lam *= 10.0
    return X, cost


def triangulate(rig, uv):
    """Non-robust triangulation from every camera with a pixel: linear, then refined in pixels.

    uv : (n_cams, 2) distorted pixels, NaN where a camera saw nothing
    returns (X_world (3,), reproj_error_px (n_cams,)); X is NaN if fewer than two cameras
    """
    uv = np.asarray(uv, dtype=float)
    if uv.shape != (len(rig), 2):
        raise ValueError(f"uv must have shape ({len(rig)}, 2) for this rig, got shape {uv.shape}")
    check_finite(uv, "uv", allow_nan=True)
    xn = np.full_like(uv, np.nan)
    seen = ~np.isnan(uv).any(axis=1)
    for i in np.flatnonzero(seen):  # one call per camera, not per pair
        xn[i] = rig[i].undistort(uv[i])
    X = triangulate_linear(xn, rig.stacked()["P"])
    if np.isnan(X).any():
        return X, np.full(len(rig), np.nan)
    X, _ = refine_point(X, uv, rig)
    return X, reprojection_errors(X, uv, rig)
