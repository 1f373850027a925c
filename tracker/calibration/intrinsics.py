"""Intrinsic calibration of one camera from ChArUco views (Zhang's method, OpenCV's solver).

``calibrate_intrinsics(views, spec, image_size)`` runs ``cv2.calibrateCameraExtended`` on the
views with enough corners, drops views whose RMS reprojection error is far above the others'
(``reject_factor`` x the median, at least ``reject_floor_px``), re-solves, and returns the camera
model with the parameters' standard deviations, the per-view errors and a coverage report.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tracker.calibration.board import BoardSpec, CharucoCorners
from tracker.camera import DISTORTION_MODELS

__all__ = ["IntrinsicsOptions", "IntrinsicsResult", "calibrate_intrinsics", "coverage_grid"]

#: names of the entries of calibrateCameraExtended's stdDeviationsIntrinsics (first 12 used here)
STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


@dataclass(frozen=True)
class IntrinsicsOptions:
    """model : ``plumb_bob`` (k1 k2 p1 p2 k3) or ``rational_polynomial`` (8 coefficients)
    min_corners : a view needs this many corners, spread over >= 2 board rows and columns
    min_views : calibration needs this many usable views
    reject_factor, reject_floor_px : a view is dropped when its RMS error exceeds
        ``max(reject_factor * median view RMS, reject_floor_px)``
    max_rounds : solve / reject rounds
    fix_k3 : hold k3 at 0 (advisable with few views or narrow lenses)
    grid : coverage cells across and down the image
    """

    model: str = "plumb_bob"
    min_corners: int = 6
    min_views: int = 5
    reject_factor: float = 3.0
    reject_floor_px: float = 1.0
    max_rounds: int = 3
    fix_k3: bool = False
    grid: tuple[int, int] = (4, 3)

    def __post_init__(self):
        if self.model not in ("plumb_bob", "rational_polynomial"):
            raise ValueError(f"intrinsics model must be 'plumb_bob' or 'rational_polynomial', got {self.model!r}")
        if self.min_corners < 4 or self.min_views < 3:
            raise ValueError(f"min_corners must be >= 4 and min_views >= 3, got {self.min_corners}, {self.min_views}")
        if not self.reject_factor > 1 or not self.reject_floor_px > 0:
            raise ValueError(f"reject_factor must be > 1 and reject_floor_px > 0, got {self.reject_factor}, {self.reject_floor_px}")


@dataclass(frozen=True)
class IntrinsicsResult:
    """K : (3, 3) pixels; distortion : (5,) or (8,) OpenCV order; model : rig-format model name
    std : parameter name -> standard deviation (pixels for fx fy cx cy, unitless for distortion)
    rms_px : RMS reprojection error over the kept views
    view_rms_px : (n_views,) RMS per input view (NaN for views never usable)
    kept : (n_views,) bool, the views the final solution used
    rejected : view index -> why it was not used
    board_to_cam : view index -> (R (3, 3), t (3,) metres) board pose, for the kept views
    coverage : (rows, cols) corner counts per image cell over the kept views
    """

    K: np.ndarray
    distortion: np.ndarray
    model: str
    image_size: tuple[int, int]
    std: dict
    rms_px: float
    view_rms_px: np.ndarray
    kept: np.ndarray
    rejected: dict
    board_to_cam: dict = field(repr=False)
    coverage: np.ndarray = field(repr=False)

    @property
    def coverage_fraction(self) -> float:
        """Share of the coverage cells holding at least one corner."""
        return float((self.coverage > 0).mean())


def coverage_grid(uv: np.ndarray, image_size, grid=(4, 3)) -> np.ndarray:
    """(rows, cols) counts of the pixels ``uv`` (N, 2) per cell of a ``grid = (cols, rows)`` split of the image."""
    w, h = image_size
    cols, rows = grid
    counts = np.zeros((rows, cols), int)
    if len(uv):
        cx = np.clip((uv[:, 0] + 0.5) * cols / w, 0, cols - 1).astype(int)
        cy = np.clip((uv[:, 1] + 0.5) * rows / h, 0, rows - 1).astype(int)
        np.add.at(counts, (cy, cx), 1)
    return counts


def _usable(view: CharucoCorners, spec: BoardSpec, min_corners: int) -> str | None:
    if len(view) < min_corners:
        return f"{len(view)} corners < {min_corners}"
    nx = spec.columns - 1
    if len(np.unique(view.ids % nx)) < 2 or len(np.unique(view.ids // nx)) < 2:
        return "corners on a single board row or column"
    return None


def calibrate_intrinsics(views, spec: BoardSpec, image_size, options: IntrinsicsOptions | None = None, *, camera: str = "camera"):
    """Calibrate one camera.

    views : sequence of :class:`CharucoCorners`, one per image (empty ones allowed)
    spec : the board; image_size : (width, height) pixels; camera : name used in messages
    returns :class:`IntrinsicsResult`
    raises ValueError naming ``camera`` when too few views are usable
    """
    opt = options or IntrinsicsOptions()
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise ValueError(f"{camera}: image_size must be positive (width, height), got {image_size!r}")
    views = list(views)
    board_pts = spec.corners_board_m.astype(np.float32)
    rejected: dict[int, str] = {}
    for i, v in enumerate(views):
        if len(v) and (v.ids.min() < 0 or v.ids.max() >= spec.n_corners):
            raise ValueError(f"{camera}: view {i} has corner ids up to {v.ids.max()} but the board has {spec.n_corners}")
        why = _usable(v, spec, opt.min_corners)
        if why:
            rejected[i] = why
    candidates = [i for i in range(len(views)) if i not in rejected]
    if len(candidates) < opt.min_views:
        n_any = sum(1 for v in views if v.n_markers > 0)
        hint = (" (ArUco markers were found but no corners: does the board spec's columns/rows/legacy_pattern match?)"
                if n_any and not any(len(v) for v in views) else "")
        raise ValueError(f"{camera}: {len(candidates)} usable board views of {len(views)} images, need >= {opt.min_views} "
                         f"with >= {opt.min_corners} corners each; markers seen in {n_any} images{hint}")
    flags = 0
    n_dist = DISTORTION_MODELS[opt.model]
    if opt.model == "rational_polynomial":
        flags |= cv2.CALIB_RATIONAL_MODEL
    if opt.fix_k3:
        flags |= cv2.CALIB_FIX_K3
    kept = list(candidates)
    for _ in range(opt.max_rounds):
        obj = [board_pts[views[i].ids] for i in kept]
        img = [views[i].uv.astype(np.float32) for i in kept]
        rms, K, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(obj, img, (w, h), None, None, flags=flags)
        per_view = np.asarray(per_view, float).ravel()
        limit = max(opt.reject_factor * float(np.median(per_view)), opt.reject_floor_px)
        bad = per_view > limit
        if not bad.any() or len(kept) - bad.sum() < opt.min_views:
            break
        for i, e in zip(kept, per_view):
            if e > limit:
                rejected[i] = f"RMS {e:.2f} px > {limit:.2f} px"
        kept = [i for i, b in zip(kept, bad) if not b]
    view_rms = np.full(len(views), np.nan)
    for i, v in enumerate(views):
        if i in kept or rejected.get(i, "").startswith("RMS"):
            view_rms[i] = _view_rms(v, board_pts, K, dist)
    std_in = np.asarray(std_in, float).ravel()
    std = {n: float(s) for n, s in zip(STD_NAMES[: 4 + n_dist], std_in[: 4 + n_dist])}
    poses = {i: (cv2.Rodrigues(r)[0], np.asarray(t, float).ravel()) for i, r, t in zip(kept, rvecs, tvecs)}
    kept_mask = np.zeros(len(views), bool)
    kept_mask[kept] = True
    uv_all = np.concatenate([views[i].uv for i in kept])
    return IntrinsicsResult(
        K=np.asarray(K, float), distortion=np.asarray(dist, float).ravel()[:n_dist], model=opt.model, image_size=(w, h),
        std=std, rms_px=float(rms), view_rms_px=view_rms, kept=kept_mask, rejected={i: rejected[i] for i in sorted(rejected)},
        board_to_cam=poses, coverage=coverage_grid(uv_all, (w, h), opt.grid),
    )


def _view_rms(view: CharucoCorners, board_pts: np.ndarray, K, dist) -> float:
    """RMS error of one view after its own PnP pose with the final intrinsics."""
    ok, r, t = cv2.solvePnP(board_pts[view.ids], view.uv.astype(np.float32), K, dist)
    if not ok:
        return float("nan")
    proj, _ = cv2.projectPoints(board_pts[view.ids], r, t, K, dist)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - view.uv) ** 2, axis=1))))
