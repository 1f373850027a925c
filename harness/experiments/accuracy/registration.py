"""Robot base frame -> camera world frame, estimated from the data (rigid Kabsch/Umeyama, trimmed re-fit).

On the real robot the cameras' world frame and the robot's base frame are calibrated separately, so the
accuracy experiment finds the transform from the run itself: FK ball positions in the base frame
(reported joints) against the tracker's positions in the camera world frame, on the first part of the
run only; the errors are then measured on the rest.

The fit is Umeyama's least-squares rigid transform without scale (S. Umeyama, "Least-squares estimation
of transformation parameters between two point patterns", IEEE TPAMI 13(4), 1991; the Kabsch fit of
``tracker.calibration.poses.rigid_fit``, shared with the calibration), made robust by a trimmed re-fit: fit
on all pairs, keep the pairs whose residual is within ``max(k * median, floor_m)``, fit again, until the
kept set no longer changes (at most ``max_iterations``). A wrong tracker position in the registration
part thus cannot pull the transform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.calibration.poses import rigid_fit

__all__ = ["RegistrationInfo", "RegistrationOptions", "fit_rigid", "register_rigid", "registration_std", "transform_difference"]


@dataclass(frozen=True)
class RegistrationOptions:
    """Trimming of :func:`register_rigid`: keep residuals <= max(trim_k * median, trim_floor_m)."""

    trim_k: float = 3.0
    trim_floor_m: float = 0.01
    max_iterations: int = 10
    min_pairs: int = 10

    def __post_init__(self):
        if not (isinstance(self.trim_k, (int, float)) and self.trim_k >= 1):
            raise ValueError(f"RegistrationOptions.trim_k must be >= 1, got {self.trim_k!r}")
        if not (isinstance(self.trim_floor_m, (int, float)) and self.trim_floor_m >= 0):
            raise ValueError(f"RegistrationOptions.trim_floor_m must be >= 0 m, got {self.trim_floor_m!r}")
        for name, low in (("max_iterations", 1), ("min_pairs", 3)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"RegistrationOptions.{name} must be an integer >= {low}, got {v!r}")


@dataclass(frozen=True)
class RegistrationInfo:
    """What :func:`register_rigid` found.

    inliers : (n,) bool, pairs used in the final fit
    residual_m : (n,) distance of every pair after the final fit, metres
    rms_m, max_m : over the inliers
    n_pairs, n_inliers, iterations
    spread_m : (3,) standard deviation of the inlier source points along their principal axes,
        largest first; a small second value means nearly collinear points and a poorly fixed rotation
    """

    inliers: np.ndarray
    residual_m: np.ndarray
    rms_m: float
    max_m: float
    n_pairs: int
    n_inliers: int
    iterations: int
    spread_m: np.ndarray


def _points(X, name: str) -> np.ndarray:
    arr = np.asarray(X, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite (drop frames without a position first)")
    return arr


def fit_rigid(X_src, X_dst) -> np.ndarray:
    """Least-squares rigid transform (no scale) with ``X_dst ~ R X_src + t``; returns T (4, 4) src -> dst.

    X_src, X_dst : (n, 3) corresponding points, n >= 3 and not all on one line.
    """
    A, B = _points(X_src, "X_src"), _points(X_dst, "X_dst")
    if A.shape != B.shape or len(A) < 3:
        raise ValueError(f"X_src and X_dst must be (n, 3) with the same n >= 3, got shapes {A.shape} and {B.shape}")
    s = np.linalg.svd(A - A.mean(axis=0), compute_uv=False)
    if s[1] <= 1e-9 * max(s[0], 1e-300):
        raise ValueError("X_src points are (nearly) collinear: the rotation about their line is undetermined")
    R, t, _ = rigid_fit(A, B)  # Kabsch / Umeyama without scale (tracker.calibration.poses)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def register_rigid(X_src, X_dst, options: RegistrationOptions = RegistrationOptions()) -> tuple[np.ndarray, RegistrationInfo]:
    """Robust rigid registration: trimmed re-fits of :func:`fit_rigid` (see the module docstring).

    X_src : (n, 3) points in the source frame (robot base); X_dst : (n, 3) in the destination (camera world)
    returns ``(T_src_to_dst (4, 4), RegistrationInfo)``
    """
    A, B = _points(X_src, "X_src"), _points(X_dst, "X_dst")
    if A.shape != B.shape:
        raise ValueError(f"X_src and X_dst must have the same shape, got {A.shape} and {B.shape}")
    if len(A) < options.min_pairs:
        raise ValueError(f"registration needs at least {options.min_pairs} point pairs, got {len(A)}")
    keep = np.ones(len(A), bool)
    for iterations in range(1, options.max_iterations + 1):
        T = fit_rigid(A[keep], B[keep])
        res = np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1)
        new = res <= max(options.trim_k * float(np.median(res[keep])), options.trim_floor_m)
        if new.sum() < options.min_pairs or (new == keep).all():
            break
        keep = new
    else:  # the last trim changed the kept set: fit it once more
        T = fit_rigid(A[keep], B[keep])
        res = np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1)
    r_in = res[keep]
    spread = np.linalg.svd(A[keep] - A[keep].mean(axis=0), compute_uv=False) / np.sqrt(keep.sum())
    return T, RegistrationInfo(keep, res, float(np.sqrt(np.mean(r_in**2))), float(r_in.max()), len(A), int(keep.sum()),
                               iterations, spread)


def registration_std(X_src_used, rms_m: float, X_query) -> np.ndarray:
    """(m,) first-order standard deviation (m) of where the fitted transform puts each query point.

    X_src_used : (n, 3) source points of the final fit; rms_m : its residual RMS; X_query : (m, 3) source
    points. Small rotation w and translation t move a point p by ``w x (p - c) + t`` (c the centroid); with
    residuals of ``rms_m / sqrt(3)`` per coordinate, ``Cov(w, t) = s^2 (sum J_i^T J_i)^-1``,
    ``J_i = [-[a_i]_x, I]``, ``a_i = X_i - c``. Large where the fit points do not fix the rotation (nearly
    collinear, or far from the query points).
    """
    A = _points(X_src_used, "X_src_used")
    Q = _points(X_query, "X_query")
    c = A.mean(axis=0)
    a = A - c
    S = np.einsum("ni,nj->ij", a, a)
    H = np.zeros((6, 6))
    H[:3, :3] = np.trace(S) * np.eye(3) - S  # sum [a]_x^T [a]_x
    H[3:, 3:] = len(A) * np.eye(3)  # the cross terms vanish: sum a_i = 0
    cov = (rms_m**2 / 3.0) * np.linalg.pinv(H)
    q = Q - c
    # J_q = [-[q]_x, I]: var = trace(J_q Cov J_q^T), batched
    qx = np.zeros((len(q), 3, 3))
    qx[:, 0, 1], qx[:, 0, 2], qx[:, 1, 2] = -q[:, 2], q[:, 1], -q[:, 0]
    qx[:, 1, 0], qx[:, 2, 0], qx[:, 2, 1] = q[:, 2], -q[:, 1], q[:, 0]
    J = np.concatenate([-qx, np.broadcast_to(np.eye(3), qx.shape)], axis=2)  # (m, 3, 6)
    return np.sqrt(np.einsum("mij,jk,mik->m", J, cov, J))


def transform_difference(T_a, T_b) -> tuple[float, float]:
    """(rotation angle in degrees, translation distance in metres) between two rigid transforms (4, 4)."""
    Ta, Tb = np.asarray(T_a, float), np.asarray(T_b, float)
    angle = float(np.degrees(Rotation.from_matrix(Ta[:3, :3].T @ Tb[:3, :3]).magnitude()))
    return angle, float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]))
