"""rt2 tracker: cameras, calibration, detection, robust triangulation and the real-time pipeline.

Imports nothing else of rt2 but its lowest layer, ``checks`` (see docs/architecture.md).

The names below are loaded on first use (PEP 562): ``from tracker import FrameSet`` imports
``tracker.observation`` and nothing else, ``from tracker import Camera`` the camera model (with its numba
twin), and only ``Tracker``, ``BallDetector``, ``RTBlobTracker`` ... bring in the pipeline, the detector or
RTBlob. Importing a submodule (``tracker.rig``, ``tracker.pipeline``) is unchanged.
"""

from checks.lazy import lazy_attributes

_WHERE = {
    "Camera": "camera",
    "BallDetector": "detection", "BallSegmentationModel": "detection", "CandidateVerifier": "detection",
    "DetectorOptions": "detection", "Detections": "detection",
    "BallObservation": "observation", "FrameSet": "observation", "Status": "observation",
    "Rig": "rig",
    "EstimateBatch": "robust", "EstimateInfo": "robust", "RobustOptions": "robust", "RobustTriangulator": "robust",
    "refine_point": "triangulation", "triangulate": "triangulation", "triangulate_linear": "triangulation",
    "triangulate_pairs": "triangulation",
    "RTBlobDetector": "rtblob", "RTBlobOptions": "rtblob", "RTBlobTracker": "rtblob",
    "BallHypotheses": "hypotheses", "HypothesisOptions": "hypotheses",
    "MotionCue": "motion", "MotionOptions": "motion",
    "Tracker": "pipeline", "TrackerOptions": "pipeline", "make_tracker": "pipeline",
    "CandidateEstimator": "candidates",
}

__all__ = sorted(_WHERE)
__getattr__, __dir__ = lazy_attributes("tracker", globals(), _WHERE)
