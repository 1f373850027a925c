"""Algorithm 1 of the paper: the ball's pixels from the probability image, and top-K candidates.

Algorithm 1 (``find ball pixels``) takes the most probable pixel ``(a, b)`` (line 1), returns
nothing if ``B_ab < T_h`` (lines 2-4), else grows the set ``O`` from ``(a, b)`` by breadth-first
search over neighbours with ``B > T_l`` (lines 5-15). We run it on the *logit* image with the
thresholds mapped through ``logit(T)``; the sigmoid is monotonic so the pixel sets are identical.

Choices the paper leaves open, fixed here:

* Neighbourhood: **4-connected** (up, down, left, right, in that order). It keeps a ball apart
  from a distractor that touches it only at a corner; a ball blob is a filled disk, so 4- and
  8-connectivity give the same pixels for it.
* Sub-pixel centre: the centroid of the blob's pixels weighted by ``B - T_l`` (zero at the blob's
  edge, so a pixel crossing ``T_l`` enters smoothly instead of jumping the centre by 1/area px).
* Score: the blob's peak probability ``B_ab``.
* Top-K (ours): after a blob is found, its pixels are suppressed and Algorithm 1 repeats on the
  rest of the image. The candidates are thus the connected components of ``{B > T_l}`` with a peak
  ``>= T_h``, in order of decreasing peak. Blobs failing the shape test (area, fill ratio, aspect)
  are suppressed too but not reported; at most ``max_seeds`` blobs are grown per image.
* Ties in the argmax go to the first pixel in row-major order (``np.argmax``). Where only some boxes of the image
  hold logits and the rest is -inf (rt2's coarse-to-fine full frame), the argmax looks in the boxes alone
  (``seed_boxes``; :func:`argmax_in_boxes`, the same pixel).

The flood fill has a numba implementation (``backend="numba"``, the default) and a plain Python
reference (``backend="python"``); tests check they return identical blobs.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numba
import numpy as np
from checks.numba_cache import key_cache_on_callees

__all__ = ["BACKENDS", "Blobs", "argmax_in_boxes", "argmax_in_boxes_reference", "find_blobs"]

_DR = np.array([-1, 1, 0, 0], dtype=np.int64)  # neighbour order: up, down, left, right
_DC = np.array([0, 0, -1, 1], dtype=np.int64)


@dataclass(frozen=True, eq=False)
class Blobs:
    """Blobs found in one logit image, best first.

    centers_px : (k, 2) sub-pixel centres (x = column, y = row), pixel (0, 0) = centre of the top-left pixel
    peak_logits : (k,) logit of each blob's most probable pixel (its score is ``sigmoid`` of it)
    boxes : (k, 4) int ``[x_min, y_min, x_max, y_max]``, inclusive pixel indices
    areas_px : (k,) number of pixels in each blob
    n_grown : blobs flood-filled, including those rejected by the shape test
    """

    centers_px: np.ndarray
    peak_logits: np.ndarray
    boxes: np.ndarray
    areas_px: np.ndarray
    n_grown: int

    def __len__(self) -> int:
        return len(self.areas_px)


# -- flood fill (Algorithm 1, lines 5-15) -----------------------------------------------------------
@numba.njit(cache=True, nogil=True)
def _fill_numba(work, r0, c0, t_low, p_low, qr, qc):
    """Grow the blob at (r0, c0) over 4-neighbours with logit > t_low; suppress its pixels to -inf.

    Returns (area, sum_w, sum_wx, sum_wy, x_min, y_min, x_max, y_max), w = sigmoid(logit) - p_low.
    """
    h, w = work.shape
    v = work[r0, c0]
    work[r0, c0] = -np.inf  # O <- {(a, b)}; -inf marks membership and suppresses the pixel
    wt = 1.0 / (1.0 + math.exp(-np.float64(v))) - p_low
    sw, sx, sy = wt, wt * c0, wt * r0
    xmin, xmax, ymin, ymax = c0, c0, r0, r0
    qr[0] = r0
    qc[0] = c0
    head, tail = 0, 1
    while head < tail:  # while q is not empty
        r = qr[head]
        c = qc[head]
        head += 1
        for k in range(4):  # for each neighbour y of x
            rr = r + _DR[k]
            cc = c + _DC[k]
            if rr < 0 or rr >= h or cc < 0 or cc >= w:
                continue
            v = work[rr, cc]
            if v > t_low:  # not y in O (members are -inf) and B_y > T_l
                work[rr, cc] = -np.inf
                qr[tail] = rr
                qc[tail] = cc
                tail += 1
                wt = 1.0 / (1.0 + math.exp(-np.float64(v))) - p_low
                sw += wt
                sx += wt * cc
                sy += wt * rr
                xmin = min(xmin, cc)
                xmax = max(xmax, cc)
                ymin = min(ymin, rr)
                ymax = max(ymax, rr)
    return tail, sw, sx, sy, xmin, ymin, xmax, ymax


def _fill_python(work, r0, c0, t_low, p_low, qr, qc):
    """Reference of :func:`_fill_numba`: the same search and sums in plain Python (``qr``/``qc`` unused)."""
    h, w = work.shape
    v = float(work[r0, c0])
    work[r0, c0] = -np.inf
    wt = 1.0 / (1.0 + math.exp(-v)) - p_low
    sw, sx, sy = wt, wt * c0, wt * r0
    xmin, xmax, ymin, ymax = c0, c0, r0, r0
    queue = deque([(r0, c0)])
    area = 1
    while queue:
        r, c = queue.popleft()
        for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            rr, cc = r + dr, c + dc
            if not (0 <= rr < h and 0 <= cc < w):
                continue
            v = float(work[rr, cc])
            if v > t_low:
                work[rr, cc] = -np.inf
                queue.append((rr, cc))
                area += 1
                wt = 1.0 / (1.0 + math.exp(-v)) - p_low
                sw += wt
                sx += wt * cc
                sy += wt * rr
                xmin, xmax, ymin, ymax = min(xmin, cc), max(xmax, cc), min(ymin, rr), max(ymax, rr)
    return area, sw, sx, sy, xmin, ymin, xmax, ymax


@numba.njit(numba.int64(numba.types.Array(numba.float32, 2, "C"), numba.types.Array(numba.int64, 2, "C")), cache=True, nogil=True)
def argmax_in_boxes(work, boxes):
    """The flat index of ``np.argmax(work)`` when every logit outside the boxes ``boxes`` ((n, 4) int64 ``x0, y0, x1,
    y1``, inside ``work``: not checked here, :func:`find_blobs` checks them) is -inf: the largest value in the boxes, the
    first in row-major order among equals (-1 without a box; :func:`argmax_in_boxes_reference` is its numpy twin). The
    coarse-to-fine full frame's seeds, without reading the frame's -inf."""
    w = work.shape[1]
    best, at = -np.inf, -1
    for b in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[b, 0], boxes[b, 1], boxes[b, 2], boxes[b, 3]
        for r in range(y0, y1):
            row = work[r]
            for c in range(x0, x1):
                v = row[c]
                if v > best or (v == best and (at < 0 or r * w + c < at)):
                    best, at = v, r * w + c
    return at


def argmax_in_boxes_reference(work: np.ndarray, boxes: np.ndarray) -> int:
    """The plain numpy twin of :func:`argmax_in_boxes`."""
    if len(boxes) == 0:
        return -1
    w = work.shape[1]
    idx = np.concatenate([(np.arange(y0, y1)[:, None] * w + np.arange(x0, x1)[None, :]).ravel() for x0, y0, x1, y1 in boxes])
    idx = np.sort(idx)
    return int(idx[np.argmax(work.reshape(-1)[idx])])


def _checked_boxes(boxes, shape) -> np.ndarray:
    """``boxes`` as the (n, 4) C-ordered int64 array :func:`argmax_in_boxes` reads (it does not check its bounds), or a
    ValueError naming ``seed_boxes``: integer ``x0, y0, x1, y1`` with ``0 <= x0 < x1 <= W`` and ``0 <= y0 < y1 <= H``."""
    arr = np.asarray(boxes)
    if arr.ndim != 2 or arr.shape[1:] != (4,) or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"seed_boxes must be an (n, 4) integer array of x0, y0, x1, y1, got shape {arr.shape} of {arr.dtype}")
    arr = np.ascontiguousarray(arr, np.int64)
    h, w = shape
    x0, y0, x1, y1 = arr.T
    bad = ~((0 <= x0) & (x0 < x1) & (x1 <= w) & (0 <= y0) & (y0 < y1) & (y1 <= h))
    if bad.any():
        raise ValueError(f"seed_boxes must lie inside the {w}x{h} logits with x0 < x1 and y0 < y1, got {arr[bad][0].tolist()}")
    return arr


#: flood-fill implementations by name
BACKENDS = {"numba": _fill_numba, "python": _fill_python}


def find_blobs(
    logits: np.ndarray,
    t_high_logit: float,
    t_low_logit: float,
    *,
    max_blobs: int = 1,
    max_seeds: int | None = None,
    min_area_px: int = 1,
    max_area_px: int | None = None,
    min_fill_ratio: float = 0.0,
    max_aspect: float = math.inf,
    backend: str = "numba",
    overwrite: bool = False,
    queues: tuple[np.ndarray, np.ndarray] | None = None,
    seed_boxes: np.ndarray | None = None,
) -> Blobs:
    """Algorithm 1, repeated for up to ``max_blobs`` candidates.

    logits : (H, W) float32 logit image (``logit(B)``)
    t_high_logit, t_low_logit : ``logit(T_h)`` and ``logit(T_l)``, ``t_low_logit < t_high_logit``
    max_blobs : candidates to report (1 with ``max_seeds=1`` and no shape test = the paper's Algorithm 1)
    max_seeds : blobs to grow at most, accepted or not (default ``max(4 * max_blobs, 8)``)
    min_area_px, max_area_px : accepted blob sizes, pixels (``None`` = unbounded)
    min_fill_ratio : accepted ``area / (box width * box height)`` (a disk fills pi/4 of its box)
    max_aspect : accepted ``max(box w, box h) / min(box w, box h)``
    backend : "numba" or "python" (the reference)
    overwrite : allow suppressing found blobs in ``logits`` itself instead of a copy
    queues : optional reusable (rows, cols) int64 arrays of at least H * W entries for the flood
        fill's queue (``backend="numba"``; default: new ones per call)
    seed_boxes : optional (n, 4) int64 boxes ``x0, y0, x1, y1`` outside which every logit is -inf: the argmax looks
        in them alone (:func:`argmax_in_boxes`: the same pixel; the blobs' pixels lie in them)
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {sorted(BACKENDS)}, got {backend!r}")
    logits = np.asarray(logits)
    if logits.ndim != 2 or logits.size == 0:
        raise ValueError(f"logits must be a non-empty (H, W) array, got shape {logits.shape}")
    if not t_low_logit < t_high_logit:
        raise ValueError(f"need t_low_logit < t_high_logit, got {t_low_logit} and {t_high_logit}")
    if max_blobs < 1:
        raise ValueError(f"max_blobs must be >= 1, got {max_blobs}")
    if seed_boxes is not None:
        seed_boxes = _checked_boxes(seed_boxes, logits.shape)
    max_seeds = max(4 * max_blobs, 8) if max_seeds is None else int(max_seeds)
    max_area = math.inf if max_area_px is None else max_area_px
    if overwrite and logits.dtype == np.float32 and logits.flags.c_contiguous and logits.flags.writeable:
        work = logits
    else:
        work = np.array(logits, dtype=np.float32, order="C")
    fill = BACKENDS[backend]
    h, w = work.shape
    flat = work.reshape(-1)
    p_low = 1.0 / (1.0 + math.exp(-float(t_low_logit)))
    t_low = np.float32(t_low_logit)
    if backend != "numba":
        qr = qc = None
    elif queues is not None and len(queues[0]) >= h * w and len(queues[1]) >= h * w:
        qr, qc = queues
    else:
        qr, qc = np.empty(h * w, dtype=np.int64), np.empty(h * w, dtype=np.int64)

    rows = []
    grown = 0
    while grown < max_seeds and len(rows) < max_blobs:
        idx = int(np.argmax(flat)) if seed_boxes is None else argmax_in_boxes(work, seed_boxes)  # line 1: (a, b) = argmax B (first in row-major order on ties)
        if idx < 0:  # no box
            break
        peak = float(flat[idx])
        if not peak >= t_high_logit:  # lines 2-4: B_ab < T_h -> no (more) ball
            break
        r0, c0 = divmod(idx, w)
        area, sw, sx, sy, xmin, ymin, xmax, ymax = fill(work, r0, c0, t_low, p_low, qr, qc)  # lines 5-15
        grown += 1
        bw, bh = xmax - xmin + 1, ymax - ymin + 1
        if not (min_area_px <= area <= max_area):
            continue
        if area < min_fill_ratio * bw * bh or max(bw, bh) > max_aspect * min(bw, bh):
            continue
        rows.append((sx / sw, sy / sw, peak, xmin, ymin, xmax, ymax, area))

    arr = np.array(rows, dtype=np.float64).reshape(-1, 8)
    return Blobs(
        centers_px=arr[:, 0:2].copy(),
        peak_logits=arr[:, 2].copy(),
        boxes=arr[:, 3:7].astype(np.int64),
        areas_px=arr[:, 7].astype(np.int64),
        n_grown=grown,
    )


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
