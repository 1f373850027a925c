"""OpenCV lens distortion: the one definition, as a batched numpy function and a compiled twin.

Normalised image coordinates ``(x, y) = (X_cam[0] / X_cam[2], X_cam[1] / X_cam[2])`` map to
distorted normalised coordinates (OpenCV's ``projectPoints`` model, ``r2 = x^2 + y^2``)::

    radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y

Coefficients are always the 8 of ``rational_polynomial`` in OpenCV's order
``k1, k2, p1, p2, k3, k4, k5, k6`` (``Camera.dist8``: zeros where a model has fewer).

* :func:`distort` / :func:`distort_jacobian` / :func:`undistort`: numpy, batched, the reference;
* :func:`distort_point` / :func:`distort_point_jacobian` / :func:`undistort_point`: numba twins for
  one point, inlined into the compiled kernels (robust estimator, ROI prediction, renderer).

``tests/tracker/test_camera.py`` checks that the twins agree and that both match ``cv2.projectPoints``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from checks.numba_cache import key_cache_on_callees

__all__ = [
    "distort",
    "distort_jacobian",
    "distort_point",
    "distort_point_jacobian",
    "undistort",
    "undistort_point",
]


def _coefficients(dist8: np.ndarray):
    d = np.asarray(dist8, float)
    return tuple(d[..., i] for i in range(8))


def distort(xn: np.ndarray, dist8: np.ndarray) -> np.ndarray:
    """Apply OpenCV distortion to normalised coordinates.

    xn : (..., 2) undistorted normalised coordinates
    dist8 : (8,) or (..., 8) coefficients ``k1, k2, p1, p2, k3, k4, k5, k6``, broadcast against
        ``xn``'s leading axes (e.g. (n_cams, 8) with xn (M, n_cams, 2): each camera its own)
    returns (..., 2) distorted normalised coordinates
    """
    return distort_jacobian(xn, dist8, jacobian=False)[0]


def distort_jacobian(xn: np.ndarray, dist8: np.ndarray, jacobian: bool = True):
    """:func:`distort` and its derivative.

    returns (xd (..., 2), J (..., 2, 2) = d xd / d xn, or None when ``jacobian`` is False)
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = _coefficients(dist8)
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rad = num / den
    xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    out = np.stack([xd, yd], axis=-1)
    if not jacobian:
        return out, None
    # d radial / d r2
    drad = ((k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) * den - num * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / (den * den)
    J = np.empty(out.shape + (2,))
    J[..., 0, 0] = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
    J[..., 0, 1] = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
    J[..., 1, 0] = J[..., 0, 1]
    J[..., 1, 1] = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return out, J


def undistort(xd: np.ndarray, dist8: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Invert :func:`distort` by Newton's method (robust where OpenCV's fixed-point iteration
    stalls near the image corners of strongly distorted lenses).

    xd : (N, 2) distorted normalised coordinates; dist8 : (8,) or (N, 8)
    returns (N, 2) undistorted normalised coordinates
    """
    x = np.array(xd, float)
    if not np.any(dist8):
        return x
    for _ in range(iterations):
        f, J = distort_jacobian(x, dist8)
        r = f - xd
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        dx = (J[:, 1, 1] * r[:, 0] - J[:, 0, 1] * r[:, 1]) / det
        dy = (J[:, 0, 0] * r[:, 1] - J[:, 1, 0] * r[:, 0]) / det
        x[:, 0] -= dx
        x[:, 1] -= dy
        if np.nanmax(np.abs(r), initial=0.0) < 1e-12:
            break
    return x


# -- compiled twins, one point at a time (coefficients as scalars, so callers may read them from
# -- any layout: a camera row, a transposed camera table, a (8,) vector) -------------------------
@njit(cache=True, inline="always", error_model="numpy")
def distort_point(x, y, k1, k2, p1, p2, k3, k4, k5, k6):
    """Compiled :func:`distort` of one point: returns ``(xd, yd)``."""
    r2 = x * x + y * y
    rad = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


@njit(cache=True, inline="always", error_model="numpy")
def distort_point_jacobian(x, y, k1, k2, p1, p2, k3, k4, k5, k6):
    """Compiled :func:`distort_jacobian` of one point: ``(xd, yd, j00, j01, j11)`` (J is symmetric)."""
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rad = num / den
    xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    drad = ((k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) * den - num * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / (den * den)
    j00 = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
    j01 = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
    j11 = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, j00, j01, j11


@njit(cache=True, error_model="numpy")
def undistort_point(xd, yd, k1, k2, p1, p2, k3, k4, k5, k6):
    """Compiled Newton inversion of one point (as :func:`undistort`; stops once the residual of
    the current iterate is below 1e-12 instead of taking one more step): returns ``(x, y)``."""
    x, y = xd, yd
    for _ in range(20):
        fx, fy, j00, j01, j11 = distort_point_jacobian(x, y, k1, k2, p1, p2, k3, k4, k5, k6)
        rx, ry = fx - xd, fy - yd
        if max(abs(rx), abs(ry)) < 1e-12:
            break
        det = j00 * j11 - j01 * j01
        x -= (j11 * rx - j01 * ry) / det
        y -= (j00 * ry - j01 * rx) / det
    return x, y


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
