"""Plain-numpy twin of :func:`harness.sim.render._kernels.draw_numba` (same table, same maths).

Vectorised over each primitive's pixel window instead of looping over pixels. Slower (numpy
call overhead per primitive), kept as the readable reference the numba kernel is tested against
(``tests/harness/sim/test_render_kernels.py``) and as the ``method="numpy"`` fallback of the renderer.
"""

from __future__ import annotations

import numpy as np

from harness.sim.render.primitives import (
    BALL,
    CAPSULE,
    DISK,
    NEAR_M,
    SHININESS,
    blur_samples,
)
from tracker.distortion import distort

__all__ = ["draw_numpy"]


def _project(K, d8, P):
    """(m, 3) camera-frame points -> (m, 2) distorted pixels."""
    xd = distort(P[:, :2] / P[:, 2:3], d8)
    return np.stack([K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2], K[1, 1] * xd[:, 1] + K[1, 2]], axis=1)


def _window(K, d8, pts, margin_m, W, H):
    front = pts[:, 2] > NEAR_M
    if not front.any():
        return None
    if not front.all():
        return 0, W - 1, 0, H - 1
    uv = _project(K, d8, pts)
    m = 1.3 * margin_m * max(K[0, 0], K[1, 1]) / pts[:, 2].min() + 2.0
    u0, u1 = max(int(np.floor(uv[:, 0].min() - m)), 0), min(int(np.ceil(uv[:, 0].max() + m)), W - 1)
    v0, v1 = max(int(np.floor(uv[:, 1].min() - m)), 0), min(int(np.ceil(uv[:, 1].max() + m)), H - 1)
    if u1 < u0 or v1 < v0:
        return None
    return u0, u1, v0, v1


def _shade(N, U, rgb, spec, L):
    """N, U : (..., 3) normals and unit rays -> (..., 3) radiance."""
    ndl = np.maximum(N @ L[:3], 0.0)
    Hv = L[:3] - U
    hn = np.linalg.norm(Hv, axis=-1)
    ndh = np.where(hn > 0, np.maximum(np.einsum("...k,...k->...", N, Hv) / np.where(hn > 0, hn, 1), 0.0), 0.0)
    s = L[5] * spec * ndh**SHININESS
    return np.asarray(rgb) * (L[3] + L[4] * ndl)[..., None] + s[..., None]


def _veil(rad, t, win, veil_a, veil_t, veil_rgb):
    behind = t > veil_t[win]
    a = np.where(behind, veil_a[win], 0.0)[..., None]
    return rad * (1 - a) + veil_rgb * a


def _put(frame, zbuf, win, cov, t, rad, veil_a, veil_t, veil_rgb, scale, vig):
    rad = _veil(rad, t, win, veil_a, veil_t, veil_rgb)
    ok = (cov > 0) & (t < zbuf[win])
    dn = np.minimum(rad * (scale * vig[win])[..., None], 255.0)
    old = frame[win].astype(float)
    val = cov[..., None] * dn + (1 - cov[..., None]) * old
    new = np.minimum(np.floor(val + 0.5), 255).astype(np.uint8)
    frame[win] = np.where(ok[..., None], new, frame[win])
    zbuf[win] = np.where(ok & (cov >= 0.5), t, zbuf[win]).astype(np.float32)


def _ball_sample(U, C, R, ppr):
    dotp = U @ C
    cross = np.linalg.norm(np.cross(U, C), axis=-1)
    alpha = np.arcsin(min(R / np.linalg.norm(C), 1.0))
    theta = np.arctan2(cross, dotp)
    cov = np.clip(0.5 + (alpha - theta) * ppr, 0.0, 1.0)
    th = dotp - np.sqrt(np.maximum(R * R - cross * cross, 0.0))
    N = th[..., None] * U - C
    nn = np.linalg.norm(N, axis=-1, keepdims=True)
    N = np.where(nn > 0, N / np.where(nn > 0, nn, 1), -U)
    return cov, th, N


def draw_numpy(frame, zbuf, rays, ppr, veil_a, veil_t, veil_rgb, vig, K, d8, R_wc, t_wc, prims, L_cam, scale, gt):
    """Same contract as :func:`harness.sim.render._kernels.draw_numba`."""
    H, W = zbuf.shape
    for row in prims:
        kind = int(row[0])
        a = R_wc @ row[1:4] + t_wc
        R = row[7]
        rgb, spec = row[8:11], row[14]
        if kind in (CAPSULE, BALL):
            b = R_wc @ row[4:7] + t_wc
            n_s = 9 if kind == CAPSULE else 3
            pts = a + (b - a) * (np.arange(n_s) / (n_s - 1))[:, None]
            box = _window(K, d8, pts, R, W, H)
        elif kind == DISK:
            n = R_wc @ row[4:7]
            e1 = np.cross(n, [1.0, 0.0, 0.0])
            if e1 @ e1 < 1e-6:
                e1 = np.cross(n, [0.0, 1.0, 0.0])
            e1 = e1 / np.sqrt(e1 @ e1)
            e2 = np.cross(n, e1)
            phi = 2 * np.pi * np.arange(16) / 16
            pts = a + R * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
            box = _window(K, d8, pts, 0.0, W, H)
        else:
            Rc = R_wc @ row[15:24].reshape(3, 3)
            h = row[4:7]
            signs = np.array([[1.0 if i & 1 else -1.0, 1.0 if i & 2 else -1.0, 1.0 if i & 4 else -1.0] for i in range(8)])
            pts = a + (signs * h) @ Rc.T
            box = _window(K, d8, pts, 0.0, W, H)
        if box is None:
            continue
        u0, u1, v0, v1 = box
        win = (slice(v0, v1 + 1), slice(u0, u1 + 1))
        U = rays[win].astype(float)
        pp = ppr[win].astype(float)
        if kind == BALL:
            d = b - a
            ends = [_project(K, d8, p[None])[0] if p[2] > NEAR_M else np.zeros(2) for p in (a, b)]
            n_t = blur_samples(float(np.hypot(*(ends[1] - ends[0]))))
            z = zbuf[win].astype(float)
            acc = np.zeros(U.shape)
            acc_a = np.zeros(U.shape[:2])
            t_min = np.full(U.shape[:2], 1e30)
            dn_scale = (scale * vig[win])[..., None]
            for k in range(n_t):
                cov, th, N = _ball_sample(U, a + (k + 0.5) / n_t * d, R, pp)
                ok = (cov > 0) & (th < z)
                rad = _veil(_shade(N, U, rgb, spec, L_cam), th, win, veil_a, veil_t, veil_rgb)
                w = np.where(ok, cov, 0.0)
                acc += w[..., None] * np.minimum(rad * dn_scale, 255.0)
                acc_a += w
                t_min = np.where(ok, np.minimum(t_min, th), t_min)
            cov, th, _ = _ball_sample(U, (a + b) / 2, R, pp)
            vis = np.where((cov > 0) & (th < z), cov, 0.0)
            vis = np.where(th > veil_t[win], vis * (1 - veil_a[win]), vis)
            gt[int(row[24])] += vis.sum()
            al = acc_a / n_t
            val = acc / n_t + (1 - al[..., None]) * frame[win].astype(float)
            new = np.minimum(np.floor(val + 0.5), 255).astype(np.uint8)
            frame[win] = np.where((acc_a > 0)[..., None], new, frame[win])
            zbuf[win] = np.where((acc_a > 0) & (al >= 0.5), t_min, z).astype(np.float32)
        elif kind == CAPSULE:
            d = b - a
            c = d @ d
            bd, e, fa = U @ d, U @ a, d @ a
            if c > 1e-12:
                den = c - bd * bd
                s = np.where(den > 1e-12, (bd * e - fa) / np.where(den > 1e-12, den, 1.0), 0.0)
                s = np.clip(s, 0.0, 1.0)
            else:
                s = np.zeros(bd.shape)
            t = e + s * bd
            Q = a + s[..., None] * d
            dist = np.linalg.norm(t[..., None] * U - Q, axis=-1)
            tt = np.where(t > NEAR_M, t, 1.0)
            cov = np.where(t > NEAR_M, np.clip(0.5 + (R - dist) / tt * pp, 0.0, 1.0), 0.0)
            th = t - np.sqrt(np.maximum(R * R - dist * dist, 0.0))
            Hp = th[..., None] * U
            sh = np.clip(((Hp - a) @ d) / c, 0.0, 1.0) if c > 1e-12 else np.zeros(th.shape)
            N = Hp - a - sh[..., None] * d
            nn = np.linalg.norm(N, axis=-1, keepdims=True)
            N = np.where(nn > 0, N / np.where(nn > 0, nn, 1), -U)
            _put(frame, zbuf, win, cov, th, _shade(N, U, rgb, spec, L_cam), veil_a, veil_t, veil_rgb, scale, vig)
        elif kind == DISK:
            den = U @ n
            ok = np.abs(den) >= 1e-9
            t = np.where(ok, (a @ n) / np.where(ok, den, 1.0), 0.0)
            ok &= t > NEAR_M
            tt = np.where(ok, t, 1.0)
            rho = np.linalg.norm(tt[..., None] * U - a, axis=-1)
            cov = np.where(ok, np.clip(0.5 + (R - rho) / tt * pp, 0.0, 1.0), 0.0)
            front = (den < 0)[..., None]
            rad = np.where(front, _shade(np.broadcast_to(n, U.shape), U, rgb, spec, L_cam), _shade(np.broadcast_to(-n, U.shape), U, row[11:14], spec, L_cam))
            _put(frame, zbuf, win, cov, tt, rad, veil_a, veil_t, veil_rgb, scale, vig)
        else:
            o = -(Rc.T @ a)
            dr = U @ Rc  # rays in the box frame
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (-h - o) / dr, (h - o) / dr
            par = np.abs(dr) < 1e-12
            lo = np.where(par, np.where(np.abs(o) > h, 1e30, -1e30), np.minimum(t1, t2))
            hi = np.where(par, 1e30, np.maximum(t1, t2))
            axis = np.argmax(lo, axis=-1)
            t_near = np.take_along_axis(lo, axis[..., None], -1)[..., 0]
            hit = (t_near <= hi.min(axis=-1)) & (t_near > NEAR_M)
            dax = np.take_along_axis(dr, axis[..., None], -1)[..., 0]
            sgn = np.where(dax > 0, -1.0, 1.0)
            N = sgn[..., None] * Rc.T[axis]
            rad = _shade(N, U, rgb, spec, L_cam)
            _put(frame, zbuf, win, hit.astype(float), np.where(hit, t_near, np.inf), rad, veil_a, veil_t, veil_rgb, scale, vig)
