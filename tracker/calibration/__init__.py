"""Camera calibration: ChArUco intrinsics, multi-camera bundle adjustment (wand, ball, board), checks.

Pure numpy / OpenCV / scipy; reads no files (the ``rt2 calib`` commands in ``harness/calib`` do).
See docs/calibration.md.
"""

from tracker.calibration.board import BoardSpec, CharucoCorners, board_from_dict, detect_charuco, make_detector
from tracker.calibration.intrinsics import IntrinsicsOptions, IntrinsicsResult, calibrate_intrinsics, coverage_grid

__all__ = ["BoardSpec", "CharucoCorners", "IntrinsicsOptions", "IntrinsicsResult", "board_from_dict", "calibrate_intrinsics",
           "coverage_grid", "detect_charuco", "make_detector"]
