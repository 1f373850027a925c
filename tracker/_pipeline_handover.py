"""Support hand-over: keep a two-camera estimate in the frame of the last confirmed ones.

When the ball slips behind the arm or the hand in all but two cameras, the ``rt2`` estimate rests on
those two (``Status.LOW_SUPPORT``). With a real calibration (1.3 px re-projection error) two cameras
that see the ball from nearly the same side triangulate it centimetres away from where three or four
cameras put it: on ``lab4_vga`` the two cameras at the launcher's end (26 degrees apart, 7.5 m away)
are 2.5 cm off in depth, a jump in the track exactly when the ball is hard to see (docs/pipeline.md,
step 9). The offset comes from the calibration, so it is nearly constant over a few centimetres of
motion: measured on the last confirmed estimates, it can be carried over.

:class:`SupportHandover` keeps the last ``history`` confirmed (``Status.OK``) estimates with the pixels
they used. For a two-camera estimate ``X_ab`` (cameras ``a``, ``b``) at time ``t``:

* reference frames: the confirmed ones within ``window_s`` of the newest, which is at most
  ``max_age_s`` older than ``t``, and in which ``a`` and ``b`` were both inliers;
* per reference frame ``r``: ``X_r`` its confirmed position, ``X_ab,r`` the same estimator run on only
  the pixels ``a`` and ``b`` used in ``r``; offset ``X_r - X_ab,r``;
* the estimate becomes ``X_ab + median offset`` (per axis) unless that exceeds ``max_offset_m``.

The median over a window (not the newest frame alone) matters: a camera about to disappear behind an
occluder is often already partly hidden in the last confirmed frames, its blob centre off by 2-3 px.
The offsets of one episode are computed once (the estimator on a few frames) and reused while the same
pair carries the estimate. Plain numpy plus the estimator (which has its own numba/numpy twins).
"""

from __future__ import annotations

import numpy as np

__all__ = ["SupportHandover"]


class SupportHandover:
    """The hand-over of one tracker (module docstring).

    estimator : the tracker's :class:`~tracker.robust.RobustTriangulator`; n_cams : rig cameras
    window_s : confirmed frames this close to the newest one give the offset, seconds
    max_age_s : no correction when the newest confirmed frame is older than this, seconds
    max_offset_m : a larger median offset is not applied (not a calibration offset), metres
    history : confirmed frames kept
    """

    def __init__(self, estimator, n_cams: int, *, window_s: float = 0.05, max_age_s: float = 0.25,
                 max_offset_m: float = 0.05, history: int = 16):
        self._estimator = estimator
        self.window_s, self.max_age_s, self.max_offset_m = float(window_s), float(max_age_s), float(max_offset_m)
        self._t_s = np.full(history, np.nan)  # ring buffer of confirmed frames
        self._X_m = np.full((history, 3), np.nan)
        self._uv_px = np.full((history, n_cams, 2), np.nan)  # the pixels each camera's inlier used, NaN otherwise
        self._next = 0
        self._t_last = None  # the last frame set's time (``step``)
        self._cache_key = None  # the inlier cameras whose offset is cached (valid until the next record)
        self._cache_offset = None

    def step(self, t_s: float) -> None:
        """The tracker's time rule, for a caller without a Tracker (re-evaluation from logged detections):
        a frame set whose time is not finite or does not increase forgets the history, as
        :class:`tracker.Tracker` does when it resets its motion prediction."""
        last = self._t_last
        if not np.isfinite(t_s) or (last is not None and not t_s > last):
            self.reset()
        if np.isfinite(t_s):
            self._t_last = float(t_s)

    def reset(self) -> None:
        """Forget every confirmed frame (a new rally, a time jump)."""
        self._t_s.fill(np.nan)
        self._cache_key = None

    def record(self, t_s: float, X_m: np.ndarray, uv_used_px: np.ndarray) -> None:
        """A confirmed estimate ``X_m`` (3,) at ``t_s`` and the (n_cams, 2) pixels of its inliers (NaN rows elsewhere)."""
        i = self._next
        self._t_s[i] = t_s
        self._X_m[i] = X_m
        self._uv_px[i] = uv_used_px
        self._next = (i + 1) % len(self._t_s)
        self._cache_key = None  # a new confirmed frame starts a new episode

    def offset(self, t_s: float, inliers: np.ndarray) -> np.ndarray | None:
        """(3,) offset to add to a two-camera estimate at ``t_s`` whose inlier cameras are ``inliers``
        (n_cams,) bool, metres; None when there is no usable reference."""
        t_new = self._t_s[(self._next - 1) % len(self._t_s)]  # the newest confirmed frame (NaN: none)
        if not 0.0 < t_s - t_new <= self.max_age_s:
            return None
        cams = np.flatnonzero(inliers)
        key = tuple(cams.tolist())
        if key == self._cache_key:
            return self._cache_offset
        offsets = []
        for j in np.flatnonzero(t_new - self._t_s <= self.window_s):  # NaN (empty slots) compare False
            if not np.isfinite(self._uv_px[j, cams, 0]).all():
                continue  # a camera of the pair was not an inlier then
            uv = np.full_like(self._uv_px[j], np.nan)
            uv[cams] = self._uv_px[j, cams]
            X_pair, _ = self._estimator.estimate(uv)
            if X_pair is not None:
                offsets.append(self._X_m[j] - X_pair)
        result = None
        if offsets:
            d = np.median(np.asarray(offsets), axis=0)
            if float(np.linalg.norm(d)) <= self.max_offset_m:
                result = d
        self._cache_key, self._cache_offset = key, result
        return result
