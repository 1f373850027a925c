"""Ball detection per camera: the single-convolution segmentation model and Algorithm 1 (paper section 2.1)."""

from tracker.detection.blobs import Blobs, find_blobs
from tracker.detection.detector import METHODS, BallDetector, DetectorOptions, Detections
from tracker.detection.model import BallSegmentationModel
from tracker.detection.verifier import CandidateVerifier
from tracker.images import check_image

__all__ = ["BallDetector", "BallSegmentationModel", "Blobs", "CandidateVerifier", "DetectorOptions", "Detections", "METHODS", "check_image", "find_blobs"]
