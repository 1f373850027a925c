"""A ball candidate's centre and diameter from its edge: a circle fitted to the strongest radial edge.

The learned stage's centres come from a heatmap of stride 8 at the network's scale and carry a few pixels of
error (measured on the semi-real caliscope frames with real white balls: median 4 px, 13 % within 1.5 px of
the truth), as do its diameters (1.1-1.8x too wide). Where the model's 5x5 filter sees the ball it refines the
centre (:meth:`BallDetector._refined`); where it does not (a white ball and an orange filter), this does:

1. around the candidate's centre ``c``, a grey window (OpenCV's luminance) a little over 2.5 diameters ``d``
   wide, looked at in a pyramid level (``cv2.pyrDown``) where the ball is ``PYRAMID_PX``-``2 PYRAMID_PX``
   wide when it is wider, and smoothed by a Gaussian of ``SMOOTH d`` (at least 0.6 px);
2. ``N_RAYS`` rays sample it (bilinear) from ``0.4 r`` to ``1.5 r + 1`` px every ``STEP_PX`` (``r = d / 2``);
   the ball is brighter or darker than its surroundings (the mean of the rays' inner thirds against their
   outer thirds); along each ray the edge is where the brightness falls (rises) fastest outward, over 2 px;
3. the rays whose edge is weaker than ``WEAK_EDGE`` x the median absolute difference are left out; a circle
   is fitted to the others' edge points by least squares (Kasa's algebraic fit), up to ``FIT_ROUNDS`` times,
   each time without the points farther than ``max(1 px, TRIM x the median residual)`` from the circle;
4. the fit is kept when at least ``MIN_POINTS`` edges remain, its radius is 0.5-1.5x the candidate's and its
   centre within half the candidate's diameter of the candidate's centre; then steps 1-3 run again from the
   fitted centre and diameter (``PASSES`` in all: the second window's smoothing and ray range fit the ball,
   not the network's wider guess).

Measured on those frames (272 network candidates on the ball, seed 0, cameras 0-3, `rt2 eval framesets --scene
caliscope --ball white --crop-frames 58:`'s frames): median centre error 4.03 -> 0.59 px, within 1.5 px 13 % ->
83 %, 90th percentile 8.2 -> 3.1 px (one pass: 0.83 px, 70 %). The fit is plain geometry, so it needs no
training; a smeared ball (an elongated blob) is fitted by its mean circle, whose centre is the smear's middle:
the ball at mid-exposure. That circle is wider than the ball's equal-area diameter (median 1.2x on those
frames, where the network's diameters are ~1.1x), so the detector takes the centre from here and keeps the
network's diameter for the 3D size test: with the fitted diameters too, the size test rejected 2-3x as many
positions (`rt2 eval framesets` recall 73 % on seed 5, 94 % with the network's).

Chroma: a ball of a saturated colour (orange) lit from one side darkens towards its far side, and there grey's
steepest fall is the shading's, not the ball's outline: on orange balls drawn into real frames (lit from a random
side, `rt2 eval detector --data /tmp/orange/eval_drawn`) the grey fit's median error was 3.1 px, leaning to the lit
side. With ``chroma`` the window is ``255 max(R - B, 0) // (R + G + B + CHROMA_DARK)`` in integers instead of grey
(the pyramid and smoothing as before): the shaded side keeps the ball's hue, so its outline is the edge; the median
error there 0.67 px, on the semi-real caliscope frames' drawn orange balls 1.14 -> 0.27 px (README Results,
"Orange centres from the ball's chroma"). ``CHROMA_DARK`` keeps dark pixels' noise from ruling the chroma. The
detector uses it for a model of orange balls (``DetectorOptions.edge_channel``).

:func:`refine_edges_reference` is the plain numpy version, :func:`refine_edges` the compiled one used per
frame (the same arithmetic in the same order; a test checks that they agree).
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np

from checks.numba_cache import key_cache_on_callees

__all__ = ["CHROMA_COLOURS", "CHROMA_DARK", "N_RAYS", "PASSES", "chroma_for", "refine_edges", "refine_edges_reference"]

N_RAYS = 32  #: rays cast from the candidate's centre
STEP_PX = 0.5  #: sample spacing along a ray, px
INNER, OUTER = 0.4, 1.5  #: the rays run from INNER r to OUTER r + 1 px
WEAK_EDGE = 0.3  #: a ray's edge weaker than this x the median absolute difference is left out
TRIM = 2.5  #: the circle fit's outlier cut: this x the median residual (at least 1 px)
MIN_POINTS = 8  #: edges needed for a fit
PASSES = 2  #: passes, each in the window of the previous pass's centre and diameter
SMOOTH = 0.08  #: the grey window's Gaussian, x the candidate's diameter (at least 0.6 px)
PYRAMID_PX = 16.0  #: a ball at least twice this wide is looked at in a pyramid level where it is 16-32 px
MIN_DIAMETER_PX, MAX_DIAMETER_PX = 4.0, 400.0  #: candidates outside these diameters keep their centre
FIT_ROUNDS = 3  #: least-squares fits per pass, each without the previous fit's outliers
#: the chroma window's darkness offset: ``255 (R - B) // (R + G + B + CHROMA_DARK)`` (dark pixels' noise stays small)
CHROMA_DARK = 30
#: the ball colours (``BallSegmentationModel.ball_colour``) whose edge is fitted on the chroma: saturated ones
CHROMA_COLOURS = frozenset({"orange"})


def chroma_for(ball_colour: str) -> bool:
    """Whether a ball of ``ball_colour`` is fitted on the chroma, not on grey (module docstring, "Chroma"): the rule
    the detector's ``edge_channel`` "auto" and the label consensus's re-centring share."""
    return ball_colour in CHROMA_COLOURS


def _bilinear(gray, x, y):
    """``gray`` at the (x, y) of the arrays ``x``, ``y`` (any shape), bilinear, coordinates clamped to the image."""
    h, w = gray.shape
    x = np.minimum(np.maximum(x, 0.0), w - 1.0)
    y = np.minimum(np.maximum(y, 0.0), h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    a, b = gray[y0, x0].astype(np.float64), gray[y0, x1].astype(np.float64)
    c, d = gray[y1, x0].astype(np.float64), gray[y1, x1].astype(np.float64)
    return (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy


@numba.njit(cache=True, nogil=True)
def _window_box(h, w, u, v, diameter):
    """The image box ``(x0, y0, x1, y1)`` of a candidate's grey window (module docstring, step 1; compiled, the
    reference's and the kernel's)."""
    r = int(math.ceil(2.5 * 0.5 * diameter + 3.0))
    x0, y0 = max(int(math.floor(u)) - r, 0), max(int(math.floor(v)) - r, 0)
    x1, y1 = min(int(math.floor(u)) + r + 2, w), min(int(math.floor(v)) + r + 2, h)
    return x0, y0, x1, y1


@numba.njit(cache=True, nogil=True)
def _reflect101(p, n):
    """OpenCV's BORDER_REFLECT_101 index of ``p`` in ``[0, n)`` (reflected as often as it takes; compiled, the
    reference's and the kernel's)."""
    if n == 1:
        return 0
    while p < 0 or p >= n:
        p = -p if p < 0 else 2 * n - 2 - p
    return p


@numba.njit(cache=True, nogil=True)
def _gauss_taps(sigma):
    """The Gaussian's taps to 2.5 sigma, normalised (float64): half the time of OpenCV's default 4 sigma (compiled,
    the reference's and the kernel's)."""
    k = 2 * int(math.ceil(2.5 * sigma)) + 1
    taps = np.empty(k)
    total = 0.0
    for t in range(k):
        x = t - (k - 1) // 2
        taps[t] = math.exp(-(x * x) / (2.0 * sigma * sigma))
        total += taps[t]
    for t in range(k):
        taps[t] /= total
    return taps


def window_of(image: np.ndarray, u: float, v: float, diameter: float, chroma: bool = False):
    """The smoothed grey window the rays of a candidate at (u, v) of ``diameter`` px are cast in, both passes:
    ``(gray (h, w) float64, x0, y0, scale)``: the window's pixel (x, y) is the image's ``(x0 + scale x, y0 + scale y)``;
    None where the window is empty. Grey = OpenCV's luminance (``COLOR_RGB2GRAY``'s integer arithmetic); a ball wider
    than ``PYRAMID_PX`` is looked at in a pyramid level (``cv2.pyrDown``'s, ``scale`` = 2 or 4 ...) where it is about
    that wide, then smoothed by a Gaussian of ``max(0.6, SMOOTH x its diameter there)`` px (separable, float64, borders
    reflected as OpenCV's default). The numpy reference of :func:`_window_nb` (the same arithmetic in the same order;
    grey and pyramid are OpenCV's to the bit, a test checks). ``chroma``: the window is the ball's colour's chroma
    instead of grey, ``255 (R - B) // (R + G + B + CHROMA_DARK)`` (at least 0), in integers: a ball of a saturated
    colour (orange) keeps it on its shaded side, where its brightness falls off (module docstring, "Chroma")."""
    h, w = image.shape[:2]
    x0, y0, x1, y1 = _window_box(h, w, u, v, diameter)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    rgb = image[y0:y1, x0:x1].astype(np.int64)
    if chroma:
        gray = np.maximum(rgb[..., 0] - rgb[..., 2], 0) * 255 // (rgb[..., 0] + rgb[..., 1] + rgb[..., 2] + CHROMA_DARK)
    else:
        gray = (rgb[..., 0] * GRAY_R + rgb[..., 1] * GRAY_G + rgb[..., 2] * GRAY_B + (1 << (GRAY_SHIFT - 1))) >> GRAY_SHIFT
    scale = 1
    while diameter / scale >= 2 * PYRAMID_PX and min(gray.shape) >= 8:
        gray = _pyr_down_reference(gray)
        scale *= 2
    taps = _gauss_taps(max(0.6, SMOOTH * diameter / scale))
    return _blur_reference(gray.astype(np.float64), taps), x0, y0, scale


#: OpenCV's RGB -> grey in integers: (R 9798 + G 19235 + B 3735 + 2^14) >> 15
GRAY_R, GRAY_G, GRAY_B, GRAY_SHIFT = 9798, 19235, 3735, 15
_PYR_TAPS = (1, 4, 6, 4, 1)


def _pyr_down_reference(gray):
    """``cv2.pyrDown`` of an integer image: the 5x5 binomial, (sum + 128) >> 8, every second pixel."""
    h, w = gray.shape
    oh, ow = (h + 1) // 2, (w + 1) // 2
    rows = np.array([[_reflect101(2 * i + a - 2, h) for a in range(5)] for i in range(oh)])
    cols = np.array([[_reflect101(2 * j + b - 2, w) for b in range(5)] for j in range(ow)])
    acc = np.zeros((oh, ow), np.int64)
    for a in range(5):
        for b in range(5):
            acc += _PYR_TAPS[a] * _PYR_TAPS[b] * gray[rows[:, a]][:, cols[:, b]]
    return (acc + 128) >> 8


def _blur_reference(gray, taps):
    """Separable smoothing of a float64 image by ``taps``: along rows, then columns, each sum in tap order."""
    h, w = gray.shape
    c = (len(taps) - 1) // 2
    tmp = np.zeros((h, w))
    for t in range(len(taps)):
        tmp = tmp + taps[t] * gray[:, [_reflect101(x + t - c, w) for x in range(w)]]
    out = np.zeros((h, w))
    for t in range(len(taps)):
        out = out + taps[t] * tmp[[_reflect101(y + t - c, h) for y in range(h)], :]
    return out


def _seq_sum(x) -> float:
    """The sum of ``x``'s elements in row-major order, one after the other (the compiled kernel's order: numpy's own
    sums pair elements up, which differs in the last bits)."""
    return sum(np.ravel(x).tolist(), 0.0)


def _circle_fit(px, py):
    """Kasa's fit: (a, b, r) of the circle through the points in the least-squares sense, or None."""
    z = px * px + py * py
    ok, a, b, r = _circle_from_sums.py_func(float(len(px)), _seq_sum(px), _seq_sum(py), _seq_sum(px * px), _seq_sum(py * py),
                                            _seq_sum(px * py), _seq_sum(z), _seq_sum(px * z), _seq_sum(py * z))
    return (a, b, r) if ok else None


def _one_pass(image, u, v, r0):
    """One pass of the module docstring's steps 1-3 from (u, v): (a, b, radius) or None."""
    n_s = int((OUTER * r0 + 1.0 - max(1.0, INNER * r0)) / STEP_PX) + 1
    if n_s < 7:
        return None
    rs = max(1.0, INNER * r0) + STEP_PX * np.arange(n_s)
    ca, sa = _COS, _SIN  # (module constants, defined with the compiled twin below)
    vals = _bilinear(image, u + ca[:, None] * rs[None, :], v + sa[:, None] * rs[None, :])
    third = n_s // 3
    inner, outer = _seq_sum(vals[:, :third]) / (N_RAYS * third), _seq_sum(vals[:, n_s - third:]) / (N_RAYS * third)
    sgn = -1.0 if inner >= outer else 1.0
    deriv = sgn * (vals[:, 4:] - vals[:, :-4])  # the edge at rs[k + 2]
    k = np.argmax(deriv, axis=1)
    strength = deriv[np.arange(N_RAYS), k]
    thr = WEAK_EDGE * np.median(np.abs(deriv)) + 1e-3
    idx = np.flatnonzero(strength > thr)
    if len(idx) < MIN_POINTS:
        return None
    re = rs[k + 2]
    px, py = u + ca * re, v + sa * re
    fit = None
    for _ in range(FIT_ROUNDS):
        fit = _circle_fit(px[idx], py[idx])
        if fit is None:
            return None
        a, b, rr = fit
        res = np.abs(np.hypot(px[idx] - a, py[idx] - b) - rr)
        keep = res <= max(1.0, TRIM * np.median(res))
        if keep.all():
            break
        idx = idx[keep]
        if len(idx) < MIN_POINTS:
            return None
    return fit


def refine_edges_reference(image: np.ndarray, uv_px: np.ndarray, diameter_px: np.ndarray, chroma: bool = False):
    """Centres and diameters of the candidates ``uv_px`` (n, 2) of diameters ``diameter_px`` (n,) in ``image``
    ((H, W, 3) uint8 RGB) refined by their edge (module docstring); returns ``(uv (n, 2), diameter (n,), refined (n,) bool)``:
    a candidate whose fit failed keeps its centre and diameter. ``chroma``: the edge of the ball's colour's chroma,
    not of grey (:func:`window_of`; a ball of a saturated colour)."""
    return _refine(image, uv_px, diameter_px, bool(chroma))


@numba.njit(cache=True, nogil=True)
def _fittable(u, v, d):
    """Whether a candidate is fitted at all: a finite centre, a finite diameter in the fitted range."""
    return math.isfinite(u) and math.isfinite(v) and math.isfinite(d) and MIN_DIAMETER_PX <= d <= MAX_DIAMETER_PX


@numba.njit(cache=True, nogil=True)
def _kept(a, b, rr, r0, u0, v0):
    """Whether a pass's circle (a, b, rr) is kept for a candidate of radius ``r0`` at (u0, v0) (module docstring, step 4)."""
    return 0.5 * r0 <= rr <= 1.5 * r0 and not math.hypot(a - u0, b - v0) > r0


def _refine(image, uv_px, diameter_px, chroma=False):
    """The passes of the module docstring over every candidate, each pass in its own window (:func:`window_of` of
    the previous pass's centre and diameter), numpy (:func:`_refine_nb` is the kernel)."""
    uv = np.array(uv_px, np.float64).reshape(-1, 2)
    d = np.array(diameter_px, np.float64).reshape(-1)
    ok = np.zeros(len(d), bool)
    for i in range(len(d)):
        u0, v0, d0 = uv[i, 0], uv[i, 1], d[i]
        if not _fittable(u0, v0, d0):
            continue
        r0, u, v, dd = 0.5 * d0, u0, v0, d0
        good = True
        for _ in range(PASSES):
            win = window_of(image, u, v, dd, chroma)
            fit = None if win is None else _one_pass(win[0], (u - win[1]) / win[3], (v - win[2]) / win[3], 0.5 * dd / win[3])
            if fit is None:
                good = False
                break
            _, x0, y0, sc = win
            a, b, rr = x0 + sc * fit[0], y0 + sc * fit[1], sc * fit[2]
            if not _kept(a, b, rr, r0, u0, v0):
                good = False
                break
            u, v, dd = a, b, 2.0 * rr
        if good:
            uv[i] = u, v
            d[i] = dd
            ok[i] = True
    return uv, d, ok


# -- the compiled twin: the same steps, loops instead of array expressions ------------------------------------
@numba.njit(cache=True, nogil=True)
def _sample(gray, x, y):
    h, w = gray.shape[0], gray.shape[1]
    x = min(max(x, 0.0), w - 1.0)
    y = min(max(y, 0.0), h - 1.0)
    x0 = min(int(math.floor(x)), w - 2 if w > 1 else 0)
    y0 = min(int(math.floor(y)), h - 2 if h > 1 else 0)
    x1, y1 = min(x0 + 1, w - 1), min(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    a, b = float(gray[y0, x0]), float(gray[y0, x1])
    c, d = float(gray[y1, x0]), float(gray[y1, x1])
    return (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy


@numba.njit(cache=True, nogil=True)
def _circle_from_sums(n, sx, sy, sxx, syy, sxy, sz, sxz, syz):
    """Kasa's normal equations from the points' sums (z = x^2 + y^2), solved by Cramer's rule: (ok, a, b, r)."""
    m00, m01, m02 = 4.0 * sxx, 4.0 * sxy, 2.0 * sx
    m11, m12, m22 = 4.0 * syy, 2.0 * sy, n
    r0_, r1_, r2_ = 2.0 * sxz, 2.0 * syz, sz
    c00 = m11 * m22 - m12 * m12
    c01 = m01 * m22 - m12 * m02
    c02 = m01 * m12 - m11 * m02
    det = m00 * c00 - m01 * c01 + m02 * c02
    if not abs(det) > 1e-9:
        return False, 0.0, 0.0, 0.0
    a = (r0_ * c00 - m01 * (r1_ * m22 - m12 * r2_) + m02 * (r1_ * m12 - m11 * r2_)) / det
    b = (m00 * (r1_ * m22 - m12 * r2_) - r0_ * c01 + m02 * (m01 * r2_ - r1_ * m02)) / det
    c = (m00 * (m11 * r2_ - r1_ * m12) - m01 * (m01 * r2_ - r1_ * m02) + r0_ * c02) / det
    r2 = c + a * a + b * b
    if not r2 > 0:
        return False, 0.0, 0.0, 0.0
    return True, a, b, math.sqrt(r2)


@numba.njit(cache=True, nogil=True)
def _circle_fit_nb(px, py, idx, n):
    sx = sy = sxx = syy = sxy = sz = sxz = syz = 0.0
    for t in range(n):
        x, y = px[idx[t]], py[idx[t]]
        z = x * x + y * y
        sx += x
        sy += y
        sxx += x * x
        syy += y * y
        sxy += x * y
        sz += z
        sxz += x * z
        syz += y * z
    return _circle_from_sums(float(n), sx, sy, sxx, syy, sxy, sz, sxz, syz)


@numba.njit(cache=True, nogil=True)
def _one_pass_nb(image, u, v, r0, ca, sa):
    n_s = int((OUTER * r0 + 1.0 - max(1.0, INNER * r0)) / STEP_PX) + 1
    if n_s < 7:
        return False, 0.0, 0.0, 0.0
    r_lo = max(1.0, INNER * r0)
    n_rays = len(ca)
    vals = np.empty((n_rays, n_s))
    for a in range(n_rays):
        for k in range(n_s):
            r = r_lo + STEP_PX * k
            vals[a, k] = _sample(image, u + ca[a] * r, v + sa[a] * r)
    third = n_s // 3
    inner = outer = 0.0
    for a in range(n_rays):
        for k in range(third):
            inner += vals[a, k]
    for a in range(n_rays):
        for k in range(n_s - third, n_s):
            outer += vals[a, k]
    inner /= n_rays * third
    outer /= n_rays * third
    sgn = -1.0 if inner >= outer else 1.0
    nd = n_s - 4
    deriv = np.empty((n_rays, nd))
    for a in range(n_rays):
        for k in range(nd):
            deriv[a, k] = sgn * (vals[a, k + 4] - vals[a, k])
    thr = WEAK_EDGE * np.median(np.abs(deriv)) + 1e-3
    px = np.empty(n_rays)
    py = np.empty(n_rays)
    idx = np.empty(n_rays, np.int64)
    n = 0
    for a in range(n_rays):
        kb = 0
        for k in range(1, nd):
            if deriv[a, k] > deriv[a, kb]:
                kb = k
        re = r_lo + STEP_PX * (kb + 2)
        px[a] = u + ca[a] * re
        py[a] = v + sa[a] * re
        if deriv[a, kb] > thr:
            idx[n] = a
            n += 1
    if n < MIN_POINTS:
        return False, 0.0, 0.0, 0.0
    ok, fa, fb, fr = False, 0.0, 0.0, 0.0
    res = np.empty(n_rays)
    for _ in range(FIT_ROUNDS):
        ok, fa, fb, fr = _circle_fit_nb(px, py, idx, n)
        if not ok:
            return False, 0.0, 0.0, 0.0
        for t in range(n):
            res[t] = abs(math.hypot(px[idx[t]] - fa, py[idx[t]] - fb) - fr)
        cut = max(1.0, TRIM * np.median(res[:n]))
        m = 0
        for t in range(n):
            if res[t] <= cut:
                idx[m] = idx[t]
                m += 1
        if m == n:
            break
        n = m
        if n < MIN_POINTS:
            return False, 0.0, 0.0, 0.0
    return ok, fa, fb, fr


_ANGLES = 2.0 * np.pi * np.arange(N_RAYS) / N_RAYS
_COS, _SIN = np.cos(_ANGLES), np.sin(_ANGLES)


@numba.njit(cache=True, nogil=True)
def _window_nb(image, u, v, diameter, chroma):
    """:func:`window_of` compiled: ``(ok, gray, x0, y0, scale)``."""
    x0, y0, x1, y1 = _window_box(image.shape[0], image.shape[1], u, v, diameter)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return False, np.empty((0, 0)), x0, y0, 1
    gh, gw = y1 - y0, x1 - x0
    gray = np.empty((gh, gw), np.int64)
    half = 1 << (GRAY_SHIFT - 1)
    for y in range(gh):
        for x in range(gw):
            r, g, b = np.int64(image[y0 + y, x0 + x, 0]), np.int64(image[y0 + y, x0 + x, 1]), np.int64(image[y0 + y, x0 + x, 2])
            if chroma:
                gray[y, x] = max(r - b, 0) * 255 // (r + g + b + CHROMA_DARK)
            else:
                gray[y, x] = (r * GRAY_R + g * GRAY_G + b * GRAY_B + half) >> GRAY_SHIFT
    scale = 1
    while diameter / scale >= 2 * PYRAMID_PX and min(gh, gw) >= 8:
        oh, ow = (gh + 1) // 2, (gw + 1) // 2
        down = np.empty((oh, ow), np.int64)
        for i in range(oh):
            for j in range(ow):
                acc = np.int64(0)
                for a in range(5):
                    yy = _reflect101(2 * i + a - 2, gh)
                    for b in range(5):
                        acc += _PYR_TAPS_NB[a] * _PYR_TAPS_NB[b] * gray[yy, _reflect101(2 * j + b - 2, gw)]
                down[i, j] = (acc + 128) >> 8
        gray, gh, gw = down, oh, ow
        scale *= 2
    taps = _gauss_taps(max(0.6, SMOOTH * diameter / scale))
    k = len(taps)
    c = (k - 1) // 2
    tmp = np.empty((gh, gw))
    for y in range(gh):
        for x in range(gw):
            acc = 0.0
            for t in range(k):
                acc += taps[t] * float(gray[y, _reflect101(x + t - c, gw)])
            tmp[y, x] = acc
    out = np.empty((gh, gw))
    for y in range(gh):
        for x in range(gw):
            acc = 0.0
            for t in range(k):
                acc += taps[t] * tmp[_reflect101(y + t - c, gh), x]
            out[y, x] = acc
    return True, out, x0, y0, scale


_PYR_TAPS_NB = np.array(_PYR_TAPS, np.int64)


@numba.njit(cache=True, nogil=True)
def _refine_nb(image, uv, d, ca, sa, chroma):
    """:func:`_refine` compiled, windows included: ``uv`` and ``d`` (copies) refined in place; returns the flags."""
    n = len(d)
    ok = np.zeros(n, np.bool_)
    for i in range(n):
        u0, v0, d0 = uv[i, 0], uv[i, 1], d[i]
        if not _fittable(u0, v0, d0):
            continue
        r0, u, v, dd = 0.5 * d0, u0, v0, d0
        good = True
        for _ in range(PASSES):
            has, gray, x0, y0, sc = _window_nb(image, u, v, dd, chroma)
            if not has:
                good = False
                break
            fit, fa, fb, fr = _one_pass_nb(gray, (u - x0) / sc, (v - y0) / sc, 0.5 * dd / sc, ca, sa)
            if not fit:
                good = False
                break
            a, b, rr = x0 + sc * fa, y0 + sc * fb, sc * fr
            if not _kept(a, b, rr, r0, u0, v0):
                good = False
                break
            u, v, dd = a, b, 2.0 * rr
        if good:
            uv[i, 0], uv[i, 1] = u, v
            d[i] = dd
            ok[i] = True
    return ok


def refine_edges(image: np.ndarray, uv_px: np.ndarray, diameter_px: np.ndarray, chroma: bool = False):
    """:func:`refine_edges_reference` compiled (numba), windows, rays and fit in one call: the same results, faster."""
    uv = np.array(uv_px, np.float64).reshape(-1, 2)
    d = np.array(diameter_px, np.float64).reshape(-1)
    if len(d) == 0:
        return uv, d, np.zeros(0, bool)
    ok = _refine_nb(image, uv, d, _COS, _SIN, bool(chroma))
    return uv, d, ok


key_cache_on_callees(globals())  # an edit of a helper or a constant recompiles the kernels
