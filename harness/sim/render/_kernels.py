"""Numba kernel: draw the primitive table into one camera's frame (the per-frame hot path).

One call per camera and frame. For each primitive it projects a few points of the object (lens
distortion included) to find a small pixel window, then walks the window's pixels, intersects the
pixel's exact ray (from :class:`~harness.sim.render.static.Background`) with the object, anti-aliases
the silhouette from the signed angular distance to it, depth-tests against the z-buffer (static lab
+ objects drawn so far), blends the net's mesh when the object is behind it, shades (ambient +
diffuse + Blinn-Phong highlight) and composites into the uint8 frame. Balls are averaged over
time samples across the exposure (motion blur) and report their visible coverage.

:mod:`harness.sim.render.reference` is the plain-numpy twin; ``tests/harness/sim/test_render_kernels.py`` checks
that they agree.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from harness.sim.render.primitives import (
    BALL,
    CAPSULE,
    DISK,
    NEAR_M,
    SHININESS,
)
from tracker.distortion import distort_point
from checks.numba_cache import key_cache_on_callees

assert SHININESS == 32, "the kernel computes ndh ** SHININESS by five squarings"


__all__ = ["draw_numba"]


@njit(cache=True, error_model="numpy")
def _project(K, d8, x, y, z):
    xd, yd = distort_point(x / z, y / z, d8[0], d8[1], d8[2], d8[3], d8[4], d8[5], d8[6], d8[7])
    return K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]


@njit(cache=True, error_model="numpy")
def _spans(K, d8, pts, margin_m, chain, W, H):
    """Pixels to visit for an object sampled by ``pts`` (m, 3) camera frame, widened by
    ``margin_m`` (object radius) at the nearest depth: rows v0..v1 and per row the columns
    ``lo[v - v0]..hi[v - v0]``. With ``chain`` the points are a path (capsule axis, ball track)
    and each consecutive pair gets its own rectangle, so a diagonal capsule visits a band, not its
    whole bounding box. Returns v1 < v0 when nothing is in front of the camera; every pixel when
    the object crosses the camera plane."""
    m_pts = pts.shape[0]
    n_front = 0
    for i in range(m_pts):
        if pts[i, 2] > NEAR_M:
            n_front += 1
    if n_front == 0:
        return 0, -1, np.zeros(0, np.int64), np.zeros(0, np.int64)
    if n_front < m_pts:  # crosses the camera plane: test every pixel
        return 0, H - 1, np.zeros(H, np.int64), np.full(H, W - 1, np.int64)
    uv = np.empty((m_pts, 2))
    for i in range(m_pts):
        uv[i, 0], uv[i, 1] = _project(K, d8, pts[i, 0], pts[i, 1], pts[i, 2])
    f = max(K[0, 0], K[1, 1])
    n_rect = m_pts - 1 if (chain and m_pts > 1) else 1
    rects = np.empty((n_rect, 4), np.int64)
    for r in range(n_rect):
        i0, i1 = (r, r + 1) if (chain and m_pts > 1) else (0, m_pts - 1)
        umin, umax, vmin, vmax, zmin = 1e30, -1e30, 1e30, -1e30, 1e30
        for i in range(i0, i1 + 1):
            umin, umax = min(umin, uv[i, 0]), max(umax, uv[i, 0])
            vmin, vmax = min(vmin, uv[i, 1]), max(vmax, uv[i, 1])
            zmin = min(zmin, pts[i, 2])
        m = 1.3 * margin_m * f / zmin + 2.0
        rects[r, 0] = max(int(math.floor(umin - m)), 0)
        rects[r, 1] = min(int(math.ceil(umax + m)), W - 1)
        rects[r, 2] = max(int(math.floor(vmin - m)), 0)
        rects[r, 3] = min(int(math.ceil(vmax + m)), H - 1)
    v0, v1 = H, -1
    for r in range(n_rect):
        if rects[r, 1] >= rects[r, 0] and rects[r, 3] >= rects[r, 2]:
            v0, v1 = min(v0, rects[r, 2]), max(v1, rects[r, 3])
    if v1 < v0:
        return 0, -1, np.zeros(0, np.int64), np.zeros(0, np.int64)
    lo = np.full(v1 - v0 + 1, W, np.int64)
    hi = np.full(v1 - v0 + 1, -1, np.int64)
    for r in range(n_rect):
        if rects[r, 1] < rects[r, 0]:
            continue
        for v in range(rects[r, 2], rects[r, 3] + 1):
            lo[v - v0] = min(lo[v - v0], rects[r, 0])
            hi[v - v0] = max(hi[v - v0], rects[r, 1])
    return v0, v1, lo, hi


@njit(cache=True, error_model="numpy")
def _shade(nx, ny, nz, ux, uy, uz, r, g, b, spec, lx, ly, lz, amb, dif, spec_gain):
    """Blinn-Phong radiance: normal n, unit ray u, reflectance rgb, light direction l (toward the
    light, camera frame), ambient, diffuse and specular gain. Scalars only: helpers taking arrays
    cost ~60 ns per call in refcounting, more than the whole pixel."""
    ndl = max(nx * lx + ny * ly + nz * lz, 0.0)
    hx, hy, hz = lx - ux, ly - uy, lz - uz
    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
    ndh = max((nx * hx + ny * hy + nz * hz) / hn, 0.0) if hn > 0 else 0.0
    p = ndh
    for _ in range(5):  # ndh ** SHININESS (= 2 ** 5) without a pow call
        p = p * p
    s = spec_gain * spec * p
    e = amb + dif * ndl
    return r * e + s, g * e + s, b * e + s


@njit(cache=True, error_model="numpy")
def _veil(r, g, b, a, vr, vg, vb):
    """Radiance seen through the net's mesh of opacity ``a`` and radiance (vr, vg, vb)."""
    return r * (1 - a) + vr * a, g * (1 - a) + vg * a, b * (1 - a) + vb * a


@njit(cache=True, error_model="numpy")
def _blend(cov, r, g, b, s, f0, f1, f2):
    """New pixel values: radiance * s (saturated at 255) over the old values f with coverage cov."""
    n0 = min(int(cov * min(r * s, 255.0) + (1 - cov) * f0 + 0.5), 255)
    n1 = min(int(cov * min(g * s, 255.0) + (1 - cov) * f1 + 0.5), 255)
    n2 = min(int(cov * min(b * s, 255.0) + (1 - cov) * f2 + 0.5), 255)
    return n0, n1, n2


@njit(cache=True, error_model="numpy")
def _ball_sample(ux, uy, uz, cx, cy, cz, R, ppr):
    """Exact angular coverage of a sphere at (cx, cy, cz) on the unit ray u: (cov, t_hit, normal)."""
    dotp = ux * cx + uy * cy + uz * cz
    kx, ky, kz = uy * cz - uz * cy, uz * cx - ux * cz, ux * cy - uy * cx
    cross = math.sqrt(kx * kx + ky * ky + kz * kz)
    D = math.sqrt(cx * cx + cy * cy + cz * cz)
    alpha = math.asin(min(R / D, 1.0))
    theta = math.atan2(cross, dotp)
    cov = min(max(0.5 + (alpha - theta) * ppr, 0.0), 1.0)
    th = dotp - math.sqrt(max(R * R - cross * cross, 0.0))
    nx, ny, nz = th * ux - cx, th * uy - cy, th * uz - cz
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if nn > 0:
        nx, ny, nz = nx / nn, ny / nn, nz / nn
    else:
        nx, ny, nz = -ux, -uy, -uz
    return cov, th, nx, ny, nz


@njit(cache=True, error_model="numpy")
def draw_numba(frame, zbuf, rays, ppr, veil_a, veil_t, veil_rgb, vig, K, d8, R_wc, t_wc, prims, L_cam, scale, gt):
    """Draw ``prims`` (n, N_COLS) world-frame table into ``frame`` (H, W, 3) uint8 and ``zbuf``
    (H, W) float32 in place; add each ball's visible mid-exposure coverage (pixels) to ``gt``.
    ``L_cam`` (6,): light direction in the camera frame, ambient, diffuse, specular gain;
    ``scale``: pixel value per unit radiance (brightness * DN_PER_RADIANCE)."""
    H, W = zbuf.shape
    lx, ly, lz, amb, dif, sg = L_cam[0], L_cam[1], L_cam[2], L_cam[3], L_cam[4], L_cam[5]
    vr, vg, vb = veil_rgb[0], veil_rgb[1], veil_rgb[2]
    for p in range(prims.shape[0]):
        row = prims[p]
        kind = int(row[0])
        a = R_wc @ row[1:4] + t_wc
        R = row[7]
        cr, cg, cb = row[8], row[9], row[10]
        spec = row[14]
        if kind == CAPSULE or kind == BALL:
            b = R_wc @ row[4:7] + t_wc
            n_s = 9 if kind == CAPSULE else 3
            pts = np.empty((n_s, 3))
            for i in range(n_s):
                pts[i] = a + (b - a) * (i / (n_s - 1))
            v0, v1, lo, hi = _spans(K, d8, pts, R, True, W, H)
            ax, ay, az = a[0], a[1], a[2]
            dx, dy, dz = b[0] - ax, b[1] - ay, b[2] - az
            c = dx * dx + dy * dy + dz * dz
            fa = dx * ax + dy * ay + dz * az
            n_t, mx, my, mz, bi = 1, 0.0, 0.0, 0.0, 0
            if kind == BALL:
                ua, va = _project(K, d8, ax, ay, az) if az > NEAR_M else (0.0, 0.0)
                ub, vb_ = _project(K, d8, b[0], b[1], b[2]) if b[2] > NEAR_M else (0.0, 0.0)
                n_t = min(max(int(math.sqrt((ub - ua) ** 2 + (vb_ - va) ** 2) * 2.0) + 1, 1), 64)
                mx, my, mz = ax + dx / 2, ay + dy / 2, az + dz / 2
                bi = int(row[24])
            for v in range(v0, v1 + 1):
                for u in range(lo[v - v0], hi[v - v0] + 1):
                    ux, uy, uz = rays[v, u, 0], rays[v, u, 1], rays[v, u, 2]
                    pp = ppr[v, u]
                    z = zbuf[v, u]
                    if kind == BALL:
                        # motion blur: average the sphere over n_t instants of the exposure
                        s_px = scale * vig[v, u]
                        acc_a, acc_r, acc_g, acc_b, t_min = 0.0, 0.0, 0.0, 0.0, 1e30
                        for k in range(n_t):
                            f = (k + 0.5) / n_t
                            cov, th, nx, ny, nz = _ball_sample(ux, uy, uz, ax + f * dx, ay + f * dy, az + f * dz, R, pp)
                            if cov <= 0 or th >= z:
                                continue
                            r, g, bb = _shade(nx, ny, nz, ux, uy, uz, cr, cg, cb, spec, lx, ly, lz, amb, dif, sg)
                            if th > veil_t[v, u]:
                                r, g, bb = _veil(r, g, bb, veil_a[v, u], vr, vg, vb)
                            acc_r += cov * min(r * s_px, 255.0)
                            acc_g += cov * min(g * s_px, 255.0)
                            acc_b += cov * min(bb * s_px, 255.0)
                            acc_a += cov
                            t_min = min(t_min, th)
                        # ground truth: visible coverage of the sphere at mid-exposure
                        cov, th, nx, ny, nz = _ball_sample(ux, uy, uz, mx, my, mz, R, pp)
                        if cov > 0 and th < z:
                            gt[bi] += cov * (1 - veil_a[v, u]) if th > veil_t[v, u] else cov
                        if acc_a > 0:
                            al = acc_a / n_t
                            frame[v, u, 0] = min(int(acc_r / n_t + (1 - al) * frame[v, u, 0] + 0.5), 255)
                            frame[v, u, 1] = min(int(acc_g / n_t + (1 - al) * frame[v, u, 1] + 0.5), 255)
                            frame[v, u, 2] = min(int(acc_b / n_t + (1 - al) * frame[v, u, 2] + 0.5), 255)
                            if al >= 0.5:
                                zbuf[v, u] = t_min
                        continue
                    # capsule: closest points between the ray and the axis segment
                    bd, e = ux * dx + uy * dy + uz * dz, ux * ax + uy * ay + uz * az
                    s = 0.0
                    if c > 1e-12:
                        den = c - bd * bd
                        s = (bd * e - fa) / den if den > 1e-12 else 0.0
                        s = min(max(s, 0.0), 1.0)
                    t = e + s * bd
                    if t <= NEAR_M:
                        continue
                    qx, qy, qz = ax + s * dx, ay + s * dy, az + s * dz
                    dist2 = (t * ux - qx) ** 2 + (t * uy - qy) ** 2 + (t * uz - qz) ** 2
                    reach = R + 0.5 * t / pp  # beyond this the coverage is 0
                    if dist2 >= reach * reach:
                        continue
                    dist = math.sqrt(dist2)
                    cov = min(max(0.5 + (R - dist) / t * pp, 0.0), 1.0)
                    th = t - math.sqrt(max(R * R - dist * dist, 0.0))
                    if cov <= 0 or th >= z:
                        continue
                    hx, hy, hz = th * ux, th * uy, th * uz
                    sh = 0.0
                    if c > 1e-12:
                        sh = min(max(((hx - ax) * dx + (hy - ay) * dy + (hz - az) * dz) / c, 0.0), 1.0)
                    nx, ny, nz = hx - ax - sh * dx, hy - ay - sh * dy, hz - az - sh * dz
                    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
                    if nn > 0:
                        nx, ny, nz = nx / nn, ny / nn, nz / nn
                    else:
                        nx, ny, nz = -ux, -uy, -uz
                    r, g, bb = _shade(nx, ny, nz, ux, uy, uz, cr, cg, cb, spec, lx, ly, lz, amb, dif, sg)
                    if th > veil_t[v, u]:
                        r, g, bb = _veil(r, g, bb, veil_a[v, u], vr, vg, vb)
                    frame[v, u, 0], frame[v, u, 1], frame[v, u, 2] = _blend(cov, r, g, bb, scale * vig[v, u], frame[v, u, 0], frame[v, u, 1], frame[v, u, 2])
                    if cov >= 0.5:
                        zbuf[v, u] = th
        elif kind == DISK:
            n = R_wc @ row[4:7]
            e1 = np.cross(n, np.array([1.0, 0.0, 0.0]))
            if e1 @ e1 < 1e-6:
                e1 = np.cross(n, np.array([0.0, 1.0, 0.0]))
            e1 = e1 / math.sqrt(e1 @ e1)
            e2 = np.cross(n, e1)
            pts = np.empty((16, 3))
            for i in range(16):
                phi = 2 * math.pi * i / 16
                pts[i] = a + R * (math.cos(phi) * e1 + math.sin(phi) * e2)
            v0, v1, lo, hi = _spans(K, d8, pts, 0.0, False, W, H)
            ax, ay, az, nx0, ny0, nz0 = a[0], a[1], a[2], n[0], n[1], n[2]
            an = ax * nx0 + ay * ny0 + az * nz0
            for v in range(v0, v1 + 1):
                for u in range(lo[v - v0], hi[v - v0] + 1):
                    ux, uy, uz = rays[v, u, 0], rays[v, u, 1], rays[v, u, 2]
                    den = ux * nx0 + uy * ny0 + uz * nz0
                    if abs(den) < 1e-9:
                        continue
                    t = an / den
                    if t <= NEAR_M or t >= zbuf[v, u]:
                        continue
                    rho = math.sqrt((t * ux - ax) ** 2 + (t * uy - ay) ** 2 + (t * uz - az) ** 2)
                    cov = min(max(0.5 + (R - rho) / t * ppr[v, u], 0.0), 1.0)
                    if cov <= 0:
                        continue
                    if den < 0:  # the front side faces the camera
                        r, g, bb = _shade(nx0, ny0, nz0, ux, uy, uz, cr, cg, cb, spec, lx, ly, lz, amb, dif, sg)
                    else:
                        r, g, bb = _shade(-nx0, -ny0, -nz0, ux, uy, uz, row[11], row[12], row[13], spec, lx, ly, lz, amb, dif, sg)
                    if t > veil_t[v, u]:
                        r, g, bb = _veil(r, g, bb, veil_a[v, u], vr, vg, vb)
                    frame[v, u, 0], frame[v, u, 1], frame[v, u, 2] = _blend(cov, r, g, bb, scale * vig[v, u], frame[v, u, 0], frame[v, u, 1], frame[v, u, 2])
                    if cov >= 0.5:
                        zbuf[v, u] = t
        else:  # BOX: slab test in the box frame
            Rc = R_wc @ row[15:24].copy().reshape(3, 3)
            h = row[4:7]
            pts = np.empty((8, 3))
            for i in range(8):
                sx, sy, sz = (1.0 if i & 1 else -1.0), (1.0 if i & 2 else -1.0), (1.0 if i & 4 else -1.0)
                pts[i] = a + Rc @ np.array([sx * h[0], sy * h[1], sz * h[2]])
            v0, v1, lo, hi = _spans(K, d8, pts, 0.0, False, W, H)
            o = -(Rc.T @ a)
            for v in range(v0, v1 + 1):
                for u in range(lo[v - v0], hi[v - v0] + 1):
                    ux, uy, uz = rays[v, u, 0], rays[v, u, 1], rays[v, u, 2]
                    t_near, t_far, axis = -1e30, 1e30, 0
                    for k in range(3):
                        drk = Rc[0, k] * ux + Rc[1, k] * uy + Rc[2, k] * uz  # ray in the box frame
                        if abs(drk) < 1e-12:
                            if abs(o[k]) > h[k]:
                                t_near = 1e30
                            continue
                        t1, t2 = (-h[k] - o[k]) / drk, (h[k] - o[k]) / drk
                        if t1 > t2:
                            t1, t2 = t2, t1
                        if t1 > t_near:
                            t_near, axis = t1, k
                        t_far = min(t_far, t2)
                    if t_near > t_far or t_near <= NEAR_M or t_near >= zbuf[v, u]:
                        continue
                    dra = Rc[0, axis] * ux + Rc[1, axis] * uy + Rc[2, axis] * uz
                    sgn = -1.0 if dra > 0 else 1.0
                    r, g, bb = _shade(sgn * Rc[0, axis], sgn * Rc[1, axis], sgn * Rc[2, axis], ux, uy, uz, cr, cg, cb, spec, lx, ly, lz, amb, dif, sg)
                    if t_near > veil_t[v, u]:
                        r, g, bb = _veil(r, g, bb, veil_a[v, u], vr, vg, vb)
                    frame[v, u, 0], frame[v, u, 1], frame[v, u, 2] = _blend(1.0, r, g, bb, scale * vig[v, u], frame[v, u, 0], frame[v, u, 1], frame[v, u, 2])
                    zbuf[v, u] = t_near


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
