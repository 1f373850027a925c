"""The three trackers of the accuracy experiment, built the same way for the live run and for re-evaluation.

* ``rt2``: ``tracker.Tracker(rig, "rt2")`` (top-K detector, ROI, robust estimator ``method="ours"``);
* ``rt2-paper``: ``tracker.Tracker(rig, "rt2-paper")`` (Algorithm 1 + Algorithm 2 as published);
* ``rtblob``: ``tracker.Tracker(rig, "rtblob")`` with ``RTBlobOptions(template_radius_px=...,
  reference_rgb=...)`` from :func:`harness.experiments.accuracy.calibration.calibrate_rtblob` (``rtblob_setup=
  "calibrated"``, the default) or ``RTBlobOptions()`` (``"default"``).

Re-evaluation from logged detections re-runs only what follows detection: the estimator, the 3D size
test and the support hand-over, as :class:`tracker.CandidateEstimator` (tracker's public entry for it).
"""

from __future__ import annotations

from tracker import RTBlobOptions, make_tracker
from tracker.pipeline import KINDS, load_model

__all__ = ["DETECTION_SUFFIX", "DETECTOR_METHOD", "build_trackers", "detections_camera", "rtblob_options"]

#: detector method of each rt2 kind (tracker.pipeline.KINDS, the one table of kinds)
DETECTOR_METHOD = {kind: spec.detector_method for kind, spec in KINDS.items() if spec.detector_method is not None}
#: the logged detections of each rt2 kind go to camera name + suffix (``/camera/cam0.rt2-paper/detections``)
DETECTION_SUFFIX = {"rt2": "", "rt2-paper": ".rt2-paper"}


def detections_camera(kind: str, camera: str) -> str:
    """The camera name the detections of tracker ``kind`` are logged under."""
    return camera + DETECTION_SUFFIX[kind]


def rtblob_options(calibration: dict | None) -> RTBlobOptions:
    """RTBlobOptions from a calibration ``{"template_radius_px": [...], "reference_rgb": [...], "colour_space",
    "colour_sigma", "min_score"}`` (None: defaults; the last three are absent from logs written before the
    colour tuning and then keep RTBlobOptions' defaults)."""
    if calibration is None:
        return RTBlobOptions()
    extra = {k: calibration[k] for k in ("colour_space", "colour_sigma", "min_score") if k in calibration}
    return RTBlobOptions(template_radius_px=tuple(calibration["template_radius_px"]),
                         reference_rgb=tuple(calibration["reference_rgb"]), **extra)


def build_trackers(config, rig, model=None, rtblob_calibration: dict | None = None) -> dict:
    """{kind: tracker.Tracker} for ``config.trackers``. model : BallSegmentationModel or path (default: the
    config's); rtblob_calibration : see :func:`rtblob_options` (required when ``rtblob_setup="calibrated"``)."""
    out = {}
    for kind in config.trackers:
        if kind == "rtblob":
            if config.rtblob_setup == "calibrated" and rtblob_calibration is None:
                raise ValueError("rtblob_setup='calibrated' needs the calibration (harness.experiments.accuracy.calibration.calibrate_rtblob)")
            out[kind] = make_tracker(kind, rig, rtblob_options=rtblob_options(
                rtblob_calibration if config.rtblob_setup == "calibrated" else None))
        else:
            if model is None:
                model = load_model(config.model_path())
            out[kind] = make_tracker(kind, rig, model=model, eps_px=config.eps_px)
    return out
