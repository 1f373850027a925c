"""Camera calibration: ChArUco intrinsics, multi-camera bundle adjustment (wand, single ball, board), pose helpers.

Pure numpy / OpenCV / scipy; reads no files (the ``rt2 calib`` commands in ``harness/calib`` do).
See docs/calibration.md.
"""

from tracker.calibration.ball import apply_similarity, calibrate_ball
from tracker.calibration.board import BoardSpec, CharucoCorners, board_from_dict, detect_charuco, make_detector
from tracker.calibration.board_rig import BoardRigOptions, BoardRigResult, calibrate_board_rig
from tracker.calibration.bundle import BoardModel, BundleOptions, BundleResult, PointModel, WandModel, bundle_adjust
from tracker.calibration.extrinsics import WandOptions, WandResult, apply_world, calibrate_wand, order_wand_points
from tracker.calibration.intrinsics import IntrinsicsOptions, IntrinsicsResult, calibrate_intrinsics, coverage_grid

__all__ = ["BoardModel", "BoardRigOptions", "BoardRigResult", "BoardSpec", "BundleOptions", "BundleResult", "CharucoCorners",
           "IntrinsicsOptions", "IntrinsicsResult", "PointModel", "WandModel", "WandOptions", "WandResult", "apply_similarity",
           "apply_world", "board_from_dict", "bundle_adjust", "calibrate_ball", "calibrate_board_rig", "calibrate_intrinsics",
           "calibrate_wand", "coverage_grid", "detect_charuco", "make_detector", "order_wand_points"]
