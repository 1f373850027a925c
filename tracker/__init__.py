"""rt2 tracker: cameras, calibration, detection, robust triangulation and the real-time pipeline.

Imports nothing else of rt2 but its lowest layer, ``checks`` (see docs/architecture.md).
"""

from tracker.camera import Camera
from tracker.detection import BallDetector, BallSegmentationModel, CandidateVerifier, DetectorOptions, Detections
from tracker.observation import BallObservation, FrameSet, Status
from tracker.rig import Rig
from tracker.robust import EstimateBatch, EstimateInfo, RobustOptions, RobustTriangulator
from tracker.triangulation import refine_point, triangulate, triangulate_linear, triangulate_pairs
from tracker.rtblob import RTBlobDetector, RTBlobOptions, RTBlobTracker
from tracker.hypotheses import BallHypotheses, HypothesisOptions
from tracker.pipeline import Tracker, TrackerOptions, make_tracker
from tracker.candidates import CandidateEstimator

__all__ = ["BallDetector", "CandidateEstimator", "CandidateVerifier", "BallObservation", "BallSegmentationModel", "Camera", "DetectorOptions", "Detections", "FrameSet", "RTBlobDetector", "RTBlobOptions", "RTBlobTracker", "Rig", "Status", "EstimateBatch", "EstimateInfo", "RobustOptions", "RobustTriangulator", "refine_point", "triangulate", "triangulate_linear", "triangulate_pairs", "Tracker", "TrackerOptions", "make_tracker", "BallHypotheses", "HypothesisOptions"]
