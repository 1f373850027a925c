"""Camera model: projection and undistortion against OpenCV, batching, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tracker import Camera
from tracker.distortion import (
    distort,
    distort_jacobian,
    distort_point,
    distort_point_jacobian,
    undistort,
    undistort_point,
)


def look_at(center, target, up=(0.0, 0.0, 1.0)):
    """R_world_to_cam, t for a camera at ``center`` looking at ``target`` (OpenCV axes)."""
    center, target, up = (np.asarray(v, float) for v in (center, target, up))
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ center


def make_camera(dist=(-0.21, 0.12, 0.001, -0.0005, -0.03), name="c0", skew=0.0):
    R, t = look_at([2.0, -1.5, 2.5], [0.0, 0.0, 1.0])
    K = [[620.0, skew, 322.0], [0.0, 615.0, 241.0], [0.0, 0.0, 1.0]]
    return Camera(name, K, list(dist), R, t, (640, 480))


def random_points(rng, n=500):
    return rng.uniform([-0.7, -0.7, 0.5], [0.7, 0.7, 1.6], (n, 3))


# -- smoke and shapes ---------------------------------------------------------------------------
def test_single_and_batched_projection_agree():
    cam = make_camera()
    X = random_points(np.random.default_rng(0), 20)
    uv = cam.project(X)
    assert uv.shape == (20, 2)
    assert np.allclose(cam.project(X[3]), uv[3])
    assert cam.project(X[3]).shape == (2,)
    assert cam.undistort(uv[3]).shape == (2,)


def test_camera_is_immutable():
    cam = make_camera()
    with pytest.raises(ValueError):
        cam.K[0, 0] = 1.0
    with pytest.raises(AttributeError):
        cam.name = "other"


# -- accuracy against OpenCV ----------------------------------------------------------------------
@pytest.mark.parametrize(
    "dist",
    [(), (-0.21, 0.12, 0.001, -0.0005), (-0.21, 0.12, 0.001, -0.0005, -0.03), (0.3, -0.1, 0.001, 0.002, 0.01, 0.4, -0.05, 0.02)],
    ids=["none", "4", "plumb_bob", "rational"],
)
def test_projection_matches_opencv(dist):
    cam = make_camera(dist)
    X = random_points(np.random.default_rng(1))
    rvec, _ = cv2.Rodrigues(cam.R_world_to_cam)
    d = np.asarray(dist, float) if dist else np.zeros(5)
    uv_cv, _ = cv2.projectPoints(X, rvec, cam.t_world_to_cam_m, cam.K, d)
    assert np.abs(cam.project(X) - uv_cv[:, 0]).max() < 1e-8


@pytest.mark.parametrize("dist", [(-0.21, 0.12, 0.001, -0.0005, -0.03), (0.3, -0.1, 0.001, 0.002, 0.01, 0.4, -0.05, 0.02)])
def test_undistort_inverts_projection_to_image_corners(dist):
    cam = make_camera(dist)
    # A grid of normalised points out to the image corners (where fixed-point iteration struggles).
    g = np.linspace(-0.62, 0.62, 25)
    xn = np.stack(np.meshgrid(g, g * 0.8), axis=-1).reshape(-1, 2)
    uv = cam.normalised_to_pixels(xn)
    assert np.abs(cam.undistort(uv) - xn).max() < 1e-10


def test_undistort_agrees_with_opencv_in_the_image_centre():
    cam = make_camera()
    rng = np.random.default_rng(2)
    uv = rng.uniform([160, 120], [480, 360], (200, 2))
    ref = cv2.undistortPoints(uv[:, None], cam.K, cam.distortion, criteria=(cv2.TERM_CRITERIA_COUNT, 100, 0))[:, 0]
    assert np.abs(cam.undistort(uv) - ref).max() < 1e-9


def test_skew_is_honoured():
    cam = make_camera(skew=3.0)
    X = random_points(np.random.default_rng(3), 50)
    assert np.abs(cam.undistort(cam.project(X)) - (cam.to_camera(X)[:, :2] / cam.to_camera(X)[:, 2:])).max() < 1e-10


def test_distortion_roundtrip_functions():
    rng = np.random.default_rng(4)
    d8 = np.array([-0.2, 0.1, 0.001, 0.002, -0.02, 0.0, 0.0, 0.0])
    xn = rng.uniform(-0.5, 0.5, (100, 2))
    assert np.abs(undistort(distort(xn, d8), d8) - xn).max() < 1e-12


# -- the one lens model: numpy and numba twins agree ----------------------------------------------
RATIONAL = np.array([0.3, -0.1, 0.001, 0.002, 0.01, 0.4, -0.05, 0.02])
PLUMB_BOB = np.array([-0.21, 0.12, 0.001, -0.0005, -0.03, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("d8", [PLUMB_BOB, RATIONAL], ids=["plumb_bob", "rational"])
def test_numba_distortion_twins_match_numpy(d8):
    xn = np.random.default_rng(6).uniform(-0.6, 0.6, (300, 2))
    xd, J = distort_jacobian(xn, d8)
    assert np.array_equal(distort(xn, d8), xd)
    for (x, y), ref, Jref in zip(xn, xd, J):
        assert distort_point(x, y, *d8) == pytest.approx(tuple(ref), abs=1e-15)
        xd_, yd_, j00, j01, j11 = distort_point_jacobian(x, y, *d8)
        assert (xd_, yd_) == pytest.approx(tuple(ref), abs=1e-15)
        assert (j00, j01, j01, j11) == pytest.approx(tuple(Jref.ravel()), abs=1e-14)
        assert undistort_point(*ref, *d8) == pytest.approx((x, y), abs=1e-10)  # stops at a 1e-12 residual
    assert np.abs(undistort(xd, d8) - xn).max() < 1e-12


def test_distortion_jacobian_matches_finite_differences():
    xn = np.random.default_rng(7).uniform(-0.5, 0.5, (50, 2))
    _, J = distort_jacobian(xn, RATIONAL)
    h = 1e-7
    for k in range(2):
        step = np.zeros(2)
        step[k] = h
        fd = (distort(xn + step, RATIONAL) - distort(xn - step, RATIONAL)) / (2 * h)
        assert np.abs(J[:, :, k] - fd).max() < 1e-7


def test_distortion_broadcasts_one_coefficient_row_per_camera():
    # (n_cams, 8) coefficients with (M, n_cams, 2) points: each camera applies its own lens.
    xn = np.random.default_rng(8).uniform(-0.5, 0.5, (10, 2, 2))
    both = distort(xn, np.stack([PLUMB_BOB, RATIONAL]))
    assert np.array_equal(both[:, 0], distort(xn[:, 0], PLUMB_BOB))
    assert np.array_equal(both[:, 1], distort(xn[:, 1], RATIONAL))


def test_rays_point_at_the_world_points():
    cam = make_camera()
    X = random_points(np.random.default_rng(5), 30)
    d = cam.rays_world(cam.project(X))
    to_X = X - cam.center_world
    to_X /= np.linalg.norm(to_X, axis=1, keepdims=True)
    assert np.abs(d - to_X).max() < 1e-9


def test_points_behind_camera_project_to_nan_and_nan_passes_through():
    cam = make_camera()
    behind = cam.center_world - (cam.R_world_to_cam[2] * 1.0)
    assert np.isnan(cam.project(behind)).all()
    assert np.isnan(cam.undistort(np.array([[np.nan, np.nan], [320.0, 240.0]]))[0]).all()
    assert cam.depth(behind)[0] < 0


def test_in_image():
    cam = make_camera()
    inside = cam.in_image([[0, 0], [639, 479], [-0.6, 10], [10, 480], [np.nan, 5]])
    assert inside.tolist() == [True, True, False, False, False]


# -- bad input ----------------------------------------------------------------------------------------
def _fields(**over):
    R, t = look_at([2.0, -1.5, 2.5], [0.0, 0.0, 1.0])
    f = dict(name="bad", K=np.diag([600.0, 600.0, 1.0]), distortion=[0.0] * 5, R_world_to_cam=R, t_world_to_cam_m=t, image_size=(640, 480))
    f.update(over)
    return f


@pytest.mark.parametrize(
    "over, match",
    [
        (dict(K=np.diag([-600.0, 600.0, 1.0])), "focal lengths must be positive"),
        (dict(K=np.diag([600.0, 0.0, 1.0])), "focal lengths must be positive"),
        (dict(K=np.eye(2)), r"K must have shape \(3, 3\)"),
        (dict(K=[[600, 0, 320], [0, 600, 240], [0, 0, 2]]), "last row"),
        (dict(K=np.full((3, 3), np.nan)), "K must not contain NaN"),
        (dict(distortion=[0.1, 0.2, 0.3]), "0, 4, 5 or 8 coefficients, got 3"),
        (dict(R_world_to_cam=np.diag([1.0, 1.0, 1.1])), "R_world_to_cam is not orthonormal"),
        (dict(R_world_to_cam=np.diag([1.0, 1.0, -1.0])), "reflection"),
        (dict(t_world_to_cam_m=[0, 0]), r"t_world_to_cam_m must have shape \(3,\)"),
        (dict(image_size=(640, 0)), "image_size must be two positive integers"),
        (dict(image_size=(640.5, 480)), "image_size must be two positive integers"),
        (dict(name=""), "camera name must be a non-empty string"),
        (dict(K="abc"), "K must be numeric"),
    ],
)
def test_bad_camera_fields_name_the_field(over, match):
    with pytest.raises(ValueError, match=match):
        Camera(**_fields(**over))


def test_bad_point_arrays():
    cam = make_camera()
    with pytest.raises(ValueError, match=r"X_world must have shape \(N, 3\)"):
        cam.project(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="uv must not contain inf"):
        cam.undistort([[np.inf, 1.0]])
