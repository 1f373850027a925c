"""Array checks at the public boundaries of tracker, policies and robot_models (one style for all).

Validate once, where data enters; inner loops trust their inputs. Every error is a ``ValueError``
that names the argument (or file and field, via ``where``) and quotes what was received, shortened
while it is built (:func:`describe`).
"""

from __future__ import annotations

import numpy as np

from checks.files import short

__all__ = ["check_array", "check_covariance", "check_finite", "check_positive", "check_rotation", "describe"]


def describe(value) -> str:
    """Short description of ``value`` for error messages: shape and dtype, or a repr shortened while
    it is built (never the whole text of a huge value)."""
    return short(value, 80)


def _prefix(where: str) -> str:
    return f"{where}: " if where else ""


def check_array(value, name: str, shape: tuple, *, dtype=float, where: str = "", finite: bool = False) -> np.ndarray:
    """Convert ``value`` to an array of ``dtype`` and check its shape (and with ``finite``, that it
    holds no NaN or inf).

    ``shape`` holds ints for fixed sizes and ``None`` for free ones, e.g. ``(None, 2)``.
    ``where`` prefixes the message (a file name, a demo index).
    """
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{_prefix(where)}{name} must be numeric, got {describe(value)}") from exc
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        dims = ["N" if s is None else str(s) for s in shape]
        want = "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"
        raise ValueError(f"{_prefix(where)}{name} must have shape {want}, got shape {arr.shape}")
    if finite:
        check_finite(arr, name, where=where)
    return arr


def check_finite(arr: np.ndarray, name: str, *, where: str = "", allow_nan: bool = False) -> None:
    """Raise if ``arr`` holds inf (or NaN unless ``allow_nan``)."""
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        kind = "inf" if allow_nan else "NaN or inf"
        raise ValueError(f"{_prefix(where)}{name} must not contain {kind}; found {float(arr[idx])!r} at index {idx}")


def check_rotation(R: np.ndarray, name: str, *, where: str = "", tol: float = 1e-6) -> None:
    """Raise unless ``R`` (3, 3) is a proper rotation (orthonormal, det +1) within ``tol``."""
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > tol:
        raise ValueError(f"{_prefix(where)}{name} is not orthonormal: max |R R^T - I| = {err:.3g} > {tol:g}")
    det = np.linalg.det(R)
    if det < 0:
        raise ValueError(f"{_prefix(where)}{name} is a reflection, not a rotation: det = {det:.6f}")


def check_covariance(value, name: str, n: int, *, where: str = "", allow_singular: bool = True) -> np.ndarray:
    """``value`` as a symmetric positive semi-definite (n, n) matrix (definite unless ``allow_singular``),
    symmetrised."""
    arr = check_array(value, name, (n, n), where=where, finite=True)
    scale = max(float(np.abs(arr).max()), 1e-300)
    asym = float(np.abs(arr - arr.T).max())
    if asym > 1e-8 * scale:
        raise ValueError(f"{_prefix(where)}{name} must be symmetric; max |C - C^T| = {asym:.3g}")
    arr = 0.5 * (arr + arr.T)
    if n == 0:
        return arr
    # A Cholesky factorisation (~10x cheaper than the eigenvalues; the ProMP's conditioning checks a
    # 100 x 100 covariance at every step of a plan) proves the bound; only when it fails are the
    # eigenvalues computed, to decide exactly and to name the smallest.
    try:
        shifted = arr.copy()
        shifted.flat[:: n + 1] += 1e-9 * scale if allow_singular else 0.0  # the tolerance on the diagonal
        np.linalg.cholesky(shifted)
        return arr
    except np.linalg.LinAlgError:
        pass
    low = float(np.linalg.eigvalsh(arr)[0])
    if low < -1e-9 * scale or (not allow_singular and low <= 0.0):
        kind = "semi-definite" if allow_singular else "definite"
        raise ValueError(f"{_prefix(where)}{name} must be positive {kind}; smallest eigenvalue {low:.3g}")
    return arr


def check_positive(value, name: str, *, where: str = "", allow_zero: bool = False) -> float:
    """``value`` as a finite float > 0 (or >= 0 with ``allow_zero``)."""
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{_prefix(where)}{name} must be a number, got {describe(value)}") from exc
    if not np.isfinite(x) or x < 0.0 or (x == 0.0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{_prefix(where)}{name} must be finite and {bound}, got {x!r}")
    return x
