"""checks.arrays.check_covariance: the Cholesky proof and the exact eigenvalue decision behind it."""

from __future__ import annotations

import numpy as np
import pytest

from checks.arrays import check_covariance


def _with_smallest(value: float, n: int = 6, seed: int = 0) -> np.ndarray:
    """A symmetric (n, n) matrix of scale ~1 whose smallest eigenvalue is ``value``."""
    Q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(n, n)))
    return (Q * np.r_[value, np.linspace(0.5, 1.0, n - 1)]) @ Q.T


def test_definite_and_semi_definite_pass_and_come_back_symmetric():
    for low in (0.3, 0.0, -1e-12):  # within the tolerance of -1e-9 x scale
        C = _with_smallest(low)
        C[0, 1] += 1e-13  # a round-off asymmetry is symmetrised
        out = check_covariance(C, "C", 6)
        assert np.array_equal(out, out.T) and np.allclose(out, C, atol=1e-12)


def test_indefinite_is_refused_naming_the_smallest_eigenvalue():
    with pytest.raises(ValueError, match=r"C must be positive semi-definite; smallest eigenvalue -0\.001"):
        check_covariance(_with_smallest(-1e-3), "C", 6)
    # below the tolerance, but only just
    with pytest.raises(ValueError, match="semi-definite"):
        check_covariance(_with_smallest(-1e-7), "C", 6)


def test_singular_is_refused_where_a_definite_matrix_is_needed():
    with pytest.raises(ValueError, match=r"C must be positive definite; smallest eigenvalue"):
        check_covariance(np.diag([1.0, 0.5, 0.0]), "C", 3, allow_singular=False)
    assert check_covariance(_with_smallest(1e-3), "C", 6, allow_singular=False).shape == (6, 6)


def test_agrees_with_the_eigenvalue_rule_on_random_matrices():
    """Accept exactly where the smallest eigenvalue is >= -1e-9 x max |C| (away from round-off)."""
    rng = np.random.default_rng(1)
    for k in range(200):
        low = float(rng.choice([-1e-2, -1e-6, -1e-8, 1e-10, 1e-4, 0.2]))
        C = _with_smallest(low, n=int(rng.integers(2, 12)), seed=k)
        ok = np.linalg.eigvalsh(C)[0] >= -1e-9 * np.abs(C).max()
        try:
            check_covariance(C, "C", len(C))
            accepted = True
        except ValueError:
            accepted = False
        assert accepted == ok, (low, len(C))
