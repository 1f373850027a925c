"""Synthetic observations of a ball for the robust estimator: the simulation study's generator
(paper Sec. 3.1), also the scene generator of tracker's own tests.

A uniformly random ball position in the rig's workspace box, projected into every camera, plus
Gaussian pixel noise (1.3 px by default); with probability ``p_outlier`` a camera's pixel is replaced
by a uniformly random pixel of its image. Randomness comes only from the ``rng`` passed in.
"""

from __future__ import annotations

import numpy as np

from tracker.rig import Rig

__all__ = ["simulate_observations"]


def simulate_observations(rig: Rig, n_frames: int, p_outlier: float, rng: np.random.Generator, *, pixel_sigma_px: float = 1.3):
    """Synthetic frames of the Sec. 3.1 study.

    returns X_true (n_frames, 3) world points in ``rig.workspace_m``; uv (n_frames, n_cams, 2)
    distorted pixels (noisy projections, outliers replaced by uniform pixels of the image);
    is_outlier (n_frames, n_cams) bool
    """
    if rig.workspace_m is None:
        raise ValueError("simulate_observations needs a rig with a workspace box (workspace_m)")
    if not 0.0 <= p_outlier <= 1.0:
        raise ValueError(f"p_outlier must be in [0, 1], got {p_outlier!r}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    lo, hi = rig.workspace_m
    X = rng.uniform(lo, hi, size=(n_frames, 3))
    uv = np.swapaxes(rig.project(X), 0, 1)  # (n_frames, n_cams, 2)
    uv = uv + rng.normal(0.0, pixel_sigma_px, size=uv.shape)
    is_out = rng.random(uv.shape[:2]) < p_outlier
    size = rig.stacked()["image_size"]  # (n_cams, 2) width, height
    random_px = rng.uniform(0.0, 1.0, size=uv.shape) * size - 0.5  # pixel centres span [-0.5, size - 0.5]
    uv = np.where(is_out[..., None], random_px, uv)
    return X, uv, is_out
