"""numba kernels of the robust estimator: one call does the whole per-frame path.

Undistort every observation, triangulate every pair of observations from different cameras
(Algorithm 2 lines 2-4), reproject each candidate into every camera with distortion and count the
cameras within ``eps_px`` (lines 6-10), keep the largest set (lines 12-14; ties by MSAC cost for
``ours``), triangulate on it, refine by Levenberg-Marquardt in pixels, re-collect inliers and
propagate pixel noise to a covariance. Inputs are trusted (validated in :mod:`tracker.robust`).
:mod:`tracker._robust_reference` is the plain numpy twin the tests compare against.

All numba code of the estimator lives in this one file on purpose: numba's on-disk cache
(``cache=True``) only notices edits to the file of the cached function, not to jitted helpers
imported from other files (numba issue #1833), so a split would serve stale machine code. The one
exception is the lens model, :mod:`tracker.distortion` (one definition for every kernel): after
editing it, delete the ``__pycache__/*.nbi``/``*.nbc`` files of the kernels (``make clean-numba``);
``tests/tracker/test_robust.py`` compares these kernels with the numpy twin, which uses the edited model,
so stale machine code fails the tests rather than going unnoticed.

Packed camera row (``cam[m]``, 25 floats, see :func:`pack_cameras`): fx, skew, cx, fy, cy,
k1, k2, p1, p2, k3, k4, k5, k6, R_world_to_cam (9, row-major), t_world_to_cam_m (3).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tracker.distortion import distort_point, distort_point_jacobian, undistort_point
from checks.numba_cache import key_cache_on_callees

# -- layout of the option vectors, outputs and workspaces ----------------------------------------
F_EPS_PX, F_MIN_DEPTH_M, F_SIGMA_PX, F_TOL_M, F_BOX = 0, 1, 2, 3, 4  # F_BOX..+5: box min xyz, max xyz
N_FOPT = 10
I_PAPER, I_TIE_BREAK, I_CHECK_DEPTH, I_USE_BOX, I_REFINE, I_RECOLLECT, I_MAX_ITER, I_MIN_SUPPORT, I_ROUNDS = range(9)
N_IOPT = 9
O_X, O_COV, O_COST, O_ERR = 0, 3, 12, 13  # fout: X (3), covariance (9), cost, err_px (n)
O_STATUS, O_SUPPORT, O_NOBS, O_NCAND, O_CAND = 0, 1, 2, 3, 4  # iout: ..., candidate index (n)
ST_OK, ST_LOW_SUPPORT, ST_NO_CONSENSUS, ST_TOO_FEW = 0, 1, 2, 3


def fout_size(n_cams: int) -> int:
    return O_ERR + n_cams


def iout_size(n_cams: int) -> int:
    return O_CAND + n_cams


def work_sizes(n_cams: int, k: int) -> tuple[int, int]:
    """(float, int) workspace lengths for n_cams cameras and k candidates per camera."""
    return 2 * n_cams * k + 3 * n_cams + 16, n_cams * k + 4 * n_cams


C_R, C_T = 13, 22  # offsets of R and t in a packed camera row


def pack_cameras(stacked: dict) -> np.ndarray:
    """(n_cams, 25) packed rows from :meth:`tracker.Rig.stacked` arrays."""
    K, d, R, t = stacked["K"], stacked["dist8"], stacked["R"], stacked["t"]
    n = len(K)
    cam = np.empty((n, 25))
    cam[:, 0], cam[:, 1], cam[:, 2], cam[:, 3], cam[:, 4] = K[:, 0, 0], K[:, 0, 1], K[:, 0, 2], K[:, 1, 1], K[:, 1, 2]
    cam[:, 5:13] = d
    cam[:, C_R:C_T] = R.reshape(n, 9)
    cam[:, C_T:] = t
    return cam


# -- camera model ---------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _distort(cam, m, x, y):
    """Distorted normalised coordinates and their 2x2 Jacobian (tracker.distortion) in camera m."""
    return distort_point_jacobian(x, y, cam[m, 5], cam[m, 6], cam[m, 7], cam[m, 8], cam[m, 9], cam[m, 10], cam[m, 11], cam[m, 12])


@njit(cache=True)
def _undistort(cam, m, xd, yd):
    """Newton inversion of the distortion in camera m (tracker.distortion.undistort_point)."""
    return undistort_point(xd, yd, cam[m, 5], cam[m, 6], cam[m, 7], cam[m, 8], cam[m, 9], cam[m, 10], cam[m, 11], cam[m, 12])


@njit(cache=True)
def _to_cam(cam, m, X0, X1, X2):
    r = C_R
    xc = cam[m, r] * X0 + cam[m, r + 1] * X1 + cam[m, r + 2] * X2 + cam[m, C_T]
    yc = cam[m, r + 3] * X0 + cam[m, r + 4] * X1 + cam[m, r + 5] * X2 + cam[m, C_T + 1]
    zc = cam[m, r + 6] * X0 + cam[m, r + 7] * X1 + cam[m, r + 8] * X2 + cam[m, C_T + 2]
    return xc, yc, zc


@njit(cache=True)
def _project(cam, m, X0, X1, X2):
    """(u, v, z): distorted pixel of a world point in camera m and its depth (u, v NaN if z <= 0)."""
    xc, yc, z = _to_cam(cam, m, X0, X1, X2)
    if not z > 0.0:
        return np.nan, np.nan, z
    iz = 1.0 / z
    xd, yd, _, _, _ = _distort(cam, m, xc * iz, yc * iz)
    return cam[m, 0] * xd + cam[m, 1] * yd + cam[m, 2], cam[m, 3] * yd + cam[m, 4], z


@njit(cache=True)
def _project_jac(cam, m, X0, X1, X2):
    """Pixel (u, v), depth z, and d(u, v)/dX_world as six numbers (row 0 then row 1)."""
    xc, yc, z = _to_cam(cam, m, X0, X1, X2)
    if not z > 0.0:
        return np.nan, np.nan, z, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    iz = 1.0 / z
    x, y = xc * iz, yc * iz
    xd, yd, j00, j01, j11 = _distort(cam, m, x, y)
    fx, s, fy = cam[m, 0], cam[m, 1], cam[m, 3]
    a00, a01, a11 = fx * j00 + s * j01, fx * j01 + s * j11, fy * j11  # K2 @ D
    a10 = fy * j01
    # d(x, y)/dXc = [[iz, 0, -x iz], [0, iz, -y iz]];  d uv/dXc = A @ that
    b00, b01, b02 = a00 * iz, a01 * iz, -(a00 * x + a01 * y) * iz
    b10, b11, b12 = a10 * iz, a11 * iz, -(a10 * x + a11 * y) * iz
    r = C_R  # times R_world_to_cam (row-major rows R0, R1, R2)
    R00, R01, R02 = cam[m, r], cam[m, r + 1], cam[m, r + 2]
    R10, R11, R12 = cam[m, r + 3], cam[m, r + 4], cam[m, r + 5]
    R20, R21, R22 = cam[m, r + 6], cam[m, r + 7], cam[m, r + 8]
    j0 = b00 * R00 + b01 * R10 + b02 * R20
    j1 = b00 * R01 + b01 * R11 + b02 * R21
    j2 = b00 * R02 + b01 * R12 + b02 * R22
    j3 = b10 * R00 + b11 * R10 + b12 * R20
    j4 = b10 * R01 + b11 * R11 + b12 * R21
    j5 = b10 * R02 + b11 * R12 + b12 * R22
    u = fx * xd + s * yd + cam[m, 2]
    v = fy * yd + cam[m, 4]
    return u, v, z, j0, j1, j2, j3, j4, j5


# -- small linear algebra -----------------------------------------------------------------------
@njit(cache=True)
def _add_view(h, cam, m, x, y):
    """Accumulate one view's DLT rows into h = [H00, H01, H02, H11, H12, H22, g0, g1, g2]."""
    r, t = C_R, C_T
    a0, a1, a2 = x * cam[m, r + 6] - cam[m, r], x * cam[m, r + 7] - cam[m, r + 1], x * cam[m, r + 8] - cam[m, r + 2]
    b = cam[m, t] - x * cam[m, t + 2]
    c0, c1, c2 = y * cam[m, r + 6] - cam[m, r + 3], y * cam[m, r + 7] - cam[m, r + 4], y * cam[m, r + 8] - cam[m, r + 5]
    d = cam[m, t + 1] - y * cam[m, t + 2]
    h[0] += a0 * a0 + c0 * c0
    h[1] += a0 * a1 + c0 * c1
    h[2] += a0 * a2 + c0 * c2
    h[3] += a1 * a1 + c1 * c1
    h[4] += a1 * a2 + c1 * c2
    h[5] += a2 * a2 + c2 * c2
    h[6] += a0 * b + c0 * d
    h[7] += a1 * b + c1 * d
    h[8] += a2 * b + c2 * d


@njit(cache=True)
def _inv_sym3(h00, h01, h02, h11, h12, h22):
    """Inverse of a symmetric 3x3 (six entries) and a flag; singular if det <= 1e-12 trace^3."""
    c00 = h11 * h22 - h12 * h12
    c01 = h02 * h12 - h01 * h22
    c02 = h01 * h12 - h02 * h11
    det = h00 * c00 + h01 * c01 + h02 * c02
    tr = h00 + h11 + h22
    if not det > 1e-12 * tr * tr * tr:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    c11 = h00 * h22 - h02 * h02
    c12 = h01 * h02 - h00 * h12
    c22 = h00 * h11 - h01 * h01
    return c00 / det, c01 / det, c02 / det, c11 / det, c12 / det, c22 / det, True


@njit(cache=True)
def _solve_h(h):
    i00, i01, i02, i11, i12, i22, ok = _inv_sym3(h[0], h[1], h[2], h[3], h[4], h[5])
    g0, g1, g2 = h[6], h[7], h[8]
    return i00 * g0 + i01 * g1 + i02 * g2, i01 * g0 + i11 * g1 + i12 * g2, i02 * g0 + i12 * g1 + i22 * g2, ok


@njit(cache=True)
def _triangulate_set(cam, xn, K, sel, h):
    """Linear N-view triangulation (the paper's ``stereo``) of the candidates sel[m] >= 0."""
    h[:] = 0.0
    for m in range(sel.shape[0]):
        c = sel[m]
        if c >= 0:
            q = 2 * (m * K + c)
            _add_view(h, cam, m, xn[q], xn[q + 1])
    return _solve_h(h)


@njit(cache=True)
def _normal_eq(cam, uv, sel, X0, X1, X2, h):
    """Gauss-Newton normal equations of the pixel loss over sel; returns the loss (inf if a camera
    of the set is behind the point). h gets [JtJ (6), -Jt r (3)]."""
    h[:] = 0.0
    cost = 0.0
    for m in range(sel.shape[0]):
        c = sel[m]
        if c < 0:
            continue
        u, v, z, j0, j1, j2, j3, j4, j5 = _project_jac(cam, m, X0, X1, X2)
        if not z > 0.0:
            return np.inf
        ru, rv = u - uv[m, c, 0], v - uv[m, c, 1]
        cost += ru * ru + rv * rv
        h[0] += j0 * j0 + j3 * j3
        h[1] += j0 * j1 + j3 * j4
        h[2] += j0 * j2 + j3 * j5
        h[3] += j1 * j1 + j4 * j4
        h[4] += j1 * j2 + j4 * j5
        h[5] += j2 * j2 + j5 * j5
        h[6] -= j0 * ru + j3 * rv
        h[7] -= j1 * ru + j4 * rv
        h[8] -= j2 * ru + j5 * rv
    return cost


@njit(cache=True)
def _loss(cam, uv, sel, X0, X1, X2):
    cost = 0.0
    for m in range(sel.shape[0]):
        c = sel[m]
        if c >= 0:
            u, v, z = _project(cam, m, X0, X1, X2)
            if not z > 0.0:
                return np.inf
            cost += (u - uv[m, c, 0]) ** 2 + (v - uv[m, c, 1]) ** 2
    return cost


@njit(cache=True)
def _refine(cam, uv, sel, X0, X1, X2, max_iter, tol_m, h):
    """Levenberg-Marquardt on the paper's loss L(X) (Sec. 2.2) in distorted pixels."""
    cost = _normal_eq(cam, uv, sel, X0, X1, X2, h)
    if not cost < np.inf:
        return X0, X1, X2
    lam = 1e-3
    for _ in range(max_iter):
        i00, i01, i02, i11, i12, i22, ok = _inv_sym3(
            h[0] * (1 + lam), h[1], h[2], h[3] * (1 + lam), h[4], h[5] * (1 + lam)
        )
        if not ok:
            break
        d0 = i00 * h[6] + i01 * h[7] + i02 * h[8]
        d1 = i01 * h[6] + i11 * h[7] + i12 * h[8]
        d2 = i02 * h[6] + i12 * h[7] + i22 * h[8]
        Y0, Y1, Y2 = X0 + d0, X1 + d1, X2 + d2
        cost_new = _loss(cam, uv, sel, Y0, Y1, Y2)
        if cost_new <= cost:
            X0, X1, X2, lam = Y0, Y1, Y2, lam * 0.1
            cost = _normal_eq(cam, uv, sel, X0, X1, X2, h)
            if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) < tol_m:
                break
        else:
            lam *= 10.0
    return X0, X1, X2


@njit(cache=True)
def _nearest(cam, uv, valid, K, k_use, m, X0, X1, X2):
    """Smallest squared pixel error over camera m's candidates (inf if behind), and its index."""
    u, v, z = _project(cam, m, X0, X1, X2)
    e2best = np.inf
    cbest = -1
    if z > 0.0:
        for c in range(k_use):
            if valid[m * K + c]:
                du, dv = u - uv[m, c, 0], v - uv[m, c, 1]
                e2 = du * du + dv * dv
                if e2 < e2best:
                    e2best, cbest = e2, c
    return e2best, cbest


@njit(cache=True)
def _errors_one_candidate(camT, U, V, X0, X1, X2, e2):
    """Squared pixel error of X in every camera with one observation (U[m], V[m]) each.

    camT : (25, n) packed cameras, transposed so each parameter is contiguous over cameras; the
    loop is branch-free so LLVM vectorises it across cameras. e2[m] = inf behind camera m and NaN
    where U[m] is NaN (no observation).
    """
    for m in range(U.shape[0]):
        xc = camT[13, m] * X0 + camT[14, m] * X1 + camT[15, m] * X2 + camT[22, m]
        yc = camT[16, m] * X0 + camT[17, m] * X1 + camT[18, m] * X2 + camT[23, m]
        zc = camT[19, m] * X0 + camT[20, m] * X1 + camT[21, m] * X2 + camT[24, m]
        iz = 1.0 / zc
        x = xc * iz
        y = yc * iz
        xd, yd = distort_point(
            x, y, camT[5, m], camT[6, m], camT[7, m], camT[8, m], camT[9, m], camT[10, m], camT[11, m], camT[12, m]
        )
        du = camT[0, m] * xd + camT[1, m] * yd + camT[2, m] - U[m]
        dv = camT[3, m] * yd + camT[4, m] - V[m]
        e = du * du + dv * dv
        e2[m] = e if zc > 0.0 else np.inf


@njit(cache=True)
def _score_one(camT, U, V, obs, X0, X1, X2, eps2, e2v, cur):
    """Support and MSAC cost of X with one observation per camera (vectorised over cameras)."""
    _errors_one_candidate(camT, U, V, X0, X1, X2, e2v)
    s, cost = 0, 0.0
    for m in range(obs.shape[0]):
        if obs[m] != 0:
            if e2v[m] < eps2:
                s += 1
                cost += e2v[m]
                cur[m] = 0
            else:
                cost += eps2
                cur[m] = -1
    return s, cost, False


@njit(cache=True)
def _score_nearest(cam, uv, valid, K, k_use, obs, n_obs, X0, X1, X2, eps2, prune, tie, best_s, best_cost, out_sel):
    """Support and MSAC cost (sum over observing cameras of min(err^2, eps^2)) of X, the nearest of each
    camera's first ``k_use`` candidates counting: ``out_sel[m]`` = its index if within eps, else -1 (also for
    a camera without observations). Returns ``(support, cost, pruned)``.

    The one scoring loop of the estimator: Algorithm 2's consensus of a candidate X (``prune``) and the
    re-collection around the refined point (no ``prune``). With ``prune`` it stops early (pruned=True) once X
    can no longer beat the best set so far (``best_s``, ``best_cost``; ``tie``: a lower cost breaks equal
    support): exact, never changes the result."""
    s, cost, remaining = 0, 0.0, n_obs
    for m in range(obs.shape[0]):
        if obs[m] == 0:
            out_sel[m] = -1
            continue
        remaining -= 1
        e2, cb = _nearest(cam, uv, valid, K, k_use, m, X0, X1, X2)
        if e2 < eps2:
            s += 1
            cost += e2
            out_sel[m] = cb
        else:
            cost += eps2
            out_sel[m] = -1
        if prune:
            if tie:
                if s + remaining < best_s or (s + remaining == best_s and cost >= best_cost):
                    return s, cost, True
            elif s + remaining <= best_s:
                return s, cost, True
    return s, cost, False


# -- the estimator ---------------------------------------------------------------------------------
@njit(cache=True)
def estimate_one(uv, cam, camT, fopt, iopt, fw, iw, fout, iout):
    """Robust estimate from uv (n, k, 2) distorted pixels (NaN = none); writes fout, iout.
    cam (n, 25) packed cameras and camT its transpose (25, n)."""
    n, K = uv.shape[0], uv.shape[1]
    paper = iopt[I_PAPER] != 0
    k_use = 1 if paper else K  # the paper's algorithm sees one observation per camera
    tie = iopt[I_TIE_BREAK] != 0 and not paper
    eps2 = fopt[F_EPS_PX] * fopt[F_EPS_PX]
    xn = fw[: 2 * n * K]
    h = fw[2 * n * K : 2 * n * K + 9]
    U = fw[2 * n * K + 16 : 2 * n * K + 16 + n]
    V = fw[2 * n * K + 16 + n : 2 * n * K + 16 + 2 * n]
    e2v = fw[2 * n * K + 16 + 2 * n : 2 * n * K + 16 + 3 * n]
    valid = iw[: n * K]
    obs = iw[n * K : n * K + n]
    cur = iw[n * K + n : n * K + 2 * n]
    best = iw[n * K + 2 * n : n * K + 3 * n]
    tmp = iw[n * K + 3 * n : n * K + 4 * n]
    fout[:] = np.nan
    iout[:] = 0
    for m in range(n):
        iout[O_CAND + m] = -1

    # 1. undistort every observation into normalised coordinates
    n_obs = 0
    for m in range(n):
        obs[m] = 0
        for c in range(K):
            valid[m * K + c] = 0
            u, v = uv[m, c, 0], uv[m, c, 1]
            if c < k_use and u == u and v == v:
                valid[m * K + c] = 1
                obs[m] = 1
                yd = (v - cam[m, 4]) / cam[m, 3]
                xd = (u - cam[m, 2] - cam[m, 1] * yd) / cam[m, 0]
                x, y = _undistort(cam, m, xd, yd)
                xn[2 * (m * K + c)] = x
                xn[2 * (m * K + c) + 1] = y
        n_obs += obs[m]
        U[m], V[m] = uv[m, 0, 0], uv[m, 0, 1]
    iout[O_NOBS] = n_obs
    if n_obs < 2:
        iout[O_STATUS] = ST_TOO_FEW
        return

    # 2. Algorithm 2: a candidate from every pair of observations in different cameras (lines 2-4)
    best_s, best_cost = 1, np.inf
    n_cand = 0
    bx0, by0, bz0 = fopt[F_BOX], fopt[F_BOX + 1], fopt[F_BOX + 2]
    bx1, by1, bz1 = fopt[F_BOX + 3], fopt[F_BOX + 4], fopt[F_BOX + 5]
    min_depth = fopt[F_MIN_DEPTH_M]
    Xb0 = Xb1 = Xb2 = 0.0
    for i in range(n - 1):
        for j in range(i + 1, n):
            for a in range(k_use):
                if valid[i * K + a] == 0:
                    continue
                for b in range(k_use):
                    if valid[j * K + b] == 0:
                        continue
                    h[:] = 0.0
                    _add_view(h, cam, i, xn[2 * (i * K + a)], xn[2 * (i * K + a) + 1])
                    _add_view(h, cam, j, xn[2 * (j * K + b)], xn[2 * (j * K + b) + 1])
                    X0, X1, X2, ok = _solve_h(h)
                    if not ok:
                        continue
                    if iopt[I_CHECK_DEPTH] != 0:  # ours: the ball is in front of both cameras
                        if not (_to_cam(cam, i, X0, X1, X2)[2] > min_depth and _to_cam(cam, j, X0, X1, X2)[2] > min_depth):
                            continue
                    if iopt[I_USE_BOX] != 0:  # ours: inside the (grown) workspace box
                        if not (bx0 <= X0 <= bx1 and by0 <= X1 <= by1 and bz0 <= X2 <= bz1):
                            continue
                    n_cand += 1
                    # lines 5-10: the cameras whose reprojection error is below eps
                    if k_use == 1:
                        s, cost, pruned = _score_one(camT, U, V, obs, X0, X1, X2, eps2, e2v, cur)
                    else:
                        s, cost, pruned = _score_nearest(cam, uv, valid, K, k_use, obs, n_obs, X0, X1, X2, eps2, True, tie,
                                                          best_s, best_cost, cur)
                    if pruned:
                        continue
                    # lines 12-14: keep the largest set; first found wins (paper) or lower cost (ours)
                    if s > best_s or (tie and s == best_s and cost < best_cost):
                        best_s, best_cost = s, cost
                        Xb0, Xb1, Xb2 = X0, X1, X2
                        for m in range(n):
                            best[m] = cur[m] if obs[m] != 0 else -1
    iout[O_NCAND] = n_cand
    if best_s < 2:
        iout[O_STATUS] = ST_NO_CONSENSUS
        return

    # 3. triangulate on the consistent set (the paper's output), then ours: refine and re-collect
    X0, X1, X2, ok = _triangulate_set(cam, xn, K, best, h)
    if not ok:
        X0, X1, X2 = Xb0, Xb1, Xb2
    support = best_s
    if not paper:
        max_iter, tol = iopt[I_MAX_ITER], fopt[F_TOL_M]
        if iopt[I_REFINE] != 0:
            X0, X1, X2 = _refine(cam, uv, best, X0, X1, X2, max_iter, tol, h)
        if iopt[I_RECOLLECT] != 0:
            for _ in range(iopt[I_ROUNDS]):
                s_new, _c, _p = _score_nearest(cam, uv, valid, K, k_use, obs, n_obs, X0, X1, X2, eps2, False, tie,
                                               best_s, best_cost, tmp)
                same = True
                for m in range(n):
                    if tmp[m] != best[m]:
                        same = False
                if same or s_new < 2:
                    break
                for m in range(n):
                    best[m] = tmp[m]
                support = s_new
                if iopt[I_REFINE] != 0:
                    X0, X1, X2 = _refine(cam, uv, best, X0, X1, X2, max_iter, tol, h)
                else:
                    Y0, Y1, Y2, ok = _triangulate_set(cam, xn, K, best, h)
                    if ok:
                        X0, X1, X2 = Y0, Y1, Y2

    # 4. outputs: errors per camera, MSAC cost, covariance sigma^2 (J^T J)^-1 over the set
    fout[0], fout[1], fout[2] = X0, X1, X2
    cost = 0.0
    for m in range(n):
        if obs[m] == 0:
            continue
        c = best[m]
        if c >= 0:
            u, v, z = _project(cam, m, X0, X1, X2)
            e2 = (u - uv[m, c, 0]) ** 2 + (v - uv[m, c, 1]) ** 2
        else:
            e2, _cb = _nearest(cam, uv, valid, K, k_use, m, X0, X1, X2)
        fout[O_ERR + m] = math.sqrt(e2)
        cost += min(e2, eps2) if e2 == e2 else eps2
        iout[O_CAND + m] = c
    fout[O_COST] = cost
    finite = _normal_eq(cam, uv, best, X0, X1, X2, h) < np.inf
    i00, i01, i02, i11, i12, i22, ok = _inv_sym3(h[0], h[1], h[2], h[3], h[4], h[5])
    if finite and ok:
        s2 = fopt[F_SIGMA_PX] * fopt[F_SIGMA_PX]
        cov = (i00, i01, i02, i01, i11, i12, i02, i12, i22)
        for q in range(9):
            fout[O_COV + q] = s2 * cov[q]
    iout[O_SUPPORT] = support
    iout[O_STATUS] = ST_OK if support >= iopt[I_MIN_SUPPORT] else ST_LOW_SUPPORT


@njit(cache=True)
def estimate_batch(uv, cam, camT, fopt, iopt, fw, iw, fout, iout):
    """estimate_one for every frame: uv (n_frames, n, k, 2), fout/iout (n_frames, ...)."""
    for f in range(uv.shape[0]):
        estimate_one(uv[f], cam, camT, fopt, iopt, fw, iw, fout[f], iout[f])


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
