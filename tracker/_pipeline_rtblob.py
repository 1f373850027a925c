"""The per-frame work of :class:`tracker.Tracker`'s ``rtblob`` kind: the RTBlob baseline
(:class:`~tracker.rtblob.RTBlobTracker`) behind the same frame-set checks and fault handling as rt2's."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from tracker._pipeline_options import PipelineInfo, TrackerKind, TrackerOptions, TrackerStats
from tracker.ball_size import ball_diameter_range_px, rtblob_radius_floor_px
from tracker.observation import BallObservation, FrameSet, Status
from tracker.rig import Rig
from tracker.rtblob import RTBlobOptions, RTBlobTracker

__all__ = ["RTBlobEngine"]


class RTBlobEngine:
    """RTBlob behind :class:`tracker.Tracker` (arguments as :class:`~tracker._pipeline_rt2.SegmentationEngine`;
    only ``rtblob_options`` apply). Attributes: ``roi`` (always False), ``rtblob`` (the
    :class:`RTBlobTracker`), ``candidates_per_camera`` (None: it keeps one peak per camera)."""

    candidates_per_camera = None
    roi = False

    def __init__(self, rig: Rig, kind: str, spec: TrackerKind, options: TrackerOptions, stats: TrackerStats, *,
                 model=None, detector_options=None, estimator_options=None, rtblob_options=None):
        for name, given in (("model", model), ("detector_options", detector_options), ("estimator_options", estimator_options), ("eps_px", options.eps_px)):
            if given is not None:
                raise ValueError(f"kind {kind!r} takes no {name} (it has its own detector and stereo pairs); use rtblob_options")
        if options.roi:
            raise ValueError(f"kind {kind!r} has no ROI search (RTBlob always searches the full frame); pass roi=False or None")
        if options.workers != 1:
            raise ValueError(f"kind {kind!r} runs its cameras in its own loop; workers must be 1, got {options.workers}")
        rtblob_options = RTBlobOptions() if rtblob_options is None else rtblob_options
        if options.size_from_rig:
            rtblob_options = _rtblob_sized(rig, rtblob_options)
        self.rtblob = RTBlobTracker(rig, rtblob_options)
        self.stats, self.n_cams, self._names = stats, len(rig), rig.names

    def forget_motion(self) -> None:
        """Nothing: RTBlob keeps no motion state."""

    def settle(self) -> None:
        """Nothing: RTBlob defers no work."""

    def close(self) -> None:
        """Nothing to stop."""

    def process(self, t_s: float, frameset: FrameSet, usable: list[int], notes: list, t0: float, *,
                prior_m=None) -> tuple[BallObservation, PipelineInfo]:
        """As :meth:`SegmentationEngine.process` (``prior_m`` is never given: the tracker refuses it for rtblob); frames the tracker found unusable are handed to RTBlob as
        missing (None), a time that is not finite as 0 (RTBlob raises on either; they are in ``notes``)."""
        images = frameset.images
        blanked = [i for i in range(self.n_cams) if images[i] is not None and i not in usable]
        t_s = float(frameset.t_s)
        if blanked or not math.isfinite(t_s):
            imgs = list(images)
            for i in blanked:
                imgs[i] = None
            frameset = FrameSet(t_s if math.isfinite(t_s) else 0.0, tuple(imgs), frameset.index)
        obs, info = self.rtblob.process_with_info(frameset)
        obs = obs if math.isfinite(t_s) else replace(obs, t_s=t_s)
        ours = set(notes)
        drop = {f"camera {self._names[i]}: no frame" for i in blanked} | ours
        notes.extend(s for s in obs.notes if s not in drop)
        n = self.n_cams
        pinfo = PipelineInfo(obs.uv_px[:, None, :].copy(), info.scores[:, None].copy(), np.full((n, 2), np.nan), np.zeros(n, bool), False, info)
        self.stats.positions += obs.position_m is not None
        self.stats.ok += obs.status is Status.OK
        return replace(obs, notes=tuple(notes), latency_s=time.perf_counter() - t0), pinfo


def _rtblob_sized(rig: Rig, options: RTBlobOptions) -> RTBlobOptions:
    """RTBlob's options with each camera's template raised to the farthest ball's radius where the
    ``expected_distance_m`` sizing is smaller (``TrackerOptions.size_from_rig``); unchanged when the
    rig has no workspace, the radii are given, or no camera needs it."""
    if rig.workspace_m is None or options.template_radius_px is not None:
        return options
    floor = rtblob_radius_floor_px(ball_diameter_range_px(rig, ball_radius_m=options.ball_radius_m))
    expected = [0.5 * (c.K[0, 0] + c.K[1, 1]) * options.ball_radius_m / options.expected_distance_m for c in rig]
    if not any(f > e for f, e in zip(floor, expected)):  # NaN floor (camera sees no workspace): keep
        return options
    return replace(options, template_radius_px=tuple(float(max(e, f)) if f > e else float(e) for f, e in zip(floor, expected)))
