"""The accuracy experiment's session log (one MCAP file, ``harness.logs``; topics in docs/logging.md).

What is written, and why (docs/accuracy.md has the full list):

* metadata ``session``: ``kind = "accuracy"``, the seed, the whole :class:`AccuracyConfig`, the camera
  names, the candidates per camera of each rt2 tracker, the nominal mount, RTBlob's template radii,
  the fault plan, the calibration error (:mod:`harness.experiments.accuracy.rig_error`) and the clock error;
  attachments ``rig.yaml`` (the rig the TRACKERS used: the estimated calibration; what re-evaluation
  uses), ``rig_true.yaml`` (simulation truth: the rig the images were rendered with; only when the two
  differ) and ``model.npz`` (the segmentation weights used);
* per frame set ``k`` at its true capture time ``t_k``, sequence ``k``:
  the delivered images (every ``log_images``-th frame set; a camera that delivered no frame has none),
  the rt2 trackers' detections (every candidate the estimator saw: rt2 under the camera's name,
  rt2-paper under ``<camera>.rt2-paper``), each tracker's ``BallObservation`` (its ``t_s`` is the
  timestamp the frame set was delivered with), the ground truth (FK of the reported joints through the
  nominal mount, reported q and qdot, commanded q), the reported arm's frames on ``/tf`` and as a line
  strip, and the true ball with every tracker's ball in the 3D scene;
* at the end: the figures (``/figures/accuracy``) and ``session_end``.

Re-evaluation (:mod:`harness.experiments.accuracy.reevaluate_accuracy`) needs only the metadata, the attachments, the images
or detections, the observations (for the delivered timestamps) and the ground truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.experiments.accuracy.evaluate import fault_plan_of
from harness.experiments.accuracy.trackers import DETECTION_SUFFIX, DETECTOR_METHOD, detections_camera
from harness.logs import SessionLogWriter
from harness.logs import LogWriterOptions
from robot_models import LINK_CHAIN
from tracker import DetectorOptions

__all__ = ["AccuracyLogWriter", "ARM_FRAMES", "RIG_ATTACHMENTS", "candidates_per_camera", "session_metadata"]

#: the WAM's frames written to /tf each frame set (children of ``world``); another arm's: its link_chain + ball_mount
ARM_FRAMES = LINK_CHAIN + ("ball_mount",)


def candidates_per_camera(kind: str) -> int:
    """k of the estimator's (n_cams, k, 2) input for rt2 kind ``kind`` (the detector defaults tracker.Tracker uses)."""
    return DetectorOptions(method=DETECTOR_METHOD[kind]).k


#: what each rig attachment is (also written into the metadata, so a reader of the log knows)
RIG_ATTACHMENTS = {
    "rig.yaml": "the rig the trackers used (estimated calibration, with the simulated calibration error)",
    "rig_true.yaml": "simulation truth: the rig the images were rendered with (not available on a real system)",
}


def session_metadata(config, rig, motion, rtblob_calibration=None, calibration_error=None) -> dict:
    """The ``session`` metadata record of an accuracy log (``rig``: the trackers' rig)."""
    cal = calibration_error or {"enabled": False}
    return {
        "kind": "accuracy",
        "seed": int(config.seed),
        "config": config.to_dict(),
        "camera_names": list(rig.names),
        "trackers": list(config.trackers),
        "candidates_per_camera": {k: candidates_per_camera(k) for k in config.trackers if k in DETECTION_SUFFIX},
        "detection_camera_suffix": dict(DETECTION_SUFFIX),
        "T_base_to_world_nominal": np.asarray(motion.T_base_to_world).tolist(),
        "rtblob_calibration": rtblob_calibration,
        "fault_plan": fault_plan_of(config, len(rig)).to_dict(),
        "motion": {k: v for k, v in motion.info.items()},
        "bias_deg": np.round(np.rad2deg(motion.bias_rad), 6).tolist(),
        "calibration_error": cal,
        "rig_attachments": {k: v for k, v in RIG_ATTACHMENTS.items() if k == "rig.yaml" or cal.get("enabled")},
    }


class AccuracyLogWriter:
    """Writes one accuracy session (see the module docstring). Use as a context manager.

    path : the .mcap file; rig : the rig the trackers used (``rig.yaml``); true_rig : the rig the images
    were rendered with (``rig_true.yaml``, when calibration_error is enabled); calibration_error : its info;
    kin : robot_models.ArmKinematics (arm frames for /tf, joint names)
    log_images : "all", "none" or N; image_format : "png" (default: lossless, re-evaluation from images
    is exact), "jpeg" or "raw"; flush_period_s : a crash loses at most about this much (docs/logging.md)
    """

    def __init__(self, path, config, rig, motion, kin, *, true_rig=None, calibration_error=None, rtblob_calibration=None,
                 log_images=50, image_format: str = "png", overwrite: bool = False, flush_period_s: float = 1.0):
        meta = session_metadata(config, rig, motion, rtblob_calibration, calibration_error)
        self.writer = SessionLogWriter(path, metadata=meta, log_images=log_images, image_format=image_format,
                                       overwrite=overwrite, flush_period_s=flush_period_s,
                                       options=LogWriterOptions(joint_names=tuple(kin.joint_names)))
        self.path = Path(path)
        self.names = rig.names
        self.motion = motion
        w = self.writer
        w.attach_rig(rig)
        if "rig_true.yaml" in meta["rig_attachments"]:
            if true_rig is None:
                raise ValueError("calibration_error is enabled: the true rig (true_rig=) must be logged too")
            import yaml

            w.attach("rig_true.yaml", yaml.safe_dump(true_rig.to_dict(), sort_keys=False).encode(), "application/yaml")
        if any(k in DETECTION_SUFFIX for k in config.trackers):
            w.attach("model.npz", config.model_path().read_bytes(), "application/x-npz")
        w.write_scene_static(0.0, rig)
        # the reported arm (what the robot says), all frames at once: (n, len(ARM_FRAMES), 4, 4)
        Q = motion.q_reported
        self.arm_frames = tuple(kin.link_chain) + ("ball_mount",)
        self._arm_T = np.stack([kin.fk_batch(Q, f, check_limits=False) for f in self.arm_frames], axis=1)

    @property
    def image_every(self) -> int:
        return self.writer.image_every

    def write_frame(self, fr) -> None:
        """Everything of one :class:`harness.experiments.accuracy.frames.FrameResult`."""
        w, k, t = self.writer, fr.index, fr.t_s
        m = self.motion
        if fr.images is not None:
            for cam, img in zip(self.names, fr.images):
                if img is not None:  # no frame delivered: nothing to log
                    w.write_image(t, cam, img, k)
        for kind, (uv, scores, areas) in fr.candidates.items():
            for i, cam in enumerate(self.names):
                have = np.isfinite(uv[i, :, 0])
                w.write_detections(t, detections_camera(kind, cam), uv[i][have], scores[i][have], k, areas_px=areas[i][have])
        for kind, obs in fr.observations.items():
            w.write_observation(t, kind, obs, k)
        w.write_ground_truth(t, m.gt_world_m[k], m.q_reported[k], m.qdot_reported[k], m.q_command[k], k)
        T = self._arm_T[k]
        w.write_transforms(t, [("world", name, T[j]) for j, name in enumerate(self.arm_frames)])
        w.write_scene_arm(t, T[: len(self.arm_frames) - 1, :3, 3])
        w.write_scene_balls(t, m.gt_world_m[k], {kind: obs.position_m for kind, obs in fr.observations.items()})

    def finish(self, figures: dict, extra: dict | None = None) -> None:
        self.writer.write_figures("accuracy", figures)
        self.writer.close(extra=extra)

    def close(self, error: str | None = None) -> None:
        self.writer.close(error=error)

    def __enter__(self) -> "AccuracyLogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.writer.__exit__(exc_type, exc, tb)
