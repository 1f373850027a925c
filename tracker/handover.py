"""Support hand-over: keep an estimate from fewer cameras in the frame of the last confirmed ones.

When the ball slips behind the arm or the hand in some cameras, the ``rt2`` estimate rests on the
others. With a real calibration (1.3 px re-projection error) a smaller camera set triangulates the
ball somewhere else than the full set: on ``lab4_vga`` the two cameras at the launcher's end (26
degrees apart, 7.5 m away) are 2.5 cm off in depth, the three left when the camera at the robot's end
loses the ball about 1 cm: a jump in the track exactly when the ball is hard to see
(docs/pipeline.md, step 9). The offset comes from the calibration, so it is nearly constant over a
few centimetres of motion: measured on the last confirmed estimates, it can be carried over.

:class:`SupportHandover` keeps the last ``history`` confirmed (``Status.OK``) estimates, as reported,
with the pixels their inliers used. For an estimate ``X_S`` from the camera set ``S`` at time ``t``:

* references: the confirmed frames within ``window_s`` of the newest, which is at most ``max_age_s``
  older than ``t``, whose inliers included ``S`` and more cameras;
* per reference ``r``: ``X_r`` its position, ``X_S,r`` the same estimator run on only the pixels the
  cameras of ``S`` used in ``r``; offset ``X_r - X_S,r``;
* the estimate becomes ``X_S + median offset`` (per axis) unless that exceeds ``max_offset_m``; the
  offset is kept for ``S`` while the estimate stays within ``max_travel_m`` of the references it was
  measured on (an episode: computed once per camera set), and a confirmed estimate becomes a reference
  as reported, so hand-overs chain (4 -> 3 -> 2 cameras). Episodes are kept per camera set until every
  camera is back or no confirmed frame is recent: 4 -> 3 -> 2 -> 3 cameras returns to the 3-camera
  episode (its references, confirmed by 4 cameras, are older than the window by then; without the kept
  episode those 3-camera estimates jumped ~1 cm for as long as they lasted, as seen live after a single
  2-camera frame).

The median over a window (not the newest frame alone) matters: a camera about to disappear behind an
occluder is often already partly hidden in the last confirmed frames, its blob centre off by 2-3 px.
Plain numpy plus the estimator (which has its own numba/numpy twins); nothing per frame when the
camera set does not shrink but one small copy of a confirmed frame.
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
    max_travel_m : an episode ends when the estimate is this far from the references it was measured
        on (the calibration offset changes over the workspace), metres
    history : confirmed frames kept
    """

    def __init__(self, estimator, n_cams: int, *, window_s: float = 0.05, max_age_s: float = 0.25,
                 max_offset_m: float = 0.05, max_travel_m: float = 0.3, history: int = 16):
        self._estimator = estimator
        self.window_s, self.max_age_s, self.max_offset_m = float(window_s), float(max_age_s), float(max_offset_m)
        self.max_travel_m = float(max_travel_m)
        self._t_s = np.full(history, np.nan)  # ring buffer of confirmed frames (NaN: empty slot)
        self._X_m = np.full((history, 3), np.nan)  # their positions (as reported: hand-over included)
        self._uv_px = np.full((history, n_cams, 2), np.nan)  # the pixels each inlier used, NaN rows elsewhere
        self._next = 0
        self._t_last = None  # the last frame set's time (``step``)
        self._episodes: dict = {}  # inlier cameras -> (offset, where it was measured) of the hand-overs under way

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
        self._episodes.clear()

    def apply(self, t_s: float, X_m: np.ndarray, uv_used_px: np.ndarray, confirmed: bool):
        """One estimate through the hand-over: ``(X_m + offset, offset)`` (offset None: unchanged).

        t_s : its time, seconds; X_m : (3,) the estimate, metres; uv_used_px : (n_cams, 2) the pixel
        each inlier camera used, NaN rows for the others; confirmed : ``Status.OK`` (it then becomes a
        reference, as reported, for later estimates)
        """
        inliers = np.isfinite(uv_used_px[:, 0])
        d = self.offset(t_s, inliers)
        if d is not None:
            key = tuple(np.flatnonzero(inliers).tolist())  # offset() has just kept this episode
            if not float(np.linalg.norm(X_m + d - self._episodes[key][1])) <= self.max_travel_m:
                d = None  # moved too far from where the offset was measured
                del self._episodes[key]
        if d is not None:
            X_m = X_m + d
        if confirmed:
            i = self._next
            self._t_s[i], self._X_m[i], self._uv_px[i] = t_s, X_m, uv_used_px
            self._next = (i + 1) % len(self._t_s)
        return X_m, d

    def offset(self, t_s: float, inliers: np.ndarray) -> np.ndarray | None:
        """(3,) offset for an estimate at ``t_s`` from the cameras ``inliers`` (n_cams,) bool, metres:
        the one of the hand-over under way for these cameras, or a new one when recent confirmed
        frames had these cameras and more; None when the cameras are not fewer than the references'
        or there is no usable reference."""
        t_new = self._t_s[(self._next - 1) % len(self._t_s)]  # the newest confirmed frame (NaN: none)
        cams = np.flatnonzero(inliers)
        if not 0.0 < t_s - t_new <= self.max_age_s or len(cams) == len(inliers):  # all cameras: none had more
            self._episodes.clear()
            return None
        key = tuple(cams.tolist())
        if key in self._episodes:
            return self._episodes[key][0]
        refs = np.flatnonzero(t_new - self._t_s <= self.window_s)  # NaN (empty slots) compare False
        have = np.isfinite(self._uv_px[refs, :, 0])  # (m, n_cams)
        refs = refs[have[:, cams].all(axis=1) & (have.sum(axis=1) > len(cams))]  # these cameras and more
        offsets, where = [], []
        for j in refs:
            uv = np.full_like(self._uv_px[j], np.nan)
            uv[cams] = self._uv_px[j, cams]
            X_sub, _ = self._estimator.estimate(uv)
            if X_sub is not None:
                offsets.append(self._X_m[j] - X_sub)
                where.append(self._X_m[j])
        d = None
        if offsets:
            d = np.median(np.asarray(offsets), axis=0)
            if not float(np.linalg.norm(d)) <= self.max_offset_m:
                d = None
        if d is not None:
            self._episodes[key] = (d, np.median(np.asarray(where), axis=0))
        return d
