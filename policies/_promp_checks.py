"""Input validation for the public boundary of the ProMP code.

Validate once, where data enters (constructor, learning, conditioning, loading); the inner
linear algebra trusts its inputs. Every error is a ``ValueError`` that names the argument
(or demo index, or file and field) and quotes what was received.
"""

from __future__ import annotations

import numpy as np

__all__ = ["as_array", "as_covariance", "as_positive", "check_demos", "describe"]


def describe(value) -> str:
    """Short description of ``value`` for error messages: shape and dtype, or repr."""
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def as_array(value, name: str, shape: tuple, *, where: str = "", finite: bool = True) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (ints fixed, ``None`` free), finite unless told.

    ``where`` prefixes the message (a file name, a demo index).
    """
    prefix = f"{where}: " if where else ""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{prefix}{name} must be numeric, got {describe(value)}") from exc
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{prefix}{name} must have shape {want}, got shape {arr.shape}")
    if finite and not np.isfinite(arr).all():
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{prefix}{name} must be finite; found {float(arr[idx])!r} at index {idx}")
    return arr


def as_covariance(value, name: str, n: int, *, where: str = "", allow_singular: bool = True) -> np.ndarray:
    """``value`` as a symmetric positive semi-definite (n, n) matrix (definite unless ``allow_singular``)."""
    prefix = f"{where}: " if where else ""
    arr = as_array(value, name, (n, n), where=where)
    scale = max(float(np.abs(arr).max()), 1e-300)
    asym = float(np.abs(arr - arr.T).max())
    if asym > 1e-8 * scale:
        raise ValueError(f"{prefix}{name} must be symmetric; max |C - C^T| = {asym:.3g}")
    arr = 0.5 * (arr + arr.T)
    low = float(np.linalg.eigvalsh(arr)[0]) if n else 0.0
    if low < -1e-9 * scale or (not allow_singular and low <= 0.0):
        kind = "semi-definite" if allow_singular else "definite"
        raise ValueError(f"{prefix}{name} must be positive {kind}; smallest eigenvalue {low:.3g}")
    return arr


def as_positive(value, name: str, *, where: str = "", allow_zero: bool = False) -> float:
    """``value`` as a finite float > 0 (or >= 0 with ``allow_zero``)."""
    prefix = f"{where}: " if where else ""
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{prefix}{name} must be a number, got {describe(value)}") from exc
    if not np.isfinite(x) or x < 0.0 or (x == 0.0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{prefix}{name} must be finite and {bound}, got {x!r}")
    return x


def check_demos(demos, times, *, n_dims: int | None = None, min_samples: int = 2) -> tuple[list, list]:
    """Validate demonstrations; return lists of (T_n, D) and (T_n,) float arrays.

    demos : sequence of (T_n, D) joint trajectories; times : sequence of (T_n,) strictly increasing s
    """
    if isinstance(demos, np.ndarray) and demos.ndim == 3:
        demos = list(demos)
    if isinstance(times, np.ndarray) and times.ndim == 2:
        times = list(times)
    if not isinstance(demos, (list, tuple)) or not isinstance(times, (list, tuple)):
        raise ValueError(f"demos and times must be lists of arrays, got {type(demos).__name__} and {type(times).__name__}")
    if len(demos) != len(times):
        raise ValueError(f"got {len(demos)} demos but {len(times)} time arrays")
    if len(demos) == 0:
        raise ValueError("no demonstrations given")
    out_q, out_t = [], []
    for n, (q, t) in enumerate(zip(demos, times)):
        q = as_array(q, f"demos[{n}]", (None, n_dims))
        if n_dims is None:
            n_dims = q.shape[1]
        if n_dims < 1:
            raise ValueError(f"demos[{n}] has no joints: shape {q.shape}")
        t = as_array(t, f"times[{n}]", (None,))
        if t.shape[0] != q.shape[0]:
            raise ValueError(f"times[{n}] has {t.shape[0]} samples but demos[{n}] has {q.shape[0]}")
        if q.shape[0] < min_samples:
            raise ValueError(f"demos[{n}] has too few samples: {q.shape[0]} < {min_samples}")
        dt = np.diff(t)
        if (dt <= 0).any():
            i = int(np.argmax(dt <= 0))
            raise ValueError(f"times[{n}] must be strictly increasing; times[{n}][{i + 1}] = {t[i + 1]!r} <= {t[i]!r}")
        out_q.append(q)
        out_t.append(t)
    return out_q, out_t
