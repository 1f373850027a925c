"""Algorithm 1 (find_blobs): semantics, numba vs the plain Python reference, top-K and shape test."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest

from tracker.detection.blobs import argmax_in_boxes, argmax_in_boxes_reference, find_blobs
from tracker.detection.model import logit


def _algorithm1_sets(B, t_high, t_low):
    """The paper's Algorithm 1, literally (sets, 4-neighbours), on a probability image: returns O."""
    a, b = np.unravel_index(np.argmax(B), B.shape)
    if B[a, b] < t_high:
        return set()
    O = {(a, b)}
    q = deque([(a, b)])
    while q:
        r, c = q.popleft()
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= rr < B.shape[0] and 0 <= cc < B.shape[1] and (rr, cc) not in O and B[rr, cc] > t_low:
                q.append((rr, cc))
                O.add((rr, cc))
    return O


def _gaussian_blobs(rng, h=60, w=80, n=4):
    yy, xx = np.mgrid[0:h, 0:w]
    lg = np.full((h, w), -6.0)
    for _ in range(n):
        cu, cv, s, amp = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(1.0, 4.0), rng.uniform(2, 10)
        lg = np.maximum(lg, -6.0 + amp * np.exp(-((xx - cu) ** 2 + (yy - cv) ** 2) / (2 * s * s)))
    return (lg + rng.normal(0, 0.3, lg.shape)).astype(np.float32)


# -- smoke -------------------------------------------------------------------------------------------
def test_smoke_single_blob():
    lg = np.full((20, 20), -5.0, np.float32)
    lg[8:11, 5:8] = 3.0
    lg[9, 6] = 4.0
    blobs = find_blobs(lg, logit(0.9), logit(0.5))
    assert len(blobs) == 1
    np.testing.assert_allclose(blobs.centers_px[0], [6.0, 9.0])
    assert blobs.areas_px[0] == 9
    np.testing.assert_array_equal(blobs.boxes[0], [5, 8, 7, 10])
    assert blobs.peak_logits[0] == pytest.approx(4.0)
    assert lg[9, 6] == 4.0  # input untouched without overwrite=True


def test_below_high_threshold_returns_nothing():
    lg = np.full((10, 10), -1.0, np.float32)
    assert len(find_blobs(lg, 0.0, -2.0)) == 0


# -- agreement with the paper's algorithm and between backends --------------------------------------
@pytest.mark.parametrize("seed", range(12))
def test_matches_literal_algorithm1(seed):
    rng = np.random.default_rng(seed)
    lg = _gaussian_blobs(rng)
    B = 1 / (1 + np.exp(-lg.astype(np.float64)))
    t_high, t_low = 0.9, 0.3
    O = _algorithm1_sets(B, t_high, t_low)
    blobs = find_blobs(lg, logit(t_high), logit(t_low), max_blobs=1, max_seeds=1)
    if not O:
        assert len(blobs) == 0
        return
    rows, cols = np.array(sorted(O)).T
    assert blobs.areas_px[0] == len(O)
    np.testing.assert_array_equal(blobs.boxes[0], [cols.min(), rows.min(), cols.max(), rows.max()])
    wts = B[rows, cols] - t_low
    np.testing.assert_allclose(blobs.centers_px[0], [np.sum(wts * cols) / wts.sum(), np.sum(wts * rows) / wts.sum()], atol=1e-9)


def _plateau_image(rng, h, w):
    """Quantised values: many ties for the argmax and plateaus for the flood fill."""
    return rng.integers(-3, 4, size=(h, w)).astype(np.float32)


@pytest.mark.parametrize("seed", range(20))
def test_numba_equals_reference(seed):
    rng = np.random.default_rng(100 + seed)
    make = _plateau_image if seed % 2 else (lambda r, h, w: _gaussian_blobs(r, h, w, n=6))
    lg = make(rng, int(rng.integers(1, 50)), int(rng.integers(1, 70)))
    kw = dict(max_blobs=int(rng.integers(1, 6)), min_area_px=int(rng.integers(1, 4)), min_fill_ratio=float(rng.uniform(0, 0.5)))
    a = find_blobs(lg, 1.5, -0.5, backend="numba", **kw)
    b = find_blobs(lg, 1.5, -0.5, backend="python", **kw)
    assert a.n_grown == b.n_grown
    for name in ("centers_px", "peak_logits", "boxes", "areas_px"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_ties_go_to_first_pixel_in_row_major_order():
    lg = np.full((9, 9), -5.0, np.float32)
    lg[2, 6] = lg[6, 1] = 2.0  # two separate one-pixel blobs with equal peaks
    for backend in ("numba", "python"):
        blobs = find_blobs(lg, 1.0, 0.0, max_blobs=2, backend=backend)
        np.testing.assert_allclose(blobs.centers_px, [[6.0, 2.0], [1.0, 6.0]], atol=1e-12)


def test_four_connectivity():
    lg = np.full((6, 6), -5.0, np.float32)
    lg[2, 2] = 3.0
    lg[3, 3] = 2.0  # diagonal neighbour: a separate blob
    blobs = find_blobs(lg, 1.0, 0.0, max_blobs=3)
    assert list(blobs.areas_px) == [1, 1]


# -- top-K and the shape test --------------------------------------------------------------------------
def test_top_k_in_order_of_peak_and_suppression():
    lg = np.full((40, 40), -5.0, np.float32)
    peaks = {(5, 5): 2.0, (20, 30): 4.0, (33, 10): 3.0}
    for (r, c), v in peaks.items():
        lg[r - 1 : r + 2, c - 1 : c + 2] = 1.0
        lg[r, c] = v
    blobs = find_blobs(lg, 1.5, 0.0, max_blobs=5)
    np.testing.assert_allclose(blobs.peak_logits, [4.0, 3.0, 2.0])
    np.testing.assert_allclose(blobs.centers_px[:, ::-1], [[20, 30], [33, 10], [5, 5]], atol=1e-9)
    assert len(find_blobs(lg, 1.5, 0.0, max_blobs=2)) == 2


def test_shape_test_rejects_and_continues():
    lg = np.full((40, 60), -5.0, np.float32)
    lg[5:8, 2:50] = 5.0  # a long bar (a table line): highest peak, but aspect 16
    lg[20:25, 20:25] = 3.0  # a compact blob
    blobs = find_blobs(lg, 1.0, 0.0, max_blobs=2, max_aspect=3.0)
    assert len(blobs) == 1 and blobs.n_grown == 2
    np.testing.assert_allclose(blobs.centers_px[0], [22.0, 22.0])
    assert len(find_blobs(lg, 1.0, 0.0, max_blobs=2, max_area_px=20)) == 0
    assert len(find_blobs(lg, 1.0, 0.0, max_blobs=2, max_seeds=1, max_aspect=3.0)) == 0


# -- statistical: sub-pixel centroid of a smooth blob -------------------------------------------------
def test_centroid_of_symmetric_blobs_is_unbiased():
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:40, 0:40]
    errs = []
    for _ in range(200):
        cu, cv = rng.uniform(15, 25, 2)
        lg = (8.0 - ((xx - cu) ** 2 + (yy - cv) ** 2) / 2.0).astype(np.float32)
        c = find_blobs(lg, 2.0, -1.0).centers_px[0]
        errs.append(c - [cu, cv])
    errs = np.array(errs)
    assert np.abs(errs.mean(axis=0)).max() < 0.01
    assert np.abs(errs).max() < 0.05


# -- bad input -----------------------------------------------------------------------------------------
def test_bad_arguments():
    lg = np.zeros((5, 5), np.float32)
    with pytest.raises(ValueError, match="backend must be one of"):
        find_blobs(lg, 1.0, 0.0, backend="cuda")
    with pytest.raises(ValueError, match=r"non-empty \(H, W\).*\(5, 5, 3\)"):
        find_blobs(np.zeros((5, 5, 3)), 1.0, 0.0)
    with pytest.raises(ValueError, match="t_low_logit < t_high_logit"):
        find_blobs(lg, 0.0, 1.0)
    with pytest.raises(ValueError, match="max_blobs must be >= 1"):
        find_blobs(lg, 1.0, 0.0, max_blobs=0)
    assert math.isfinite(logit(0.5)) and logit(0.5) == 0.0


@pytest.mark.parametrize("seed", range(5))
def test_the_argmax_in_boxes_is_numpys_argmax_where_the_rest_is_minus_inf(seed):
    """The coarse-to-fine full frame's seeds: the argmax over its computed boxes alone is np.argmax of the frame (ties
    to the first pixel in row-major order, boxes in any order), its numpy twin the same; and Algorithm 1 with
    ``seed_boxes`` finds the same blobs."""
    rng = np.random.default_rng(seed)
    for _ in range(30):
        h, w = (int(v) for v in rng.integers(1, 70, 2))
        work = np.full((h, w), -np.inf, np.float32)
        boxes = []
        for _ in range(int(rng.integers(1, 6))):
            x0, y0 = int(rng.integers(0, w)), int(rng.integers(0, h))
            x1, y1 = int(rng.integers(x0 + 1, w + 1)), int(rng.integers(y0 + 1, h + 1))
            boxes.append((x0, y0, x1, y1))
            work[y0:y1, x0:x1] = rng.integers(-3, 4, (y1 - y0, x1 - x0))  # few values: many ties
        boxes = np.array(boxes, np.int64)[rng.permutation(len(boxes))]
        want = int(np.argmax(work))
        assert argmax_in_boxes(work, boxes) == want == argmax_in_boxes_reference(work, boxes)
        plain = find_blobs(work.copy(), 1.5, 0.5, max_blobs=4)
        boxed = find_blobs(work.copy(), 1.5, 0.5, max_blobs=4, seed_boxes=boxes)
        for a, b in ((plain.centers_px, boxed.centers_px), (plain.areas_px, boxed.areas_px), (plain.boxes, boxed.boxes)):
            assert a.tobytes() == b.tobytes()
    empty = np.zeros((0, 4), np.int64)
    assert argmax_in_boxes(np.zeros((3, 3), np.float32), empty) == -1 == argmax_in_boxes_reference(np.zeros((3, 3), np.float32), empty)
    assert len(find_blobs(np.zeros((3, 3), np.float32), 1.5, 0.5, seed_boxes=empty)) == 0


@pytest.mark.parametrize("boxes, match", [
    (np.array([[0, 0, 5]]), r"\(n, 4\) integer array"),
    (np.array([[0.0, 0.0, 5.0, 5.0]]), r"\(n, 4\) integer array"),
    (np.array([[0, 0, 11, 5]]), r"inside the 10x8 logits .*\[0, 0, 11, 5\]"),
    (np.array([[-1, 0, 5, 5]]), "inside the 10x8 logits"),
    (np.array([[4, 0, 4, 5]]), "x0 < x1"),
    (np.array([[0, 6, 5, 3]]), "y0 < y1"),
])
def test_find_blobs_refuses_seed_boxes_outside_its_logits(boxes, match):
    """The compiled argmax does not check its boxes' bounds: find_blobs does, before reading anything."""
    with pytest.raises(ValueError, match=match):
        find_blobs(np.zeros((8, 10), np.float32), 1.5, 0.5, seed_boxes=boxes)
