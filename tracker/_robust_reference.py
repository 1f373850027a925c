"""Plain numpy reference of the robust estimator (the twin of :mod:`tracker._robust_kernels`).

Same inputs, options and output layout as the numba kernel, written with whole-array operations:
every pair of observations is triangulated in one batched call, every candidate is projected into
every camera in one call, and the consensus set is picked with array reductions. Slow-ish but easy
to read; the tests require both to agree. Selected with ``RobustTriangulator(backend="numpy")``.
"""

from __future__ import annotations

import numpy as np

from tracker import _robust_kernels as kern
from tracker.triangulation import (
    _camera_arrays,
    _project,
    camera_pairs,
    refine_point,
    triangulate_linear,
    triangulate_pairs,
)


def _undistort_all(uv: np.ndarray, rig) -> np.ndarray:
    """(n, k, 2) pixels -> (n, k, 2) normalised coordinates (NaN stays NaN); one call per camera."""
    return np.stack([cam.undistort(uv[m]) for m, cam in enumerate(rig)])


def _nearest(X: np.ndarray, uv: np.ndarray, valid: np.ndarray, cams: dict):
    """X (M, 3) -> (M, n) smallest squared pixel error over each camera's candidates (inf if none
    or behind) and (M, n) its index."""
    uv_hat, z = _project(X, cams)  # (M, n, 2), (M, n)
    e2 = ((uv_hat[:, :, None, :] - uv[None]) ** 2).sum(-1)  # (M, n, k)
    e2 = np.where(valid[None] & (z[:, :, None] > 0), e2, np.inf)
    e2 = np.where(np.isnan(e2), np.inf, e2)
    return e2.min(axis=2), e2.argmin(axis=2)


def _select(e2: np.ndarray, cb: np.ndarray, obs: np.ndarray, eps2: float):
    """Per candidate: selection (M, n) (-1 = not inlier), support (M,), MSAC cost (M,)."""
    inl = (e2 < eps2) & obs
    sel = np.where(inl, cb, -1)
    cost = np.where(inl, e2, eps2)[:, obs].sum(axis=1)
    return sel, inl.sum(axis=1), cost


def _linear(xn: np.ndarray, sel: np.ndarray, P: np.ndarray) -> np.ndarray:
    n = len(sel)
    pts = np.where((sel >= 0)[:, None], xn[np.arange(n), np.maximum(sel, 0)], np.nan)
    return triangulate_linear(pts, P)


def _pixels(uv: np.ndarray, sel: np.ndarray) -> np.ndarray:
    n = len(sel)
    return np.where((sel >= 0)[:, None], uv[np.arange(n), np.maximum(sel, 0)], np.nan)


def estimate_reference(uv, rig, fopt, iopt, fout, iout) -> None:
    """Same contract as :func:`tracker._robust_kernels.estimate_one` (uv (n, k, 2))."""
    n, K = uv.shape[:2]
    paper = bool(iopt[kern.I_PAPER])
    k_use = 1 if paper else K
    tie = bool(iopt[kern.I_TIE_BREAK]) and not paper
    eps2 = fopt[kern.F_EPS_PX] ** 2
    uv = uv[:, :k_use]
    cams = _camera_arrays(rig)
    P = rig.stacked()["P"]
    fout[:] = np.nan
    iout[:] = 0
    iout[kern.O_CAND :] = -1

    valid = ~np.isnan(uv).any(axis=2)  # (n, k)
    obs = valid.any(axis=1)
    iout[kern.O_NOBS] = obs.sum()
    if obs.sum() < 2:
        iout[kern.O_STATUS] = kern.ST_TOO_FEW
        return
    xn = _undistort_all(uv, rig)

    # all pairs of observations in different cameras, in the order of Algorithm 2's loops
    pairs = camera_pairs(n)
    p, a, b = (g.ravel() for g in np.meshgrid(np.arange(len(pairs)), np.arange(k_use), np.arange(k_use), indexing="ij"))
    i, j = pairs[p, 0], pairs[p, 1]
    keep = valid[i, a] & valid[j, b]
    i, j, a, b = i[keep], j[keep], a[keep], b[keep]
    X = triangulate_pairs(xn[i, a], xn[j, b], P[i], P[j])
    ok = ~np.isnan(X).any(axis=1)
    if iopt[kern.I_CHECK_DEPTH]:
        R, t = cams["R"], cams["t"]
        with np.errstate(invalid="ignore"):
            zi = np.einsum("mk,mk->m", R[i, 2], X) + t[i, 2]
            zj = np.einsum("mk,mk->m", R[j, 2], X) + t[j, 2]
            ok &= (zi > fopt[kern.F_MIN_DEPTH_M]) & (zj > fopt[kern.F_MIN_DEPTH_M])
    if iopt[kern.I_USE_BOX]:
        lo, hi = fopt[kern.F_BOX : kern.F_BOX + 3], fopt[kern.F_BOX + 3 : kern.F_BOX + 6]
        with np.errstate(invalid="ignore"):
            ok &= ((X >= lo) & (X <= hi)).all(axis=1)
    X = X[ok]
    iout[kern.O_NCAND] = len(X)
    if len(X) == 0:
        iout[kern.O_STATUS] = kern.ST_NO_CONSENSUS
        return
    e2, cb = _nearest(X, uv, valid, cams)
    sel, support, cost = _select(e2, cb, obs, eps2)

    # the largest set; ties: first found (paper) or lowest MSAC cost, then first found (ours)
    best_s = support.max()
    if best_s < 2:
        iout[kern.O_STATUS] = kern.ST_NO_CONSENSUS
        return
    top = np.flatnonzero(support == best_s)
    idx = top[np.argmin(cost[top])] if tie else top[0]
    best = sel[idx]

    Xf = _linear(xn, best, P)
    if np.isnan(Xf).any():
        Xf = X[idx]
    s_final = int(best_s)
    if not paper:
        refine = bool(iopt[kern.I_REFINE])
        max_iter, tol = int(iopt[kern.I_MAX_ITER]), fopt[kern.F_TOL_M]
        if refine:
            Xf, _ = refine_point(Xf, _pixels(uv, best), rig, max_iterations=max_iter, tol_m=tol)
        if iopt[kern.I_RECOLLECT]:
            for _ in range(int(iopt[kern.I_ROUNDS])):
                e2n, cbn = _nearest(Xf[None], uv, valid, cams)
                tmp, s_new, _c = _select(e2n, cbn, obs, eps2)
                tmp, s_new = tmp[0], int(s_new[0])
                if (tmp == best).all() or s_new < 2:
                    break
                best, s_final = tmp, s_new
                if refine:
                    Xf, _ = refine_point(Xf, _pixels(uv, best), rig, max_iterations=max_iter, tol_m=tol)
                else:
                    Y = _linear(xn, best, P)
                    if not np.isnan(Y).any():
                        Xf = Y

    uv_hat, _, J = _project(Xf[None], cams, jacobian=True)
    e2_all, cb_all = _nearest(Xf[None], uv, valid, cams)
    used = _pixels(uv, best)
    err2 = np.where(best >= 0, ((uv_hat[0] - used) ** 2).sum(-1), e2_all[0])
    err2 = np.where(obs, err2, np.nan)
    fout[kern.O_X : kern.O_X + 3] = Xf
    fout[kern.O_ERR :] = np.sqrt(err2)
    fout[kern.O_COST] = np.where(np.isnan(err2), eps2, np.minimum(err2, eps2))[obs].sum()
    iout[kern.O_CAND :] = np.where(obs, best, -1)
    Js = J[0][best >= 0].reshape(-1, 3)
    H = Js.T @ Js
    if np.isfinite(H).all() and np.linalg.det(H) > 1e-12 * np.trace(H) ** 3:
        fout[kern.O_COV : kern.O_COV + 9] = (fopt[kern.F_SIGMA_PX] ** 2 * np.linalg.inv(H)).ravel()
    iout[kern.O_SUPPORT] = s_final
    iout[kern.O_STATUS] = kern.ST_OK if s_final >= iopt[kern.I_MIN_SUPPORT] else kern.ST_LOW_SUPPORT
