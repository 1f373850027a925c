"""The session log of ``rt2 track``: the same MCAP topics as the experiments (docs/logging.md).

What is written (kind ``"track"``):

* metadata ``session``: ``kind = "track"``, the tracker kind, the source, the seed, the camera
  names, the candidates per camera (k of the estimator's input); attachments ``rig.yaml`` and, for
  the rt2 kinds, ``model.npz`` (the segmentation weights), so ``rt2 reevaluate`` rebuilds the tracker;
  the static scene (table, net, camera frustums, calibrations);
* per frame set ``num`` (the MCAP sequence), at log time = first host arrival stamp - the first frame
  set's: the images (every ``log_images``-th frame set, cameras that delivered a frame), the rt2
  kinds' detections (every candidate the estimator saw, with blob areas), the ``BallObservation``
  on ``/tracker/<kind>/ball``, and the ball in the 3D scene;
* at the end: the run's figures on ``/figures/track`` and ``session_end``.

A :class:`~harness.logs.BackgroundLogWriter` does the writing on its own thread: the tracking loop
never waits for the disk (what it had to drop is counted in ``session_end``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from harness.logs import BackgroundLogWriter, SessionLogWriter

__all__ = ["LiveLog", "session_metadata"]


def session_metadata(rig, tracker, *, source: str, seed: int | None, config: dict | None = None) -> dict:
    k = tracker.candidates_per_camera  # None for rtblob (one peak per camera, no candidates)
    return {"kind": "track", "tracker": tracker.kind, "source": source, "seed": seed, "camera_names": list(rig.names),
            "candidates_per_camera": k, "config": config or {},
            "defer_full_frame": bool(tracker.options.defer_full_frame)}  # a re-run on the images defers as live did


class LiveLog:
    """Writes one ``rt2 track`` session (module docstring).

    path : the .mcap file (must not exist unless ``overwrite``); rig, tracker : the running ones
    log_images : "all", "none" or N; image_format : "jpeg" (default), "png", "raw"
    flush_period_s : a crash (SIGKILL) loses at most about this much wall time of the log
    max_pending_images : images waiting for the encoder at most (default 8 per camera); more are
        dropped and counted, so a slow disk or encoder never slows the tracker
    """

    def __init__(self, path, rig, tracker, *, source: str, seed: int | None = None, config: dict | None = None,
                 log_images="all", image_format: str = "jpeg", overwrite: bool = False, flush_period_s: float = 0.5,
                 model_path=None, max_pending_images: int | None = None):
        meta = session_metadata(rig, tracker, source=source, seed=seed, config=config)
        writer = SessionLogWriter(path, metadata=meta, log_images=log_images, image_format=image_format,
                                  overwrite=overwrite, flush_period_s=flush_period_s)
        self.path = writer.path
        self.names = rig.names
        self.kind = tracker.kind
        self._detections = tracker.candidates_per_camera is not None  # the kinds with a candidate detector
        writer.attach_rig(rig)
        if self._detections:
            from tracker.pipeline import DEFAULT_MODEL

            writer.attach("model.npz", Path(model_path or DEFAULT_MODEL).read_bytes(), "application/x-npz")
        writer.write_scene_static(0.0, rig)
        writer.flush()
        self.image_every = writer.image_every
        pending = 8 * len(rig) if max_pending_images is None else int(max_pending_images)
        self.bg = BackgroundLogWriter(writer, max_pending_images=pending, max_pending=max(16384, pending))
        self._t0: float | None = None

    def log_time(self, t_first_host_s: float) -> float:
        """Session log time (s >= 0) of a frame set whose first frame arrived at ``t_first_host_s``."""
        if self._t0 is None:
            self._t0 = t_first_host_s
        dt = t_first_host_s - self._t0
        return dt if dt > 0 and math.isfinite(dt) else 0.0

    def write(self, num: int, t_log_s: float, afs, obs, info) -> None:
        """Everything of one frame set (the arrays are copied where the tracker reuses them)."""
        bg = self.bg
        if self.image_every and num % self.image_every == 0:
            for cam, img in zip(self.names, afs.frameset.images):
                if img is not None:
                    bg.write_image(t_log_s, cam, img.copy(), num)
        if self._detections and info is not None:
            uv, sc, ar = info.uv_candidates_px, info.scores, info.areas_px
            for i, cam in enumerate(self.names):
                have = np.isfinite(uv[i, :, 0])
                bg.write_detections(t_log_s, cam, uv[i][have], sc[i][have], num,
                                    areas_px=None if ar is None else ar[i][have])
        bg.write_observation(t_log_s, self.kind, obs, num)
        bg.write_scene_balls(t_log_s, None, {self.kind: obs.position_m})

    @property
    def dropped(self) -> dict:
        return dict(self.bg.dropped)

    def close(self, figures: dict | None = None, error: str | None = None) -> None:
        """Write the figures, drain the queue and finish the file (footer, summary)."""
        if figures is not None and not self.bg.closed:
            self.bg.write_figures("track", figures)
        self.bg.close(error=error)
