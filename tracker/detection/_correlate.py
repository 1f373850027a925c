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

__all__ = ["COARSE_BLOCK_PX", "blob_frontier", "blob_frontier_reference", "coarse_blocks", "coarse_grid", "coarse_blocks_reference", "coarse_kernel", "coarse_logits", "coarse_logits_reference", "coarse_scratch_shape", "correlate_5x5x3", "correlate_5x5x3_blocks",
           "correlate_5x5x3_reference", "grid_boxes", "scratch_shape"]


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


@numba.njit(cache=True, nogil=True)
def _window_into(image, lut, k, bias, x0, y0, x1, y1, t, out, oy, ox):
    """out[oy + y, ox + x] = the logit of the image's pixel (x0 + x, y0 + y) for the window's pixels (the body of
    :func:`correlate_5x5x3`; :func:`correlate_5x5x3_blocks` writes several windows into one frame-sized array)."""
    hh, ww = image.shape[0], image.shape[1]
    h, w = y1 - y0, x1 - x0
    cols = np.empty(w + 4, np.int64)  # padded column -> the image's column
    for q in range(w + 4):
        cols[q] = _reflect_101(x0 + q - 2, ww)
    for p in range(4):  # the first four padded rows; row p + 4 joins just before output row p
        _transform_row(image, lut, _reflect_101(y0 + p - 2, hh), cols, t, p)
    for y in range(h):
        _transform_row(image, lut, _reflect_101(y0 + y + 2, hh), cols, t, (y + 4) % 5)
        acc = out[oy + y]
        for x in range(w):
            acc[ox + x] = 0.0
        for c in range(3):
            for i in range(5):
                r = t[c, (y + i) % 5]
                a0, a1, a2, a3, a4 = k[c, i, 0], k[c, i, 1], k[c, i, 2], k[c, i, 3], k[c, i, 4]
                for x in range(w):  # contiguous: vectorised
                    acc[ox + x] += a0 * r[x] + a1 * r[x + 1] + a2 * r[x + 2] + a3 * r[x + 3] + a4 * r[x + 4]
        for x in range(w):
            acc[ox + x] += bias


@numba.njit(_signatures(), cache=True, nogil=True)
def correlate_5x5x3(image, lut, k, bias, x0, y0, x1, y1, t, out):
    """out ((y1 - y0, x1 - x0) float32) = the logits of the window (see the module docstring).

    image : (H, W, 3) uint8, C order (writable or not); lut : (256,) float32; k : (3, 5, 5) float32,
    channel first, in the image's channel order; bias : float32; x0, y0, x1, y1 : int; t : float32
    scratch of :func:`scratch_shape` (overwritten). Other types are refused (no compilation at run time).
    """
    _window_into(image, lut, k, bias, x0, y0, x1, y1, t, out, 0, 0)


def _block_signatures():
    f32 = [numba.types.Array(numba.float32, n, "C") for n in (1, 2, 3)]
    i64 = numba.types.Array(numba.int64, 2, "C")
    return [numba.void(numba.types.Array(numba.uint8, 3, "C", readonly=ro), f32[0], f32[2], numba.float32, i64, f32[2], f32[1])
            for ro in (False, True)]


@numba.njit(_block_signatures(), cache=True, nogil=True)
def correlate_5x5x3_blocks(image, lut, k, bias, blocks, t, out):
    """out (the frame's (H, W) float32) = the logits inside each box ``blocks[b] = (x0, y0, x1, y1)``; the rest of
    ``out`` is left as it was. t : scratch of :func:`scratch_shape` for the widest box (or wider). A pixel's value is
    the full frame's, bit for bit (the window's arithmetic is the same)."""
    for b in range(blocks.shape[0]):
        _window_into(image, lut, k, bias, blocks[b, 0], blocks[b, 1], blocks[b, 2], blocks[b, 3], t, out, blocks[b, 1], blocks[b, 0])


def coarse_scratch_shape(h: int, w: int) -> tuple[int, int, int]:
    """Shape of the float32 scratch of :func:`coarse_logits`: three rows of the half-resolution grid per channel."""
    return (3, 3, (w + 1) // 2 + 2)


def coarse_kernel(k: np.ndarray) -> np.ndarray:
    """The (3, 3, 3) float32 kernel of :func:`coarse_logits` from a (3, 5, 5) one: each tap at an odd offset split in
    half between its two even neighbours (the value there taken as the mean of theirs), per axis."""
    split = np.array([[1, 0, 0], [0.5, 0.5, 0], [0, 1, 0], [0, 0.5, 0.5], [0, 0, 1]], np.float64)
    return np.ascontiguousarray(np.einsum("cij,ia,jb->cab", np.asarray(k, np.float64), split, split).astype(np.float32))


def _coarse_signatures():
    f32 = [numba.types.Array(numba.float32, n, "C") for n in (1, 2, 3)]
    return [numba.void(numba.types.Array(numba.uint8, 3, "C", readonly=ro), f32[0], f32[2], numba.float32, f32[2], f32[1])
            for ro in (False, True)]


@numba.njit(_coarse_signatures(), cache=True, nogil=True)
def coarse_logits(image, lut, k3, bias, t, out):
    """out ((ceil(H / 2), ceil(W / 2)) float32) ~ the logits at the pixels ``(2 m, 2 r)``, from those pixels alone: the
    image's every other pixel of every other row, transformed, correlated with ``k3`` (:func:`coarse_kernel`; the
    half-resolution grid's borders reflected without repeating the edge). About a sixteenth of the full frame's work;
    an approximation (where the image is not locally linear, e.g. a ball's edge, it differs), for finding where to
    compute the exact logits. t : scratch of :func:`coarse_scratch_shape`."""
    ho, wo = out.shape[0], out.shape[1]
    cols = np.empty(wo + 2, np.int64)  # padded half-grid column -> the image's column
    for q in range(wo + 2):
        cols[q] = 2 * _reflect_101(q - 1, wo)
    for p in range(2):  # padded half-grid rows 0, 1; row p + 2 joins just before output row p
        _transform_row(image, lut, 2 * _reflect_101(p - 1, ho), cols, t, p)
    for y in range(ho):
        _transform_row(image, lut, 2 * _reflect_101(y + 1, ho), cols, t, (y + 2) % 3)
        acc = out[y]
        for x in range(wo):
            acc[x] = 0.0
        for c in range(3):
            for i in range(3):
                r = t[c, (y + i) % 3]
                a0, a1, a2 = k3[c, i, 0], k3[c, i, 1], k3[c, i, 2]
                for x in range(wo):
                    acc[x] += a0 * r[x] + a1 * r[x + 1] + a2 * r[x + 2]
        for x in range(wo):
            acc[x] += bias


def coarse_logits_reference(image: np.ndarray, lut: np.ndarray, k3: np.ndarray, bias) -> np.ndarray:
    """The plain numpy twin of :func:`coarse_logits`: same operations in the same order; returns a new array."""
    half = image[::2, ::2]
    ho, wo = half.shape[:2]
    t = np.asarray(lut, np.float32)[np.pad(half, ((1, 1), (1, 1), (0, 0)), mode="reflect")]
    return _correlate_rows(t, k3, ho, wo, bias)


def _correlate_rows(t: np.ndarray, k: np.ndarray, h: int, w: int, bias) -> np.ndarray:
    """The references' sums: per channel and kernel row (in that order) the row's products summed left to right
    and added to the running sum, the bias last; t : the transformed, padded pixels (h + n - 1, w + n - 1, 3)."""
    k = np.asarray(k, np.float32)
    n = k.shape[1]
    out = np.zeros((h, w), np.float32)
    for c in range(3):
        for i in range(n):
            rows = t[i : i + h, :, c]
            a = k[c, i]
            term = a[0] * rows[:, 0:w]
            for j in range(1, n):
                term = term + a[j] * rows[:, j : j + w]
            out += term
    out += np.float32(bias)
    return out


def correlate_5x5x3_reference(image: np.ndarray, lut: np.ndarray, k: np.ndarray, bias, window=None) -> np.ndarray:
    """The plain numpy twin of :func:`correlate_5x5x3`: same operations in the same order; ``window`` =
    ``(x0, y0, x1, y1)`` or None (the whole image); returns a new (h, w) float32 array."""
    hh, ww = image.shape[:2]
    x0, y0, x1, y1 = (0, 0, ww, hh) if window is None else window
    h, w = y1 - y0, x1 - x0
    t = np.asarray(lut, np.float32)[np.pad(image, ((2, 2), (2, 2), (0, 0)), mode="reflect")]  # (H + 4, W + 4, 3)
    return _correlate_rows(t[y0 : y1 + 4, x0 : x1 + 4], k, h, w, bias)


#: the fine pass's blocks, pixels (a multiple of 2: whole coarse cells)
COARSE_BLOCK_PX = 16


def _grid_signatures():
    b2 = numba.types.Array(numba.boolean, 2, "C")
    return [numba.void(b2, numba.int64, b2)]


def _runs_signatures():
    i64 = numba.int64
    return [i64(numba.types.Array(numba.boolean, 2, "C"), i64, i64, i64, numba.types.Array(numba.int64, 2, "C"))]


def _frontier_signatures():
    b2 = numba.types.Array(numba.boolean, 2, "C")
    return [numba.void(numba.types.Array(numba.float32, 2, "C"), b2, numba.float32, numba.int64, b2)]


def coarse_grid(mask: np.ndarray, block_px: int = COARSE_BLOCK_PX) -> np.ndarray:
    """The blocks of the frame to compute at every pixel, from ``mask``, the coarse samples (every other pixel of every
    other row) above the coarse threshold: the ``block_px`` blocks that hold a sample within one coarse cell (2 pixels)
    of one above it, as a bool grid (block rows, block columns + 2) whose first and last columns stay False (compiled;
    :func:`coarse_blocks_reference` is the numpy twin of it and :func:`grid_boxes` together)."""
    cells = block_px // 2
    on = np.zeros((-(-mask.shape[0] // cells), -(-mask.shape[1] // cells) + 2), np.bool_)
    _coarse_grid_nb(np.ascontiguousarray(mask, np.bool_), cells, on)
    return on


def grid_boxes(on: np.ndarray, height: int, width: int, block_px: int = COARSE_BLOCK_PX) -> np.ndarray:
    """(n, 4) int64 boxes ``x0, y0, x1, y1`` of the blocks set in ``on`` (a grid of :func:`coarse_grid`'s layout) in an
    (height, width) frame, consecutive blocks of a row merged into one box, in row-major order (compiled)."""
    out = np.empty((on.size // 2 + 1, 4), np.int64)
    n = _grid_boxes_nb(on, block_px, height, width, out)
    return out[:n].copy()


def coarse_blocks(mask: np.ndarray, height: int, width: int, block_px: int = COARSE_BLOCK_PX) -> np.ndarray:
    """(n, 4) int64 boxes of :func:`coarse_grid`'s blocks (:func:`grid_boxes`); :func:`coarse_blocks_reference` is
    its numpy twin."""
    return grid_boxes(coarse_grid(mask, block_px), height, width, block_px)


@numba.njit(_grid_signatures(), cache=True, nogil=True)
def _coarse_grid_nb(mask, cells, on):
    ho, wo = mask.shape
    for r in range(ho):
        for c in range(wo):
            if mask[r, c]:
                for d in range(-1, 2):
                    br = min(max(r + d, 0), ho - 1) // cells
                    for e in range(-1, 2):
                        on[br, 1 + min(max(c + e, 0), wo - 1) // cells] = True


@numba.njit(_runs_signatures(), cache=True, nogil=True)
def _grid_boxes_nb(on, block_px, height, width, out):
    n = 0
    for by in range(on.shape[0]):
        for bx in range(on.shape[1] - 1):
            if on[by, bx + 1] != on[by, bx]:
                if on[by, bx + 1]:  # a run starts at block bx
                    out[n, 0] = bx * block_px
                    out[n, 1] = by * block_px
                else:  # it ended at block bx - 1
                    out[n, 2] = min(bx * block_px, width)
                    out[n, 3] = min((by + 1) * block_px, height)
                    n += 1
    return n


def blob_frontier(logits: np.ndarray, computed: np.ndarray, theta, block_px: int = COARSE_BLOCK_PX) -> np.ndarray:
    """The blocks to compute next so that no blob of pixels above ``theta`` (4-connected, as Algorithm 1 grows it) is
    cut by the edge of the computed region: ``computed`` (:func:`coarse_grid`'s layout) holds the blocks whose logits
    ``logits`` (the frame's, -inf elsewhere) has; returns a grid of the same layout with the blocks not computed that
    lie across an edge of a computed block from one of its pixels at or above ``theta`` (a float32 at or below the
    flood fill's threshold: the test errs on the side of computing more) (compiled;
    :func:`blob_frontier_reference` is its numpy twin)."""
    h, w = logits.shape
    want = (-(-h // block_px), -(-w // block_px) + 2)
    if computed.shape != want or computed.dtype != np.bool_ or logits.dtype != np.float32:
        raise ValueError(f"blob_frontier: need float32 logits and a bool grid of shape {want} for {w}x{h} logits and "
                         f"{block_px} px blocks (coarse_grid's layout), got {logits.dtype} logits and a {computed.dtype} grid of {computed.shape}")
    new = np.zeros_like(computed)
    _blob_frontier_nb(np.ascontiguousarray(logits), np.ascontiguousarray(computed), np.float32(theta), block_px, new)
    return new


@numba.njit(_frontier_signatures(), cache=True, nogil=True)
def _blob_frontier_nb(logits, computed, theta, block_px, new):
    h, w = logits.shape
    nby, nbx = computed.shape[0], computed.shape[1] - 2
    for by in range(nby):
        for bx in range(nbx):
            if not computed[by, bx + 1]:
                continue
            y0, x0 = by * block_px, bx * block_px
            y1, x1 = min(y0 + block_px, h), min(x0 + block_px, w)
            if by > 0 and not computed[by - 1, bx + 1] and not new[by - 1, bx + 1]:
                for x in range(x0, x1):
                    if logits[y0, x] >= theta:
                        new[by - 1, bx + 1] = True
                        break
            if by + 1 < nby and not computed[by + 1, bx + 1] and not new[by + 1, bx + 1]:
                for x in range(x0, x1):
                    if logits[y1 - 1, x] >= theta:
                        new[by + 1, bx + 1] = True
                        break
            if bx > 0 and not computed[by, bx] and not new[by, bx]:
                for y in range(y0, y1):
                    if logits[y, x0] >= theta:
                        new[by, bx] = True
                        break
            if bx + 1 < nbx and not computed[by, bx + 2] and not new[by, bx + 2]:
                for y in range(y0, y1):
                    if logits[y, x1 - 1] >= theta:
                        new[by, bx + 2] = True
                        break


def blob_frontier_reference(logits: np.ndarray, computed: np.ndarray, theta, block_px: int = COARSE_BLOCK_PX) -> np.ndarray:
    """The plain numpy twin of :func:`blob_frontier` (the same grid)."""
    h, w = logits.shape
    above = logits >= np.float32(theta)
    new = np.zeros_like(computed)
    inner = computed[:, 1:-1]
    for by, bx in zip(*np.nonzero(inner)):
        y0, x0 = by * block_px, bx * block_px
        y1, x1 = min(y0 + block_px, h), min(x0 + block_px, w)
        edges = ((by - 1, bx, above[y0, x0:x1]), (by + 1, bx, above[y1 - 1, x0:x1]),
                 (by, bx - 1, above[y0:y1, x0]), (by, bx + 1, above[y0:y1, x1 - 1]))
        for ny, nx, edge in edges:
            if 0 <= ny < inner.shape[0] and 0 <= nx < inner.shape[1] and not inner[ny, nx] and edge.any():
                new[ny, nx + 1] = True
    return new


def coarse_blocks_reference(mask: np.ndarray, height: int, width: int, block_px: int = COARSE_BLOCK_PX) -> np.ndarray:
    """The plain numpy twin of :func:`coarse_blocks` (the same boxes in the same order)."""
    rr, cc = np.nonzero(mask)
    if len(rr) == 0:
        return np.zeros((0, 4), np.int64)
    cells = block_px // 2
    hb, wb = -(-mask.shape[0] // cells), -(-mask.shape[1] // cells)
    on = np.zeros((hb, wb + 2), np.bool_)  # a False column on each side ends every run
    for d in (-1, 1, 0):  # a sample's neighbours one cell away: the blocks they fall in
        r = np.clip(rr + d, 0, mask.shape[0] - 1) // cells
        for e in (-1, 1, 0):
            on[r, 1 + np.clip(cc + e, 0, mask.shape[1] - 1) // cells] = True
    by, bx = np.nonzero(on[:, 1:] != on[:, :-1])  # run edges, in row-major order: start, stop, start, stop, ...
    y0 = by[0::2] * block_px
    return np.stack([bx[0::2] * block_px, y0, np.minimum(bx[1::2] * block_px, width), np.minimum(y0 + block_px, height)], axis=1).astype(np.int64)


key_cache_on_callees(globals())  # the helpers live in this file, so an edit of them changes the kernel's own cache key too
