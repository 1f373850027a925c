"""Where to look next: the ball's predicted 3D position at a new frame time, projected into every camera.

Used by :class:`tracker.Tracker` for its region-of-interest (ROI) search. Not in the paper (its
detector always searches the full frame, Sec. 2.1); this is our addition, see docs/pipeline.md.

Prediction from the last *confirmed* estimates (``Status.OK``) only:

* two confirmed estimates ``(t0, X0)``, ``(t1, X1)`` with ``t1 - t0 <= max_gap_s``:
  constant velocity, ``X(t) = X1 + (X1 - X0) / (t1 - t0) * (t - t1)``;
* else one confirmed estimate: the last position, ``X(t) = X1``;
* no prediction when ``t - t1 > max_gap_s`` (the ball may be anywhere), after :meth:`reset`, or
  when time did not advance (``t <= t1``).

``max_gap_s`` stretches when the frame sets the tracker is given are themselves far apart: a live tracker
whose full-frame search takes longer than a few frame periods (nine 1440x1080 cameras: 65-110 ms on a 2-core
machine) is handed the newest frame set each time, so its confirmed estimates are always more than 50 ms
old and, with a fixed gap, it never predicts, never searches a window and never catches up. The gap used
is ``max(max_gap_s, STRETCH x the shorter of the last two intervals between frame sets)`` (at most
``MAX_STRETCHED_GAP_S``): one jump in time (a new flight, a recording's pause) stretches nothing, and a
tracker given every frame set at 100-200 Hz predicts exactly as with the fixed gap.

Gravity is ignored: over one 5 ms frame it moves the ball 0.12 mm, far inside any search window.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.distortion import distort, distort_point
from tracker.rig import Rig
from checks.numba_cache import key_cache_on_callees

__all__ = ["BACKENDS", "MAX_STRETCHED_GAP_S", "STRETCH", "MotionPredictor", "project_point", "project_point_numba"]

STRETCH = 2.0  #: the gap is at least this many intervals between the frame sets the tracker is given ...
MAX_STRETCHED_GAP_S = 0.25  #: ... up to this (seconds): beyond it the ball may be anywhere


def project_point(X_world: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray, dist8: np.ndarray) -> np.ndarray:
    """One world point into every camera of a rig, in one batched call.

    X_world : (3,) point, world frame, metres
    R : (n_cams, 3, 3) world->camera rotations; t : (n_cams, 3) translations, metres
    K : (n_cams, 3, 3) intrinsics; dist8 : (n_cams, 8) OpenCV distortion (zeros where unused)
    returns (n_cams, 2) distorted pixels, NaN rows for cameras the point is not in front of
    (same result as ``Rig.project``, which loops over cameras)
    """
    X_cam = R @ X_world + t  # (n_cams, 3)
    z = X_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = X_cam[:, :2] / z[:, None]
    xn[~(z > 0)] = np.nan
    xd = distort(xn, dist8)  # each camera's own coefficients for its own point
    u = K[:, 0, 0] * xd[:, 0] + K[:, 0, 1] * xd[:, 1] + K[:, 0, 2]
    v = K[:, 1, 1] * xd[:, 1] + K[:, 1, 2]
    return np.stack([u, v], axis=1)


@numba.njit(cache=True, nogil=True)
def project_point_numba(X_world, R, t, K, dist8, out):
    """Compiled twin of :func:`project_point` (same arguments, writes ``out`` (n_cams, 2)).

    The per-frame cost of the numpy version is ~40 us of array overhead for 4 cameras; this is ~1 us.
    """
    nan = np.nan
    for c in range(R.shape[0]):
        xc = R[c, 0, 0] * X_world[0] + R[c, 0, 1] * X_world[1] + R[c, 0, 2] * X_world[2] + t[c, 0]
        yc = R[c, 1, 0] * X_world[0] + R[c, 1, 1] * X_world[1] + R[c, 1, 2] * X_world[2] + t[c, 1]
        zc = R[c, 2, 0] * X_world[0] + R[c, 2, 1] * X_world[1] + R[c, 2, 2] * X_world[2] + t[c, 2]
        if not zc > 0.0:
            out[c, 0] = nan
            out[c, 1] = nan
            continue
        x = xc / zc
        y = yc / zc
        d = dist8[c]
        xd, yd = distort_point(x, y, d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7])
        out[c, 0] = K[c, 0, 0] * xd + K[c, 0, 1] * yd + K[c, 0, 2]
        out[c, 1] = K[c, 1, 1] * yd + K[c, 1, 2]
    return out


def _project_numpy(X_world, R, t, K, dist8, out):
    out[:] = project_point(X_world, R, t, K, dist8)
    return out


#: projection implementations by name (the numpy one is the reference)
BACKENDS = {"numba": project_point_numba, "numpy": _project_numpy}


class MotionPredictor:
    """Constant-velocity prediction of the ball from the last two confirmed estimates (module docstring).

    rig : the cameras the prediction is projected into
    max_gap_s : longest time over which an estimate is trusted for prediction, seconds
    backend : "numba" (compiled projection) or "numpy" (the reference)
    """

    def __init__(self, rig: Rig, max_gap_s: float, backend: str = "numba"):
        if backend not in BACKENDS:
            raise ValueError(f"unknown projection backend {backend!r}; valid: {sorted(BACKENDS)}")
        s = rig.stacked()
        self._R, self._t, self._K, self._dist8 = (np.ascontiguousarray(s[k]) for k in ("R", "t", "K", "dist8"))
        self._project = BACKENDS[backend]
        self.max_gap_s = float(max_gap_s)
        self._t_s = np.full(2, np.nan)  # [older, newer] times of confirmed estimates
        self._X_m = np.full((2, 3), np.nan)
        self._n = 0
        self._last_frame_s = math.nan  # the frame sets' times seen by predict_pixels, for the stretched gap
        self._intervals_s = [0.0, 0.0]

    def reset(self) -> None:
        """Forget every estimate: the next :meth:`predict` returns None."""
        self._n = 0

    @property
    def n_estimates(self) -> int:
        """Confirmed estimates held (0, 1 or 2)."""
        return self._n

    def update(self, t_s: float, X_world: np.ndarray) -> None:
        """Record a confirmed estimate ``X_world`` (3,) at time ``t_s``."""
        if self._n and not t_s > self._t_s[1]:  # time did not advance: keep only the newest
            self._n = 0
        self._t_s[0], self._X_m[0] = self._t_s[1], self._X_m[1]
        self._t_s[1] = t_s
        self._X_m[1] = X_world
        self._n = min(self._n + 1, 2)

    @property
    def gap_s(self) -> float:
        """The gap in use: ``max_gap_s``, stretched by the intervals between frame sets (module docstring)."""
        stretched = min(STRETCH * min(self._intervals_s), MAX_STRETCHED_GAP_S)
        return max(self.max_gap_s, stretched)

    def predict(self, t_s: float) -> np.ndarray | None:
        """(3,) predicted ball position at ``t_s``, world frame, metres; None without a basis."""
        if self._n == 0:
            return None
        t1 = self._t_s[1]
        dt = t_s - t1
        gap = self.gap_s
        if not (0.0 < dt <= gap):
            return None
        X1 = self._X_m[1]
        span = t1 - self._t_s[0]
        if self._n == 2 and 0.0 < span <= gap:
            return X1 + (X1 - self._X_m[0]) * (dt / span)  # constant velocity
        return X1.copy()  # last position

    def predict_pixels(self, t_s: float) -> np.ndarray | None:
        """(n_cams, 2) predicted ball pixel per camera (NaN rows: behind the camera), or None. Called once per
        frame set: its time also measures the interval between frame sets (the stretched gap)."""
        if t_s > self._last_frame_s:  # (False while NaN: the first frame set)
            self._intervals_s = [self._intervals_s[1], t_s - self._last_frame_s]
        if math.isfinite(t_s):
            self._last_frame_s = t_s
        X = self.predict(t_s)
        if X is None or not math.isfinite(float(X.sum())):
            return None
        return self._project(X, self._R, self._t, self._K, self._dist8, np.empty((len(self._R), 2)))


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
