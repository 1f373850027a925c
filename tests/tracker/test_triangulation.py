"""Triangulation: linear N-view, batched two-view, the batched camera model and LM refinement."""

from __future__ import annotations

import numpy as np
import pytest

from tests.tracker._tracker_scenes import shipped_rig
from tracker import Camera, Rig, refine_point, triangulate, triangulate_linear, triangulate_pairs
from tracker.triangulation import camera_pairs, project_points, projection_jacobian, reprojection_errors


@pytest.fixture(scope="module")
def rig():
    return shipped_rig("sim_c8")


def normalised(rig, X):
    """(n_cams, 2) exact normalised coordinates of X in every camera."""
    Xc = np.einsum("nij,j->ni", rig.stacked()["R"], X) + rig.stacked()["t"]
    return Xc[:, :2] / Xc[:, 2:]


# -- smoke ------------------------------------------------------------------------------------------
def test_linear_recovers_exact_point(rig):
    X = np.array([-1.0, 0.3, 1.2])
    assert np.allclose(triangulate_linear(normalised(rig, X), rig.stacked()["P"]), X, atol=1e-12)


def test_triangulate_convenience_with_distorted_pixels(rig):
    X = np.array([-0.4, -0.6, 0.9])
    X_hat, err = triangulate(rig, rig.project(X))
    assert np.allclose(X_hat, X, atol=1e-9)
    assert err.shape == (len(rig),) and err.max() < 1e-6


# -- shapes and batching ------------------------------------------------------------------------------
def test_batched_equals_single(rig):
    rng = np.random.default_rng(0)
    X = rng.uniform(*rig.workspace_m, size=(7, 3))
    xn = np.stack([normalised(rig, x) for x in X])  # (7, n, 2)
    xn += rng.normal(0, 1e-3, xn.shape)
    batched = triangulate_linear(xn, rig.stacked()["P"])
    assert batched.shape == (7, 3)
    for b in range(7):
        assert np.allclose(batched[b], triangulate_linear(xn[b], rig.stacked()["P"]), atol=1e-12)


def test_pairs_equal_two_view_linear(rig):
    rng = np.random.default_rng(1)
    P = rig.stacked()["P"]
    pairs = camera_pairs(len(rig))
    assert pairs.shape == (len(rig) * (len(rig) - 1) // 2, 2) and (pairs[:, 0] < pairs[:, 1]).all()
    assert pairs[:3].tolist() == [[0, 1], [0, 2], [0, 3]]  # Algorithm 2's loop order
    xn = normalised(rig, np.array([-1.2, 0.1, 1.3])) + rng.normal(0, 2e-3, (len(rig), 2))
    i, j = pairs[:, 0], pairs[:, 1]
    X = triangulate_pairs(xn[i], xn[j], P[i], P[j])
    assert X.shape == (len(pairs), 3)
    for k in (0, 5, len(pairs) - 1):
        assert np.allclose(X[k], triangulate_linear(xn[[i[k], j[k]]], P[[i[k], j[k]]]), atol=1e-12)


def test_nan_views_are_ignored_and_too_few_give_nan(rig):
    X = np.array([-1.0, 0.0, 1.0])
    xn = normalised(rig, X)
    xn[[1, 4]] = np.nan
    assert np.allclose(triangulate_linear(xn, rig.stacked()["P"]), X, atol=1e-12)
    xn[2:] = np.nan
    xn[1] = np.nan
    assert np.isnan(triangulate_linear(xn, rig.stacked()["P"])).all()  # one view left


def test_zero_weight_drops_a_view(rig):
    X = np.array([-1.0, 0.0, 1.0])
    xn = normalised(rig, X)
    xn[3] += 0.5  # a gross outlier in view 3
    w = np.ones(len(rig))
    w[3] = 0
    assert np.allclose(triangulate_linear(xn, rig.stacked()["P"], weights=w), X, atol=1e-12)
    assert not np.allclose(triangulate_linear(xn, rig.stacked()["P"]), X, atol=1e-3)


def test_parallel_rays_give_nan():
    R = np.eye(3)
    P = np.stack([np.hstack([R, [[0], [0], [1]]]), np.hstack([R, [[0], [0], [2]]])])  # same optical axis
    assert np.isnan(triangulate_linear(np.zeros((2, 2)), P)).all()


def test_project_points_matches_rig_project(rig):
    X = np.random.default_rng(2).uniform(*rig.workspace_m, size=(20, 3))
    assert np.allclose(project_points(X, rig), np.swapaxes(rig.project(X), 0, 1), atol=1e-9)


# -- bad input ----------------------------------------------------------------------------------------
def test_bad_input_raises(rig):
    P = rig.stacked()["P"]
    with pytest.raises(ValueError, match=r"xn must have shape"):
        triangulate_linear(np.zeros(3), P)
    with pytest.raises(ValueError, match=r"P must have shape"):
        triangulate_linear(np.zeros((len(rig), 2)), P[:3])
    with pytest.raises(ValueError, match=r"xn must not contain inf"):
        triangulate_linear(np.full((len(rig), 2), np.inf), P)
    with pytest.raises(ValueError, match=r"weights must be finite and non-negative"):
        triangulate_linear(np.zeros((len(rig), 2)), P, weights=-np.ones(len(rig)))
    with pytest.raises(ValueError, match=r"weights must broadcast"):
        triangulate_linear(np.zeros((len(rig), 2)), P, weights=np.ones(3))
    with pytest.raises(ValueError, match=r"uv must have shape \(8, 2\) for this rig, got shape \(3, 2\)"):
        triangulate(rig, np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"uv must not contain inf"):
        triangulate(rig, np.full((len(rig), 2), np.inf))
    with pytest.raises(ValueError, match=r"X_world must have shape"):
        project_points(np.zeros((2, 4)), rig)


# -- accuracy on a synthetic scene ----------------------------------------------------------------------
def test_jacobian_matches_finite_differences(rig):
    X = np.array([-0.9, 0.4, 1.4])
    J = projection_jacobian(X, rig)
    h = 1e-6
    num = np.stack([(project_points(X + h * e, rig)[0] - project_points(X - h * e, rig)[0]) / (2 * h) for e in np.eye(3)], axis=-1)
    assert J.shape == (len(rig), 2, 3)
    assert np.allclose(J, num, rtol=1e-6, atol=1e-4)


def test_refinement_lowers_pixel_error_under_distortion():
    """The linear solution ignores distortion-weighted pixel geometry; LM minimises the pixel loss."""
    rng = np.random.default_rng(3)
    rig = shipped_rig("sim_c4")
    X = np.array([-1.5, 0.7, 1.6])
    uv = rig.project(X) + rng.normal(0, 1.3, (4, 2))
    xn = np.stack([c.undistort(uv[i]) for i, c in enumerate(rig)])
    X_lin = triangulate_linear(xn, rig.stacked()["P"])
    X_ref, cost = refine_point(X_lin, uv, rig)
    e_lin = reprojection_errors(X_lin, uv, rig)
    assert cost == pytest.approx(np.sum(reprojection_errors(X_ref, uv, rig) ** 2))
    assert cost < np.sum(e_lin**2)
    # the refined point is the least-squares optimum: the gradient J^T r vanishes there
    J = projection_jacobian(X_ref, rig).reshape(-1, 3)
    r = (project_points(X_ref, rig)[0] - uv).ravel()
    assert np.abs(J.T @ r).max() < 1e-6 * np.abs(J).max()


def test_refine_respects_mask(rig):
    X = np.array([-1.0, 0.2, 1.1])
    uv = rig.project(X)
    uv[2] += 40.0  # an outlier camera, masked out
    mask = np.ones(len(rig), bool)
    mask[2] = False
    X_hat, cost = refine_point(X + 0.01, uv, rig, mask)
    assert np.allclose(X_hat, X, atol=1e-9) and cost < 1e-12


# -- statistical check (seeded) -------------------------------------------------------------------------
def test_refined_error_is_unbiased_and_small():
    rig = shipped_rig("sim_c8")
    rng = np.random.default_rng(4)
    X = np.array([-1.1, 0.0, 1.26])
    errs = []
    for _ in range(300):
        X_hat, _ = triangulate(rig, rig.project(X) + rng.normal(0, 1.3, (8, 2)))
        errs.append(X_hat - X)
    errs = np.array(errs)
    sem = errs.std(axis=0) / np.sqrt(len(errs))
    assert (np.abs(errs.mean(axis=0)) < 4 * sem).all()  # no bias beyond 4 standard errors
    assert np.median(np.linalg.norm(errs, axis=1)) < 0.01  # sub-centimetre with 8 cameras


def test_single_camera_rig_returns_nan():
    cam = Camera("only", np.diag([500.0, 500.0, 1.0]) + [[0, 0, 320], [0, 0, 240], [0, 0, 0]], [], np.eye(3), [0, 0, 0], (640, 480))
    X, err = triangulate(Rig([cam]), [[320.0, 240.0]])
    assert np.isnan(X).all() and np.isnan(err).all()
