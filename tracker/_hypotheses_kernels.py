"""Compiled twins of :class:`tracker.hypotheses.BallHypotheses`' per-frame-set steps (``backend="numba"``).

The numpy methods of ``BallHypotheses`` are the reference; these kernels do the same on the same arrays
in place, in one call per frame set (~100x less than the numpy version's small-array overhead, which
was a fifth of a window-search frame set). ``tests/tracker/test_hypotheses.py`` checks that both agree
on random scenes of several balls.

Options are passed as one float64 array (:data:`OPTION_FIELDS` order).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from checks.numba_cache import key_cache_on_callees

__all__ = ["OPTION_FIELDS", "update_kernel", "wants_full_frame_kernel"]

#: the HypothesisOptions fields in the order of the kernels' ``o`` array
OPTION_FIELDS = ("gate_m", "gate_growth_mps", "forget_s", "forget_other_s", "speed_window_s", "min_samples",
                 "min_speed_mps", "min_height_m", "max_withhold_s", "full_frame_period_s")


@numba.njit(cache=True, nogil=True)
def _clear(i, T, XM, count, in_play, other):
    count[i] = 0
    in_play[i] = False
    other[i] = False
    for k in range(T.shape[1]):
        T[i, k] = np.nan
        XM[i, k, 0] = np.nan
        XM[i, k, 1] = np.nan
        XM[i, k, 2] = np.nan


@numba.njit(cache=True, nogil=True)
def _classify(t, i, T, XM, in_play, o):
    """The least-squares speed test of slot i (``BallHypotheses._classify`` for one slot)."""
    h = T.shape[1]
    sw = o[4]
    nw = 0.0
    for k in range(h):
        if t - T[i, k] <= sw:
            nw += 1.0
    den = max(nw, 1.0)
    st = 0.0
    sx = np.zeros(3)
    for k in range(h):
        if t - T[i, k] <= sw:
            st += T[i, k] - t
            for c in range(3):
                sx[c] += XM[i, k, c]
    t_mean = st / den
    x_mean = sx / den
    sxx = 0.0
    sxy = np.zeros(3)
    for k in range(h):
        if t - T[i, k] <= sw:
            dt = (T[i, k] - t) - t_mean
            sxx += dt * dt
            for c in range(3):
                sxy[c] += dt * (XM[i, k, c] - x_mean[c])
        else:  # weight 0: (0 - t_mean) * 0
            pass
    if sxx > 0.0:
        vx, vy = sxy[0] / sxx, sxy[1] / sxx
        fast = math.hypot(vx, vy) >= o[6]
    else:
        fast = False
    high = XM[i, 0, 2] >= o[7]
    in_play[i] = nw >= o[5] and sxx > 0.0 and fast and high


@numba.njit(cache=True, nogil=True)
def update_kernel(t, X, T, XM, count, in_play, other, lead, withhold, o):
    """``BallHypotheses.update`` on its arrays: returns (row, lead, switched, withhold)."""
    m = T.shape[0]
    n = X.shape[0]
    switched = False
    for i in range(m):  # drop the old
        if count[i] > 0:
            lim = o[3] if other[i] else o[2]
            if not (t - T[i, 0] <= lim):
                _clear(i, T, XM, count, in_play, other)
                if lead >= 0 and i == lead:
                    lead = -1
    if n == 0:
        return -1, lead, switched, withhold
    # associate: nearest pairs within the gate first (constant-velocity predictions)
    d = np.empty((m, n))
    sw = o[4]
    for i in range(m):
        dt = T[i, 0] - T[i, 1]
        use_v = count[i] >= 2 and dt > 0.0
        ahead = t - T[i, 0]
        if ahead > sw:
            ahead = sw
        gate = o[0] + o[1] * (t - T[i, 0])
        for j in range(n):
            s = 0.0
            for c in range(3):
                v = (XM[i, 0, c] - XM[i, 1, c]) / dt if use_v else 0.0
                p = XM[i, 0, c] + v * ahead
                s += (p - X[j, c]) * (p - X[j, c])
            dist = math.sqrt(s)
            d[i, j] = dist if dist <= gate else np.inf
    slots = np.full(n, -1, np.int64)
    taken = np.zeros(m, np.bool_)
    for _ in range(min(m, n)):
        best, bi, bj = np.inf, -1, -1
        for i in range(m):
            for j in range(n):
                if d[i, j] < best:
                    best, bi, bj = d[i, j], i, j
        if bi < 0:
            break
        slots[bj] = bi
        taken[bi] = True
        for j in range(n):
            d[bi, j] = np.inf
        for i in range(m):
            d[i, bj] = np.inf
    for j in range(n):
        if slots[j] >= 0:
            continue
        i = -1
        for q in range(m):
            if count[q] == 0 and not taken[q]:
                i = q
                break
        if i < 0:  # the hypothesis seen longest ago (never the lead while another can go) makes room
            n_free = 0
            for q in range(m):
                n_free += not taken[q]
            best = -np.inf
            i = 0
            for q in range(m):
                a = -np.inf if taken[q] or (lead >= 0 and q == lead and n_free > 1) else t - T[q, 0]
                if q == 0 or a > best:
                    best, i = a, q
        _clear(i, T, XM, count, in_play, other)
        if i == lead:
            lead = -1
        slots[j] = i
        taken[i] = True
    # push the positions
    h = T.shape[1]
    for j in range(n):
        i = slots[j]
        for k in range(h - 1, 0, -1):
            T[i, k] = T[i, k - 1]
            for c in range(3):
                XM[i, k, c] = XM[i, k - 1, c]
        T[i, 0] = t
        for c in range(3):
            XM[i, 0, c] = X[j, c]
        count[i] += 1
    for j in range(n):
        _classify(t, slots[j], T, XM, in_play, o)
    # the lead
    lead_row = -1
    for j in range(n):
        if slots[j] == lead:
            lead_row = j
            break
    any_in_play = False
    for j in range(n):
        any_in_play = any_in_play or in_play[slots[j]]
    if any_in_play:  # (a)
        if lead_row >= 0 and in_play[lead]:
            row = lead_row
        else:
            row, best = -1, -1
            for j in range(n):
                if in_play[slots[j]] and count[slots[j]] > best:
                    row, best = j, count[slots[j]]
            switched = lead >= 0
        for j in range(n):
            other[slots[j]] = True
        other[slots[row]] = False
    elif lead_row >= 0:  # (b)
        row = lead_row
    else:
        row, n_rows = -1, 0
        for j in range(n):
            if not other[slots[j]]:
                n_rows += 1
                if row < 0:
                    row = j
        if n_rows == 0:  # (c) only known other balls
            return -1, -1, switched, np.nan
        if n_rows > 1:  # (d)
            if math.isnan(withhold):
                withhold = t
            if t - withhold < o[8]:
                return -1, -1, switched, withhold
    return row, slots[row], switched, np.nan


@numba.njit(cache=True, nogil=True)
def wants_full_frame_kernel(t, T, count, in_play, other, lead, withhold, last_full, o):
    """``BallHypotheses.wants_full_frame``."""
    if not math.isnan(withhold):
        return True
    if lead >= 0 and in_play[lead]:
        return False
    for i in range(T.shape[0]):
        if i != lead and count[i] > 0 and count[i] < o[5] and not other[i] and t - T[i, 0] <= o[4]:
            return True
    return t - last_full >= o[9]


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
