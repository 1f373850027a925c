"""tracker.size_test: the widths the 3D size test compares and the edge loss fit over many of them.

Sections: the widths agree with the ratio, accuracy on synthetic blobs a known edge loss narrower than
the ball (seeded), bad input. The size test on candidates and in the Tracker is tests/tracker/test_pipeline.py.
"""

from __future__ import annotations

import statistics

import numpy as np
import pytest


from tracker.size_test import EdgeLossFit, SizeTest, fit_edge_loss

RADIUS_M = 0.02


def _ball_px_independent(rig, X):
    """(n_cams,) a ball's width 2 r f / z at ``X``, computed here from the cameras (not by SizeTest)."""
    z = np.array([c.R_world_to_cam[2] @ X + c.t_world_to_cam_m[2] for c in rig])
    f = np.array([0.5 * (c.K[0, 0] + c.K[1, 1]) for c in rig])
    return 2.0 * RADIUS_M * f / z


def _synthetic_widths(rig, seed, slope, edge_px, noise_px, n_positions=200):
    """Blobs ``slope * ball - edge_px`` (+ Gaussian noise) wide at random positions in the workspace, seen by
    a random subset (>= 2) of the cameras; the pairs SizeTest.widths_px gives for them, concatenated."""
    rng = np.random.default_rng(seed)
    lo, hi = rig.workspace_m
    test = SizeTest(rig, None, RADIUS_M)
    blobs, balls = [], []
    for _ in range(n_positions):
        X = rng.uniform(lo, hi)
        cand = np.where(rng.random(len(rig)) < 0.7, 0, -1)
        cand[rng.choice(len(rig), 2, replace=False)] = 0
        width = slope * _ball_px_independent(rig, X) - edge_px + rng.normal(0.0, noise_px, len(rig))
        areas = np.pi / 4.0 * width[:, None] ** 2
        b, w = test.widths_px(X, cand, areas)
        blobs.append(b)
        balls.append(w)
    return np.concatenate(blobs), np.concatenate(balls)


# -- the widths ------------------------------------------------------------------------------------
def test_widths_are_the_ones_the_ratio_compares(rig):
    X = np.array([-1.0, 0.1, 1.3])
    cand = np.array([0, -1, 1, 0])
    areas = np.array([[50.0, np.nan], [np.nan, np.nan], [9.0, 70.0], [40.0, 3.0]])
    test = SizeTest(rig, None, RADIUS_M, edge_px=2.8)
    blob, ball = test.widths_px(X, cand, areas)
    assert blob.shape == ball.shape == (3,)
    np.testing.assert_allclose(blob, np.sqrt(4.0 / np.pi * np.array([50.0, 70.0, 40.0])))
    np.testing.assert_allclose(ball, _ball_px_independent(rig, X)[[0, 2, 3]])
    assert test.ratio(X, cand, areas) == pytest.approx(statistics.median((blob + 2.8) / ball), rel=1e-12)


# -- accuracy on synthetic blobs -------------------------------------------------------------------
def test_fit_recovers_a_known_edge_loss_exactly_without_noise(rig):
    blob, ball = _synthetic_widths(rig, 0, 0.98, 2.8, 0.0)
    fit = fit_edge_loss(blob, ball)
    assert isinstance(fit, EdgeLossFit) and fit.cameras == len(blob) >= 400
    assert fit.slope == pytest.approx(0.98, abs=1e-9) and fit.edge_loss_px == pytest.approx(2.8, abs=1e-8) and fit.residual_px < 1e-8


@pytest.mark.parametrize("edge_px", [0.0, 1.5, 2.8, 4.0])
def test_fit_recovers_a_known_edge_loss_in_noise(rig, edge_px):
    blob, ball = _synthetic_widths(rig, 1, 1.0, edge_px, 0.9)
    fit = fit_edge_loss(blob, ball)
    assert fit.edge_loss_px == pytest.approx(edge_px, abs=0.4) and fit.slope == pytest.approx(1.0, abs=0.05)
    assert fit.residual_px == pytest.approx(0.9, abs=0.1)  # the noise put in
    assert "ball width -" in str(fit) and f"{fit.cameras} cameras" in str(fit)
    # the same seed gives the same figure; another seed a different one
    assert fit_edge_loss(*_synthetic_widths(rig, 1, 1.0, edge_px, 0.9)) == fit
    assert fit_edge_loss(*_synthetic_widths(rig, 2, 1.0, edge_px, 0.9)) != fit


# -- bad input -------------------------------------------------------------------------------------
def test_fit_rejects_bad_input():
    with pytest.raises(ValueError, match=r"same length, got shapes \(3,\) and \(2,\)"):
        fit_edge_loss([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="got NaN or inf"):
        fit_edge_loss([1.0, np.nan], [1.0, 2.0])
    with pytest.raises(ValueError, match=">= 2 cameras with different ball widths, got 1"):
        fit_edge_loss([1.0], [2.0])
    with pytest.raises(ValueError, match="different ball widths, got 3"):
        fit_edge_loss([1.0, 2.0, 3.0], [5.0, 5.0, 5.0])
