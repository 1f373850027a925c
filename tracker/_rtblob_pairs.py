"""RTBlob stereo: each fixed camera pair triangulated on its own by the linear method.

Lampert & Peters 2012 use two fixed stereo pairs of their four cameras; each pair gives its own 3D
position and nothing checks the two against each other (RT2 paper, Sec. 1.2). Here:

    (4) for a pair (a, b) with undistorted normalised points x_a, x_b and P_i = [R_i | t_i]:
        the linear two-view triangulation of ``tracker.triangulation.triangulate_pairs``, i.e. the
        DLT rows  x P^3 X - P^1 X = 0,  y P^3 X - P^2 X = 0  of both views solved for X
        (Hartley & Zisserman 2003, Sec. 12.2, "linear triangulation methods")
    (5) covariance of X from isotropic pixel noise sigma, first order:
        C = sigma^2 (J^T J)^-1,  J = d(uv_a, uv_b)/dX (4 x 3) at X, from
        ``tracker.triangulation.projection_jacobian`` (full camera model, analytic)
        (Hartley & Zisserman 2003, Sec. 5.2.3, backward propagation of covariance)

All pairs are triangulated in one batched call. No cheirality and no consistency check: that is
the baseline.
"""

from __future__ import annotations

import numpy as np

from tracker.rig import Rig
from tracker.triangulation import projection_jacobian, triangulate_pairs

__all__ = ["pair_covariances", "triangulate_fixed_pairs"]


def triangulate_fixed_pairs(rig: Rig, uv_px: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Eq. (4) for every pair at once.

    rig : the cameras (rows of ``uv_px`` follow rig order)
    uv_px : (n_cams, 2) distorted pixels, NaN where a camera has no detection
    pairs : (n_pairs, 2) int camera indices
    returns (n_pairs, 3) world points, metres; NaN where a pixel is missing or the two rays are
    parallel
    """
    uv_px = np.asarray(uv_px, float)
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    xn = np.full((len(rig), 2), np.nan)
    for i in np.unique(pairs):  # one undistortion per camera, not per pixel
        if np.isfinite(uv_px[i]).all():
            xn[i] = rig[int(i)].undistort(uv_px[i])
    P = rig.stacked()["P"]  # (n_cams, 3, 4) normalised projections [R | t]
    return triangulate_pairs(xn[pairs[:, 0]], xn[pairs[:, 1]], P[pairs[:, 0]], P[pairs[:, 1]])


def pair_covariances(rig: Rig, X_world: np.ndarray, pairs: np.ndarray, sigma_px: float) -> np.ndarray:
    """Eq. (5) for each pair.

    X_world : (n_pairs, 3) the pairs' triangulated points (NaN rows give NaN covariances)
    pairs : (n_pairs, 2) int camera indices
    sigma_px : standard deviation of the pixel noise, per coordinate
    returns (n_pairs, 3, 3) covariances, m^2; NaN where J^T J is singular or a point is behind a camera
    """
    X_world = np.asarray(X_world, float).reshape(-1, 3)
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    C = np.full((len(pairs), 3, 3), np.nan)
    for k, pair in enumerate(pairs):  # a handful of pairs; each Jacobian covers every camera at once
        if not np.isfinite(X_world[k]).all():
            continue
        J = projection_jacobian(X_world[k], rig)[pair].reshape(4, 3)  # (2 views x 2 coords, 3)
        if not np.isfinite(J).all():
            continue
        JtJ = J.T @ J
        if np.linalg.cond(JtJ) > 1e12:
            continue
        C[k] = sigma_px**2 * np.linalg.inv(JtJ)
    return C
