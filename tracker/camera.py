"""Pinhole camera with OpenCV lens distortion, batched over points.

Conventions (OpenCV's): a world point ``X_world`` maps to camera coordinates
``X_cam = R_world_to_cam @ X_world + t_world_to_cam_m``; the camera looks along +z, x to the
right, y down. Normalised image coordinates are ``(X_cam[0] / X_cam[2], X_cam[1] / X_cam[2])``;
distortion maps them to distorted normalised coordinates and ``K`` to pixels. Pixel (0, 0) is the
centre of the top-left pixel.

Distortion coefficients follow OpenCV's order ``k1, k2, p1, p2[, k3[, k4, k5, k6]]``:
``plumb_bob`` has 5, ``rational_polynomial`` has 8, ``none`` has 0; the model itself is
:mod:`tracker.distortion`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from checks.arrays import check_array, check_finite, check_rotation, describe
from tracker.distortion import distort, undistort

__all__ = ["Camera", "DISTORTION_MODELS"]

#: Distortion model name -> number of coefficients (OpenCV order).
DISTORTION_MODELS = {"none": 0, "plumb_bob": 5, "rational_polynomial": 8}


def _pad8(coeffs: np.ndarray) -> np.ndarray:
    out = np.zeros(8)
    out[: len(coeffs)] = coeffs
    return out


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera. Immutable; build a new one to change it.

    name : unique name within a rig
    K : (3, 3) intrinsics, ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels
    distortion : (0,), (4,), (5,) or (8,) OpenCV coefficients ``k1, k2, p1, p2[, k3[, k4, k5, k6]]``
    R_world_to_cam : (3, 3) rotation world -> camera
    t_world_to_cam_m : (3,) translation world -> camera, metres
    image_size : (width, height) in pixels
    """

    name: str
    K: np.ndarray
    distortion: np.ndarray
    R_world_to_cam: np.ndarray
    t_world_to_cam_m: np.ndarray
    image_size: tuple[int, int]
    dist8: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        where = f"camera {self.name!r}"
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"camera name must be a non-empty string, got {describe(self.name)}")
        K = check_array(self.K, "K", (3, 3), where=where)
        check_finite(K, "K", where=where)
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"{where}: focal lengths must be positive, got fx={K[0, 0]!r}, fy={K[1, 1]!r}")
        if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise ValueError(f"{where}: K must be upper triangular with last row [0, 0, 1], got {K.tolist()}")
        d = check_array(self.distortion, "distortion", (None,), where=where)
        if len(d) not in (0, 4, 5, 8):
            raise ValueError(f"{where}: distortion must have 0, 4, 5 or 8 coefficients, got {len(d)}")
        check_finite(d, "distortion", where=where)
        R = check_array(self.R_world_to_cam, "R_world_to_cam", (3, 3), where=where)
        check_finite(R, "R_world_to_cam", where=where)
        check_rotation(R, "R_world_to_cam", where=where)
        t = check_array(self.t_world_to_cam_m, "t_world_to_cam_m", (3,), where=where)
        check_finite(t, "t_world_to_cam_m", where=where)
        size = check_array(self.image_size, "image_size", (2,), where=where)
        if (size <= 0).any() or (size != np.round(size)).any():
            raise ValueError(f"{where}: image_size must be two positive integers (width, height), got {size.tolist()}")
        for name, value in (("K", K), ("distortion", d), ("R_world_to_cam", R), ("t_world_to_cam_m", t)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))
        d8 = _pad8(d)
        d8.setflags(write=False)
        object.__setattr__(self, "dist8", d8)

    # -- derived quantities ---------------------------------------------------------------------
    @property
    def distortion_model(self) -> str:
        """``none``, ``plumb_bob`` or ``rational_polynomial`` (4 coefficients count as plumb_bob)."""
        return {0: "none", 4: "plumb_bob", 5: "plumb_bob", 8: "rational_polynomial"}[len(self.distortion)]

    @property
    def center_world(self) -> np.ndarray:
        """(3,) optical centre in the world frame, metres."""
        return -self.R_world_to_cam.T @ self.t_world_to_cam_m

    @property
    def cam_to_world(self) -> np.ndarray:
        """(4, 4) homogeneous transform camera -> world."""
        T = np.eye(4)
        T[:3, :3] = self.R_world_to_cam.T
        T[:3, 3] = self.center_world
        return T

    @property
    def P_normalised(self) -> np.ndarray:
        """(3, 4) ``[R | t]``: projection to normalised (undistorted) image coordinates."""
        return np.hstack([self.R_world_to_cam, self.t_world_to_cam_m[:, None]])

    # -- mapping points ---------------------------------------------------------------------------
    def to_camera(self, X_world) -> np.ndarray:
        """(N, 3) world points -> (N, 3) camera-frame points."""
        X = _points(X_world, "X_world", 3)
        return X @ self.R_world_to_cam.T + self.t_world_to_cam_m

    def depth(self, X_world) -> np.ndarray:
        """(N,) depth (camera z, metres) of world points; <= 0 means behind the camera."""
        return self.to_camera(X_world)[:, 2]

    def normalised_to_pixels(self, xn) -> np.ndarray:
        """(N, 2) undistorted normalised coordinates -> (N, 2) distorted pixels."""
        xn = _points(xn, "xn", 2)
        xd = distort(xn, self.dist8)
        K = self.K
        return np.stack(
            [K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2], K[1, 1] * xd[:, 1] + K[1, 2]], axis=-1
        )

    def project(self, X_world) -> np.ndarray:
        """Project world points to distorted pixels.

        X_world : (N, 3) or (3,) world points, metres
        returns (N, 2) or (2,) distorted pixels; NaN for points at or behind the camera plane
        """
        single = np.ndim(X_world) == 1
        Xc = self.to_camera(X_world)
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = Xc[:, :2] / z[:, None]
        xn[z <= 0] = np.nan
        uv = self.normalised_to_pixels(xn)
        return uv[0] if single else uv

    def undistort(self, uv) -> np.ndarray:
        """Distorted pixels -> undistorted normalised image coordinates.

        uv : (N, 2) or (2,) distorted pixels (NaN rows pass through as NaN)
        returns (N, 2) or (2,) normalised coordinates ``(x/z, y/z)``
        """
        single = np.ndim(uv) == 1
        uv = _points(uv, "uv", 2)
        K = self.K
        yd = (uv[:, 1] - K[1, 2]) / K[1, 1]
        xd = (uv[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        xn = undistort(np.stack([xd, yd], axis=-1), self.dist8)
        return xn[0] if single else xn

    def rays_world(self, uv) -> np.ndarray:
        """(N, 2) distorted pixels -> (N, 3) unit viewing directions in the world frame."""
        xn = self.undistort(np.atleast_2d(uv))
        d = np.hstack([xn, np.ones((len(xn), 1))]) @ self.R_world_to_cam
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def in_image(self, uv, margin_px: float = 0.0) -> np.ndarray:
        """(N,) True where pixels lie inside the image (shrunk by ``margin_px``)."""
        uv = np.atleast_2d(np.asarray(uv, float))
        w, h = self.image_size
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= -0.5 + margin_px)
                & (uv[:, 0] <= w - 0.5 - margin_px)
                & (uv[:, 1] >= -0.5 + margin_px)
                & (uv[:, 1] <= h - 0.5 - margin_px)
            )

    def __repr__(self) -> str:
        fx, fy = self.K[0, 0], self.K[1, 1]
        c = np.round(self.center_world, 3).tolist()
        return f"Camera({self.name!r}, {self.image_size[0]}x{self.image_size[1]}, f=({fx:.1f}, {fy:.1f}) px, centre={c} m, {self.distortion_model})"


def _points(value, name: str, dim: int) -> np.ndarray:
    """Accept (N, dim) or (dim,); NaN passes through (a missing point), inf is refused."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}) or ({dim},), got shape {np.shape(value)}")
    check_finite(arr, name, allow_nan=True)
    return arr
