"""The segmentation model's logits in one compiled pass: the 5x5x3 correlation of the transformed channels.

``correlate_5x5x3(image, lut, k, bias, x0, y0, x1, y1, t, out)`` computes, for every pixel of the window
``x0 <= x < x1, y0 <= y < y1`` of a (H, W, 3) uint8 image (the whole image or a part of it),

    out[y - y0, x - x0] = sum_c sum_i sum_j k[c, i, j] * lut[image[y + i - 2, x + j - 2, c]]  +  bias

with the image's borders reflected without repeating the edge pixel (OpenCV's ``BORDER_REFLECT_101``,
numpy's ``np.pad(mode="reflect")``). ``lut`` is the model's per-channel input transform ``T`` of the 256
channel values. It replaces ``cv2.split``, three ``cv2.LUT``, three ``cv2.filter2D`` and two ``cv2.add``
passes over the frame: each pixel is looked up once into ``t`` (five rows of the window and its
2-pixel surround, channel first, used as a ring), and one output row stays in the first-level cache
while its fifteen kernel rows (3 channels x 5 rows, five products each) are added to it (``rt2 bench
detector`` times both paths).

The summation order is fixed, in float32 without fused multiply-adds: per channel ``c`` and kernel row
``i`` (in that order) the row's five products are summed left to right and added to the pixel's
running sum, which starts at 0; the bias is added last. A pixel's value therefore does not depend on
the window it is computed in (a window's logits are the full frame's, bit for bit), and
``correlate_5x5x3_reference`` (plain numpy slices, same order) gives the same bytes
(``tests/tracker/test_detection_model.py``).
"""

from __future__ import annotations

import numba
import numpy as np

from checks.numba_cache import key_cache_on_callees

__all__ = ["correlate_5x5x3", "correlate_5x5x3_reference", "scratch_shape"]


def scratch_shape(h: int, w: int) -> tuple[int, int, int]:
    """Shape of the float32 scratch ``t`` of a window of h x w pixels: five padded rows per channel, reused
    as a ring (row ``p`` of the padded window in slot ``p % 5``)."""
    return (3, 5, w + 4)


@numba.njit(cache=True, nogil=True)
def _reflect_101(i, n):
    """Index ``i`` of a line of ``n`` pixels, reflected at both ends without repeating the edge pixel."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        if i < 0:
            i = -i
        if i >= n:
            i = 2 * n - 2 - i
    return i


@numba.njit(cache=True, nogil=True)
def _transform_row(image, lut, row, cols, t, slot):
    """t[:, slot] = T of the image's row ``row`` at the padded window's columns ``cols``, channel first."""
    src = image[row]
    t0, t1, t2 = t[0, slot], t[1, slot], t[2, slot]
    for q in range(len(cols)):
        cq = cols[q]
        t0[q] = lut[src[cq, 0]]
        t1[q] = lut[src[cq, 1]]
        t2[q] = lut[src[cq, 2]]


def _signatures():
    """The kernel's two signatures, compiled (or loaded from numba's cache) at import: a frame that comes
    read-only (a raw image decoded from a log, a buffer a driver lends) must not compile a second version
    in the middle of a run."""
    f32 = [numba.types.Array(numba.float32, n, "C") for n in (1, 2, 3)]
    i64 = numba.int64
    return [numba.void(numba.types.Array(numba.uint8, 3, "C", readonly=ro), f32[0], f32[2], numba.float32, i64, i64, i64, i64, f32[2], f32[1])
            for ro in (False, True)]


@numba.njit(_signatures(), cache=True, nogil=True)
def correlate_5x5x3(image, lut, k, bias, x0, y0, x1, y1, t, out):
    """out ((y1 - y0, x1 - x0) float32) = the logits of the window (see the module docstring).

    image : (H, W, 3) uint8, C order (writable or not); lut : (256,) float32; k : (3, 5, 5) float32,
    channel first, in the image's channel order; bias : float32; x0, y0, x1, y1 : int; t : float32
    scratch of :func:`scratch_shape` (overwritten). Other types are refused (no compilation at run time).
    """
    hh, ww = image.shape[0], image.shape[1]
    h, w = y1 - y0, x1 - x0
    cols = np.empty(w + 4, np.int64)  # padded column -> the image's column
    for q in range(w + 4):
        cols[q] = _reflect_101(x0 + q - 2, ww)
    for p in range(4):  # the first four padded rows; row p + 4 joins just before output row p
        _transform_row(image, lut, _reflect_101(y0 + p - 2, hh), cols, t, p)
    for y in range(h):
        _transform_row(image, lut, _reflect_101(y0 + y + 2, hh), cols, t, (y + 4) % 5)
        acc = out[y]
        for x in range(w):
            acc[x] = 0.0
        for c in range(3):
            for i in range(5):
                r = t[c, (y + i) % 5]
                a0, a1, a2, a3, a4 = k[c, i, 0], k[c, i, 1], k[c, i, 2], k[c, i, 3], k[c, i, 4]
                for x in range(w):  # contiguous: vectorised
                    acc[x] += a0 * r[x] + a1 * r[x + 1] + a2 * r[x + 2] + a3 * r[x + 3] + a4 * r[x + 4]
        for x in range(w):
            acc[x] += bias


def correlate_5x5x3_reference(image: np.ndarray, lut: np.ndarray, k: np.ndarray, bias, window=None) -> np.ndarray:
    """The plain numpy twin of :func:`correlate_5x5x3`: same operations in the same order; ``window`` =
    ``(x0, y0, x1, y1)`` or None (the whole image); returns a new (h, w) float32 array."""
    hh, ww = image.shape[:2]
    x0, y0, x1, y1 = (0, 0, ww, hh) if window is None else window
    h, w = y1 - y0, x1 - x0
    t = np.asarray(lut, np.float32)[np.pad(image, ((2, 2), (2, 2), (0, 0)), mode="reflect")]  # (H + 4, W + 4, 3)
    t = t[y0 : y1 + 4, x0 : x1 + 4]
    k = np.asarray(k, np.float32)
    out = np.zeros((h, w), np.float32)
    for c in range(3):
        for i in range(5):
            rows = t[i : i + h, :, c]
            a = k[c, i]
            out += a[0] * rows[:, 0:w] + a[1] * rows[:, 1 : w + 1] + a[2] * rows[:, 2 : w + 2] + a[3] * rows[:, 3 : w + 3] + a[4] * rows[:, 4 : w + 4]
    out += np.float32(bias)
    return out


key_cache_on_callees(globals())  # the helpers live in this file, so an edit of them changes the kernel's own cache key too
