"""The three trackers of the accuracy experiment, built the same way for the live run and for re-evaluation.

* ``rt2``: ``tracker.Tracker(rig, "rt2")`` (top-K detector, ROI, robust estimator ``method="ours"``);
* ``rt2-paper``: ``tracker.Tracker(rig, "rt2-paper")`` (Algorithm 1 + Algorithm 2 as published);
* ``rtblob``: ``tracker.Tracker(rig, "rtblob")`` with ``RTBlobOptions(template_radius_px=...,
  reference_rgb=...)`` from :func:`harness.accuracy.calibration.calibrate_rtblob` (``rtblob_setup=
  "calibrated"``, the default) or ``RTBlobOptions()`` (``"default"``).

Re-evaluation from logged detections re-runs only the estimator and the 3D size test:
:func:`estimator_for` builds the same ``RobustTriangulator`` the rt2 trackers use, :func:`size_test_for`
the same :class:`tracker._size_test.SizeTest`.
"""

from __future__ import annotations

from tracker import RobustOptions, RobustTriangulator, RTBlobOptions, TrackerOptions, make_tracker
from tracker._pipeline_handover import SupportHandover
from tracker._size_test import SizeTest
from tracker.pipeline import load_model

__all__ = ["DETECTION_SUFFIX", "DETECTOR_METHOD", "ESTIMATOR_METHOD", "build_trackers", "detections_camera", "estimator_for", "handover_for", "rtblob_options", "size_test_for"]

#: detector and estimator method of each rt2 kind (as tracker.pipeline uses them)
DETECTOR_METHOD = {"rt2": "ours", "rt2-paper": "paper"}
ESTIMATOR_METHOD = {"rt2": "ours", "rt2-paper": "paper"}
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
                raise ValueError("rtblob_setup='calibrated' needs the calibration (harness.accuracy.calibration.calibrate_rtblob)")
            out[kind] = make_tracker(kind, rig, rtblob_options=rtblob_options(
                rtblob_calibration if config.rtblob_setup == "calibrated" else None))
        else:
            if model is None:
                model = load_model(config.model_path())
            out[kind] = make_tracker(kind, rig, model=model, eps_px=config.eps_px)
    return out


def estimator_for(kind: str, rig, eps_px=None) -> RobustTriangulator:
    """The robust estimator tracker ``kind`` ("rt2" or "rt2-paper") runs, for re-evaluation from detections."""
    if kind not in ESTIMATOR_METHOD:
        raise ValueError(f"tracker {kind!r} has no robust estimator to re-run; valid: {sorted(ESTIMATOR_METHOD)}")
    options = RobustOptions() if eps_px is None else RobustOptions(eps_px=float(eps_px))
    return RobustTriangulator(rig, options, method=ESTIMATOR_METHOD[kind])


def handover_for(kind: str, estimator) -> SupportHandover | None:
    """The support hand-over tracker ``kind`` applies (the Tracker default: on for "rt2", off for "rt2-paper")."""
    if kind not in ESTIMATOR_METHOD:
        raise ValueError(f"tracker {kind!r} has no support hand-over; valid: {sorted(ESTIMATOR_METHOD)}")
    age = TrackerOptions().handover_max_age_s
    return SupportHandover(estimator, len(estimator.rig), max_age_s=age) if kind == "rt2" and age is not None else None


def size_test_for(kind: str, rig, edge_px: float = 0.0) -> SizeTest:
    """The 3D size test tracker ``kind`` applies (the Tracker defaults: on for "rt2", measuring only for "rt2-paper");
    ``edge_px``: the detector's edge loss, pixels (the ``edge_loss_px`` of the model the log recorded)."""
    if kind not in ESTIMATOR_METHOD:
        raise ValueError(f"tracker {kind!r} has no size test; valid: {sorted(ESTIMATOR_METHOD)}")
    opt = TrackerOptions()
    return SizeTest(rig, opt.max_size_ratio if kind == "rt2" else None, opt.ball_radius_m, edge_px)
