"""RANSAC over a second-order polynomial in time per axis: the consistent start of a ball flight.

The paper's RTBlob heuristic (sec. 3.2): "the RANSAC algorithm was used on a set of initial
observations fitting a second order polynomial". The model is ``X(t) = c0 + c1 tau + c2 tau^2``
per axis, ``tau = t - t_ref``; three observations determine it. One consensus loop (docs/filters.md,
sec. 3.1):

1. draw ``iterations`` triples of distinct observations with ``rng`` (all at once);
2. solve each triple's 3x3 Vandermonde system for the three axes (batched);
3. score every candidate by its truncated squared error (MSAC: ``sum min(|r|^2, thr^2)``) over all
   observations -- inliers are those within ``inlier_threshold_m`` (Euclidean, metres);
4. refit the best candidate by least squares on its inliers, re-select inliers, refit once more.

Returns ``(model, info)``; the model is None when fewer than ``min_inliers`` agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["QuadraticTrack", "RansacInfo", "ransac_quadratic"]


@dataclass(frozen=True)
class QuadraticTrack:
    """Per-axis quadratic in time. t_ref_s : reference time; coef : (3, 3) rows = powers 0..2, cols = x, y, z."""

    t_ref_s: float
    coef: np.ndarray

    def position(self, t_s) -> np.ndarray:
        """t_s (M,) -> (M, 3) m."""
        tau = np.asarray(t_s, float) - self.t_ref_s
        return self.coef[0] + tau[:, None] * self.coef[1] + tau[:, None] ** 2 * self.coef[2]

    def velocity(self, t_s) -> np.ndarray:
        """t_s (M,) -> (M, 3) m/s."""
        tau = np.asarray(t_s, float) - self.t_ref_s
        return self.coef[1] + 2.0 * tau[:, None] * self.coef[2]


def _lstsq(tau: np.ndarray, X: np.ndarray) -> np.ndarray:
    V = np.stack([np.ones_like(tau), tau, tau**2], axis=1)
    return np.linalg.lstsq(V, X, rcond=None)[0]


@dataclass(frozen=True)
class RansacInfo:
    """What :func:`ransac_quadratic` found besides the track.

    inliers : (N,) bool, the observations within the threshold of the refined track; n_inliers : their
    count; rms_m : their RMS distance from it, metres (NaN without inliers); iterations : candidate
    triples drawn
    """

    inliers: np.ndarray
    n_inliers: int
    rms_m: float
    iterations: int


def ransac_quadratic(t_s: np.ndarray, X: np.ndarray, *, inlier_threshold_m: float, min_inliers: int,
                     iterations: int, rng: np.random.Generator) -> tuple[QuadraticTrack | None, RansacInfo]:
    """Consensus quadratic track of observations.

    t_s : (N,) strictly increasing times, s;  X : (N, 3) positions, m (trusted: checked by the caller)
    Returns ``(track | None, RansacInfo)``.
    """
    n = len(t_s)
    t_ref = float(t_s[0])
    tau = t_s - t_ref
    scale = max(float(tau[-1]), 1e-6)
    u = tau / scale  # conditioning: solve in [0, 1], rescale the coefficients after
    # 1. candidate triples: the 3 smallest of N random keys per row = distinct indices, uniformly.
    idx = np.sort(np.argsort(rng.random((iterations, n)), axis=1)[:, :3], axis=1)
    ut = u[idx]  # (K, 3)
    V = np.stack([np.ones_like(ut), ut, ut**2], axis=2)  # (K, 3, 3)
    det = (ut[:, 1] - ut[:, 0]) * (ut[:, 2] - ut[:, 0]) * (ut[:, 2] - ut[:, 1])
    ok = np.abs(det) > 1e-12
    coef = np.zeros((iterations, 3, 3))
    if ok.any():
        coef[ok] = np.linalg.solve(V[ok], X[idx[ok]])  # 2. (K, powers, axes)
    # 3. MSAC score over all observations
    Vall = np.stack([np.ones_like(u), u, u**2], axis=1)  # (N, 3)
    pred = np.einsum("np,kpa->kna", Vall, coef)
    err2 = np.sum((pred - X[None]) ** 2, axis=2)  # (K, N)
    thr2 = inlier_threshold_m**2
    cost = np.minimum(err2, thr2).sum(axis=1)
    cost[~ok] = np.inf
    best = int(np.argmin(cost))
    inliers = err2[best] < thr2
    # 4. refine on the inliers (twice: refit, re-select)
    c = coef[best]
    for _ in range(2):
        if inliers.sum() < 3:
            break
        c = _lstsq(u[inliers], X[inliers])
        inliers = np.sum((Vall @ c - X) ** 2, axis=1) < thr2
    k = int(inliers.sum())
    rms = float(np.sqrt(np.mean(np.sum((Vall[inliers] @ c - X[inliers]) ** 2, axis=1)))) if k else float("nan")
    info = RansacInfo(inliers, k, rms, int(iterations))
    if k < max(min_inliers, 3):
        return None, info
    coef_t = c / np.array([1.0, scale, scale**2])[:, None]  # back to seconds
    return QuadraticTrack(t_ref, coef_t), info
