"""Input validation shared by the public boundary of ``tracker``.

Validate once, where data enters; inner loops trust their inputs. Every error is a
``ValueError`` that names the argument (or file and field) and quotes what was received.
"""

from __future__ import annotations

import numpy as np

from tracker.files import short

__all__ = ["check_array", "check_finite", "check_rotation", "describe"]


def describe(value) -> str:
    """Short description of ``value`` for error messages: shape and dtype, or a repr shortened while
    it is built (never the whole text of a huge value)."""
    return short(value, 80)


def check_array(value, name: str, shape: tuple, *, dtype=float, where: str = "") -> np.ndarray:
    """Convert ``value`` to an array of ``dtype`` and check its shape.

    ``shape`` holds ints for fixed sizes and ``None`` for free ones, e.g. ``(None, 2)``.
    ``where`` prefixes the message (a file name, say).
    """
    prefix = f"{where}: " if where else ""
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{prefix}{name} must be numeric, got {describe(value)}") from exc
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        dims = ["N" if s is None else str(s) for s in shape]
        want = "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"
        raise ValueError(f"{prefix}{name} must have shape {want}, got shape {arr.shape}")
    return arr


def check_finite(arr: np.ndarray, name: str, *, where: str = "", allow_nan: bool = False) -> None:
    """Raise if ``arr`` holds inf (or NaN unless ``allow_nan``)."""
    prefix = f"{where}: " if where else ""
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        kind = "inf" if allow_nan else "NaN or inf"
        raise ValueError(f"{prefix}{name} must not contain {kind}; found {arr[idx]!r} at index {idx}")


def check_rotation(R: np.ndarray, name: str, *, where: str = "", tol: float = 1e-6) -> None:
    """Raise unless ``R`` (3, 3) is a proper rotation (orthonormal, det +1) within ``tol``."""
    prefix = f"{where}: " if where else ""
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > tol:
        raise ValueError(f"{prefix}{name} is not orthonormal: max |R R^T - I| = {err:.3g} > {tol:g}")
    det = np.linalg.det(R)
    if det < 0:
        raise ValueError(f"{prefix}{name} is a reflection, not a rotation: det = {det:.6f}")
