"""rt2 tracker: cameras, calibration, detection, robust triangulation and the real-time pipeline.

Imports nothing else of rt2 (see docs/architecture.md).
"""

from tracker.camera import Camera
from tracker.observation import BallObservation, FrameSet, Status
from tracker.rig import Rig

__all__ = ["BallObservation", "Camera", "FrameSet", "Rig", "Status"]
