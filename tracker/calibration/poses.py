"""Pose helpers for multi-camera calibration: rotations, rigid / similarity fits, pose graphs.

A pose ``(R, t)`` maps frame a to frame b: ``X_b = R @ X_a + t``. Camera poses are world -> camera.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["chain_poses", "mean_rotation", "reframe_poses", "rigid_fit", "rotation_angle_deg", "rvec_to_R", "R_to_rvec"]


def rvec_to_R(rvec: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors -> (..., 3, 3) matrices."""
    rvec = np.asarray(rvec, float)
    return Rotation.from_rotvec(rvec.reshape(-1, 3)).as_matrix().reshape(rvec.shape[:-1] + (3, 3))


def R_to_rvec(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) rotation vectors."""
    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """(...,) angle of ``R_a R_b^T`` in degrees."""
    D = np.einsum("...ij,...kj->...ik", R_a, R_b)
    c = (np.trace(D, axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of (N, 3, 3) rotations (projection of their sum onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.sum(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rigid_fit(A: np.ndarray, B: np.ndarray, *, scale: bool = False):
    """Least-squares ``B ~ s R A + t`` (Kabsch / Umeyama).

    A, B : (N, 3) corresponding points, N >= 3 not collinear
    returns (R (3, 3), t (3,), s)  (s = 1 unless ``scale``)
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    if A.shape != B.shape or A.ndim != 2 or A.shape[1] != 3 or len(A) < 3:
        raise ValueError(f"rigid_fit needs two (N >= 3, 3) arrays of the same shape, got {A.shape} and {B.shape}")
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    A0, B0 = A - ca, B - cb
    U, S, Vt = np.linalg.svd(B0.T @ A0)
    if S[1] < 1e-9 * max(S[0], 1e-300):
        raise ValueError("rigid_fit: the points are collinear; need three points not on a line")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / np.sum(A0 * A0)) if scale else 1.0
    return R, cb - s * R @ ca, s


def reframe_poses(R: np.ndarray, t: np.ndarray, X_calib: np.ndarray, X_world: np.ndarray, *, scale: bool = False):
    """Re-frame (and with ``scale`` re-scale) world -> camera poses R (n, 3, 3), t (n, 3) so points
    ``X_calib`` (N >= 3, 3) land on their known ``X_world``: returns (R', t', s, fit residual (N,) metres)."""
    A, b, s = rigid_fit(X_calib, X_world, scale=scale)
    Rn = R @ A.T
    tn = s * t - np.einsum("nij,j->ni", Rn, b)
    resid = np.linalg.norm(s * X_calib @ A.T + b - X_world, axis=1)
    return Rn, tn, s, resid


def chain_poses(n_cams: int, edges: dict, weights: dict, *, names=None, root: int = 0):
    """World -> camera poses from pairwise relative poses along a maximum-weight spanning tree.

    edges : (i, j) -> (R_ij, t_ij) mapping camera i's frame to camera j's
    weights : (i, j) -> support (shared observations); the tree keeps the best-supported pairs
    returns (R (n, 3, 3), t (n, 3)) with camera ``root`` at the world origin
    raises ValueError naming the cameras that share no view with the others
    """
    names = names or [f"camera {i}" for i in range(n_cams)]
    R = np.full((n_cams, 3, 3), np.nan)
    t = np.full((n_cams, 3), np.nan)
    R[root], t[root] = np.eye(3), np.zeros(3)
    done = {root}
    # Prim's algorithm on the support
    while len(done) < n_cams:
        best = None
        for (i, j), w in weights.items():
            for a, b, inv in ((i, j, False), (j, i, True)):
                if a in done and b not in done and (best is None or w > best[0]):
                    best = (w, a, b, inv, (i, j))
        if best is None:
            missing = [names[k] for k in range(n_cams) if k not in done]
            raise ValueError(f"cameras {missing} share no usable view with {[names[k] for k in sorted(done)]}: "
                             "move the wand / board where both groups see it")
        _, a, b, inv, key = best
        Rij, tij = edges[key]
        if inv:  # we need a -> b but have b -> a
            Rij, tij = Rij.T, -Rij.T @ tij
        R[b] = Rij @ R[a]
        t[b] = Rij @ t[a] + tij
        done.add(b)
    return R, t
