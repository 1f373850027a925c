"""The joint reference a robot follows: a piecewise function of time built from commanded trajectories.

A new trajectory replaces the reference from ``max(t_s[0], now)`` on (contract in robot_models/robot_interface.py);
each piece is a cubic Hermite spline through the commanded ``(t_s, q, qdot)`` (or a not-a-knot cubic
spline through ``(t_s, q)`` when no velocities are given) and holds its last point after its end.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicHermiteSpline, CubicSpline

__all__ = ["PiecewiseReference"]


class PiecewiseReference:
    """Reference ``(q, qdot, qddot)`` of time. Starts holding ``q_hold`` (7,) forever."""

    def __init__(self, q_hold: np.ndarray):
        q_hold = np.asarray(q_hold, float)
        # pieces: (start time s, end time s, spline or None, q held after the end)
        self._pieces: list[tuple[float, float, object, np.ndarray]] = [(-np.inf, -np.inf, None, q_hold.copy())]

    def replace_from(self, t_s: np.ndarray, q: np.ndarray, qdot: np.ndarray | None, now_s: float) -> float:
        """Install a validated trajectory from ``max(t_s[0], now_s)`` on; returns that start time."""
        spline = CubicSpline(t_s, q, axis=0) if qdot is None else CubicHermiteSpline(t_s, q, qdot, axis=0)
        start = max(float(t_s[0]), float(now_s))
        kept = [p for p in self._pieces if p[0] < start]
        # pieces that started before now and were already superseded before now can never be used again
        while len(kept) > 1 and kept[1][0] <= now_s:
            kept.pop(0)
        kept.append((start, float(t_s[-1]), spline, np.array(q[-1], float)))
        self._pieces = kept
        return start

    @property
    def end_s(self) -> float:
        """Time after which the reference is constant (the last piece's end)."""
        return self._pieces[-1][1]

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reference at times ``t`` (n,) s, ascending: ``q, qdot, qddot`` each (n, 7)."""
        n_j = self._pieces[0][3].shape[0]
        q = np.empty((t.shape[0], n_j))
        qd = np.zeros_like(q)
        qdd = np.zeros_like(q)
        starts = np.array([p[0] for p in self._pieces])
        which = np.searchsorted(starts, t, side="right") - 1  # the latest piece started at or before t
        for i in np.unique(which):  # a handful of pieces per block, not one per tick
            sel = which == i
            _, end, spline, q_end = self._pieces[i]
            ts = t[sel]
            inside = ts <= end
            block = np.broadcast_to(q_end, (ts.shape[0], n_j)).copy()
            block_d = np.zeros_like(block)
            block_dd = np.zeros_like(block)
            if spline is not None and inside.any():
                block[inside] = spline(ts[inside])
                block_d[inside] = spline(ts[inside], 1)
                block_dd[inside] = spline(ts[inside], 2)
            q[sel], qd[sel], qdd[sel] = block, block_d, block_dd
        return q, qd, qdd
