"""Basis functions of a ProMP over the phase z in [0, 1].

Paraschos et al. 2013, Sec. 2.1 / Paraschos et al. 2018 (AuRo), Eq. 3: normalised Gaussian
radial basis functions

    b_k(z) = exp(-(z - c_k)^2 / (2 h^2)),    phi_k(z) = b_k(z) / sum_j b_j(z),

with centres c_k evenly spaced on [0, 1] and one width h (a standard deviation in phase units).
Because the normalised RBFs sum to one, a constant term would be redundant; optional polynomial
terms z, z^2, ..., z^p (``n_poly = p``) can be appended, as in Gomez-Gonzalez et al. 2020
(their basis combines squared exponentials with a polynomial).

For a movement of duration T the phase is z = t / T, so positions are q(t) = Phi(z) w and
velocities are dq/dt = dPhi/dz(z) w / T (AuRo 2018, Eq. 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from checks.arrays import check_array

__all__ = ["RBFBasis"]


@dataclass(frozen=True)
class RBFBasis:
    """Normalised Gaussian RBFs on the phase, plus optional polynomial terms.

    n_basis : number of Gaussian RBFs (>= 2), centres ``linspace(0, 1, n_basis)``
    width : RBF standard deviation in phase units; ``None`` -> the centre spacing 1 / (n_basis - 1)
    n_poly : number of polynomial terms z, z^2, ..., z^n_poly appended after the RBFs (>= 0)
    """

    n_basis: int = 10
    width: float | None = None
    n_poly: int = 0

    def __post_init__(self):
        if isinstance(self.n_basis, bool) or not isinstance(self.n_basis, (int, np.integer)) or self.n_basis < 2:
            raise ValueError(f"n_basis must be an integer >= 2, got {self.n_basis!r}")
        if isinstance(self.n_poly, bool) or not isinstance(self.n_poly, (int, np.integer)) or not 0 <= self.n_poly <= 5:
            raise ValueError(f"n_poly must be an integer in [0, 5], got {self.n_poly!r}")
        width = 1.0 / (self.n_basis - 1) if self.width is None else self.width
        try:
            width = float(width)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"width must be a positive number, got {self.width!r}") from exc
        if not np.isfinite(width) or width <= 0.0:
            raise ValueError(f"width must be finite and > 0, got {self.width!r}")
        object.__setattr__(self, "n_basis", int(self.n_basis))
        object.__setattr__(self, "n_poly", int(self.n_poly))
        object.__setattr__(self, "width", width)

    @property
    def n_functions(self) -> int:
        """Number of weights per joint: RBFs plus polynomial terms."""
        return self.n_basis + self.n_poly

    @property
    def centers(self) -> np.ndarray:
        """(n_basis,) RBF centres in phase units."""
        return np.linspace(0.0, 1.0, self.n_basis)

    def __call__(self, z) -> np.ndarray:
        """Basis values. z : (n,) phases in [0, 1] -> (n, n_functions)."""
        return self.evaluate(z)[0]

    def evaluate(self, z) -> tuple[np.ndarray, np.ndarray]:
        """Basis values and their phase derivatives.

        z : (n,) phases (trusted: finite, inside [0, 1]; see :meth:`check_phase`)
        returns phi (n, n_functions), dphi_dz (n, n_functions)
        """
        z = np.asarray(z, dtype=float).reshape(-1)
        diff = z[:, None] - self.centers[None, :]  # (n, n_basis)
        a = -0.5 * (diff / self.width) ** 2
        a -= a.max(axis=1, keepdims=True)  # stable softmax: normalisation is shift-invariant
        e = np.exp(a)
        phi_rbf = e / e.sum(axis=1, keepdims=True)
        # d/dz of the normalised RBF: phi_k (a'_k - sum_j phi_j a'_j), a'_k = -(z - c_k) / h^2
        da = -diff / self.width**2
        dphi_rbf = phi_rbf * (da - (phi_rbf * da).sum(axis=1, keepdims=True))
        if self.n_poly == 0:
            return phi_rbf, dphi_rbf
        powers = np.arange(1, self.n_poly + 1)
        poly = z[:, None] ** powers[None, :]
        dpoly = powers[None, :] * z[:, None] ** (powers[None, :] - 1)
        return np.hstack([phi_rbf, poly]), np.hstack([dphi_rbf, dpoly])

    @staticmethod
    def check_phase(z, name: str = "phase", tol: float = 1e-9) -> np.ndarray:
        """``z`` as a finite (n,) array inside [0, 1] (values within ``tol`` outside are clipped)."""
        z = check_array(np.atleast_1d(z), name, (None,), finite=True)
        if z.size and (z.min() < -tol or z.max() > 1.0 + tol):
            bad = z[(z < -tol) | (z > 1.0 + tol)][0]
            raise ValueError(f"{name} must lie in [0, 1] (t_s in [0, duration_s]), got {bad!r}")
        return np.clip(z, 0.0, 1.0)
