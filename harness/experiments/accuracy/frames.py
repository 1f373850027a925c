"""Per frame set: compose the scene, render every camera, apply injected faults, run every tracker.

A :class:`FrameProducer` owns one renderer and one set of trackers (one per process: neither is
thread-safe) and turns a range of frames into :class:`FrameResult`s. Frames are processed in
independent *segments* (``AccuracyConfig.segments()``): the trackers are reset at each segment's start,
so any process can run any segment and the figures do not depend on the number of workers. A segment
after the first is preceded by a *warm-up*: the freshly reset trackers run over the
``config.warmup_frames`` frames before its start (their outputs dropped), so they enter the segment
tracking, as in one continuous session, instead of re-acquiring the ball at every segment start (which
with a second ball in view is a coin flip, see docs/accuracy.md).

Worker processes (``--workers > 1``) build their producer once in :func:`init_worker`; one of them
calibrates RTBlob (:func:`calibrate`, it has a renderer already), then they run segments with
:func:`run_segment`; images travel back only for the frames that are logged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.experiments.accuracy.calibration import calibrate_rtblob
from harness.experiments.accuracy.evaluate import fault_plan_of
from harness.experiments.accuracy.session_scene import SessionScene
from harness.experiments.accuracy.trackers import build_trackers
from harness.sim.render import RenderOptions, Renderer
from tracker import FrameSet

__all__ = ["FrameProducer", "FrameResult", "calibrate", "init_worker", "render_seed", "run_segment", "warmup_range"]


def render_seed(seed: int) -> int:
    """The renderer's sensor-noise seed of a session (its own stream of the session seed)."""
    return int(np.random.SeedSequence([int(seed), 3]).generate_state(1)[0])


@dataclass(frozen=True)
class FrameResult:
    """One frame set through every tracker.

    index : frame number; t_s : true capture time (mid-exposure), robot clock
    t_camera_s : the timestamp the frame set was delivered with (the camera clock: t_s plus the
        clock error, and changed by a timestamp fault)
    observations : {tracker: tracker.BallObservation}
    candidates : {rt2 kind: (uv (n_cams, k, 2) distorted px, scores (n_cams, k), blob areas (n_cams, k) px)},
        the estimator's input
    images : the delivered images (None entries = no frame) when the frame is logged, else None
    faults : the injected fault kinds that hit this frame
    """

    index: int
    t_s: float
    t_camera_s: float
    observations: dict
    candidates: dict
    images: list | None
    faults: tuple


class FrameProducer:
    """Renders and tracks frames of one session (see the module docstring).

    rig : the TRUE rig (the renderer draws with it); tracker_rig : the rig the trackers get (the
        estimated calibration, :mod:`harness.experiments.accuracy.rig_error`; None = the true rig)
    motion : :class:`harness.experiments.accuracy.motion.RobotMotion` of the session
    link_radii_m : (8,) arm capsule radii; model : BallSegmentationModel (None: the config's path)
    log_images_every : keep the delivered images of frames ``k % N == 0`` in the results (0 = never)

    The trackers are built by :meth:`start`, which needs RTBlob's calibration (:meth:`calibration`).
    """

    def __init__(self, config, rig, motion, link_radii_m, *, tracker_rig=None, model=None, log_images_every: int = 0):
        self.config, self.rig, self.motion, self.model = config, rig, motion, model
        self.tracker_rig = rig if tracker_rig is None else tracker_rig
        self.renderer = Renderer(rig, RenderOptions(), seed=render_seed(config.seed))
        self.scene = SessionScene(link_radii_m, motion.T_base_to_world[:3, 3], config.scene, seed=config.seed)
        self.trackers = {}
        self.rtblob_calibration = None
        self.plan = fault_plan_of(config, len(rig))
        self.log_every = int(log_images_every)
        self.period_s = 1.0 / config.rate_hz

    def calibration(self) -> dict | None:
        """RTBlob's radius and colour for this session (None when RTBlob is not run or not calibrated)."""
        if "rtblob" not in self.config.trackers or self.config.rtblob_setup != "calibrated":
            return None
        return calibrate_rtblob(self.config, self.tracker_rig, self.renderer, self.scene, self.motion)

    def start(self, rtblob_calibration: dict | None) -> None:
        """Build the trackers (once; again only when the calibration differs)."""
        if not self.trackers or rtblob_calibration != self.rtblob_calibration:
            self.close()
            self.trackers = build_trackers(self.config, self.tracker_rig, self.model, rtblob_calibration)
            self.rtblob_calibration = rtblob_calibration

    def close(self) -> None:
        for t in self.trackers.values():
            t.close()

    def frame(self, k: int, *, keep_images: bool = True) -> FrameResult:
        """Frame ``k``: scene, images, faults, every tracker (in config order); keep_images=False never
        keeps the images (warm-up)."""
        m = self.motion
        t_s = float(m.t_s[k])
        scene = self.scene.scene_at(k, t_s, m.links_world_m[k], m.ball_true_world_m[k], m.ball_velocity_world_mps[k])
        images = self.renderer.render(scene)  # the true rig
        t_cam = float(m.t_camera_s[k])  # the camera's timestamp (clock error included)
        t_cam, images = self.plan.apply(k, t_cam, images, self.period_s) if self.plan.active else (t_cam, images)
        fs = FrameSet(t_cam, tuple(images), k)
        obs, cand = {}, {}
        for kind, tracker in self.trackers.items():
            obs[kind], info = tracker.process_with_info(fs)
            if kind != "rtblob":
                cand[kind] = (info.uv_candidates_px, info.scores, info.areas_px)
        keep = keep_images and self.log_every > 0 and k % self.log_every == 0
        return FrameResult(k, t_s, t_cam, obs, cand, images if keep else None, self.plan.faults_at(k))

    def segment(self, start: int, stop: int):
        """Frames ``start .. stop - 1`` with freshly reset trackers, warmed up on the frames before ``start``
        (:func:`warmup_range`); yields FrameResults."""
        for t in self.trackers.values():
            t.reset(clear_stats=True)
        for k in warmup_range(self.config, start):
            self.frame(k, keep_images=False)
        self._stats0 = {kind: t.stats.as_dict() for kind, t in self.trackers.items()}
        for k in range(start, stop):
            yield self.frame(k)

    def stats(self) -> dict:
        """{tracker: TrackerStats dict} since the last segment start (warm-up not counted)."""
        base = getattr(self, "_stats0", {})
        return {kind: {key: v - base.get(kind, {}).get(key, 0) for key, v in t.stats.as_dict().items()}
                for kind, t in self.trackers.items()}


def warmup_range(config, start: int) -> range:
    """The frames the trackers of the segment starting at ``start`` are warmed up on (empty for the first)."""
    return range(max(0, start - config.warmup_frames), start) if start > 0 else range(0)


_WORKER: FrameProducer | None = None


def init_worker(config, rig, tracker_rig, motion, link_radii_m, log_images_every: int) -> None:
    """Worker initializer: build this process's producer (renderer, scene) once."""
    import cv2

    global _WORKER
    cv2.setNumThreads(1)  # one core per worker process
    _WORKER = FrameProducer(config, rig, motion, link_radii_m, tracker_rig=tracker_rig, log_images_every=log_images_every)


def calibrate(_task=None) -> dict | None:
    """Worker task: RTBlob's calibration (see :meth:`FrameProducer.calibration`)."""
    return _WORKER.calibration()


def run_segment(task: tuple) -> tuple[list[FrameResult], dict]:
    """Worker task ``(start, stop, rtblob_calibration)``: one segment's FrameResults and tracker stats."""
    start, stop, rtblob_calibration = task
    _WORKER.start(rtblob_calibration)
    frames = list(_WORKER.segment(start, stop))
    return frames, _WORKER.stats()
