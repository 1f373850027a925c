"""Probabilistic Movement Primitives (ProMPs) in joint space.

A ProMP is a Gaussian distribution over trajectories, q(t) = Psi(t / T) w with w ~ N(mu_w, Sigma_w)
(Paraschos et al., "Probabilistic Movement Primitives", NeurIPS 2013; "Using probabilistic movement
primitives in robotics", AuRo 2018). This module holds the frozen :class:`ProMP` (evaluation,
sampling, time scaling, conditioning, save/load); learning lives in ``_promp_learning.py``,
conditioning in ``_promp_condition.py``, the file format in ``_promp_io.py``. See docs/promp.md.

Weights are joint-major: ``mu_w[d * n_functions + k]`` is the weight of basis function k of joint d.
Times are seconds from the movement's start; the phase is z = t_s / duration_s in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from policies import _promp_condition as _cond
from policies import _promp_io as _io
from policies._promp_basis import RBFBasis
from checks.arrays import check_array, check_covariance, check_positive
from policies._promp_learning import check_demos
from policies._promp_learning import EMInfo, NIWPrior, demo_log_likelihood, fit_em

__all__ = ["EMInfo", "NIWPrior", "ProMP", "RBFBasis"]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)  # own copy
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ProMP:
    """A learned (or conditioned) movement primitive for ``n_dims`` joints. Immutable.

    basis : :class:`RBFBasis` over the phase (n_basis RBFs, width, optional polynomial terms)
    mu_w : (n_dims * n_functions,) weight mean, joint-major
    Sigma_w : (n_dims * n_functions, n_dims * n_functions) weight covariance
    Sigma_y : (n_dims, n_dims) observation noise of the demonstrations (rad^2)
    duration_s : nominal duration T of the movement, seconds (mean of the demonstrations')
    joint_names : n_dims names; ``()`` -> ``("joint_0", ...)``
    robot_id : which robot the joints belong to ("" = any); checked by :meth:`load`
    duration_std_s : spread of the demonstrations' durations, seconds
    """

    basis: RBFBasis
    mu_w: np.ndarray
    Sigma_w: np.ndarray
    Sigma_y: np.ndarray
    duration_s: float = 1.0
    joint_names: tuple = ()
    robot_id: str = ""
    duration_std_s: float = 0.0
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.basis, RBFBasis):
            raise ValueError(f"basis must be an RBFBasis, got {type(self.basis).__name__}")
        K = self.basis.n_functions
        mu_w = check_array(self.mu_w, "mu_w", (None,), finite=True)
        if mu_w.size == 0 or mu_w.size % K:
            raise ValueError(f"mu_w must have n_dims * {K} entries (n_functions = {K}), got {mu_w.size}")
        n_dims = mu_w.size // K
        Sigma_w = check_covariance(self.Sigma_w, "Sigma_w", mu_w.size)
        Sigma_y = check_covariance(self.Sigma_y, "Sigma_y", n_dims)
        names = tuple(str(n) for n in self.joint_names) or tuple(f"joint_{d}" for d in range(n_dims))
        if len(names) != n_dims:
            raise ValueError(f"joint_names has {len(names)} names but the weights describe {n_dims} joints")
        if len(set(names)) != len(names):
            raise ValueError(f"joint_names must be unique, got {names}")
        if not isinstance(self.robot_id, str):
            raise ValueError(f"robot_id must be a string, got {self.robot_id!r}")
        object.__setattr__(self, "mu_w", _readonly(mu_w))
        object.__setattr__(self, "Sigma_w", _readonly(Sigma_w))
        object.__setattr__(self, "Sigma_y", _readonly(Sigma_y))
        object.__setattr__(self, "joint_names", names)
        object.__setattr__(self, "duration_s", check_positive(self.duration_s, "duration_s"))
        object.__setattr__(self, "duration_std_s", check_positive(self.duration_std_s, "duration_std_s", allow_zero=True))
        object.__setattr__(self, "metadata", dict(self.metadata))

    def __repr__(self) -> str:
        return (f"ProMP(robot_id={self.robot_id!r}, n_dims={self.n_dims}, basis={self.basis}, "
                f"duration_s={self.duration_s:.4g})")

    # ------------------------------------------------------------------ sizes
    @property
    def n_dims(self) -> int:
        return self.mu_w.size // self.basis.n_functions

    @property
    def n_basis(self) -> int:
        return self.basis.n_basis

    @property
    def n_weights(self) -> int:
        return self.mu_w.size

    # ------------------------------------------------------------------ time
    def phase(self, t_s=None, *, phase=None, duration_s: float | None = None) -> tuple[np.ndarray, float]:
        """Phases and phase rate for times or phases.

        t_s : (n,) seconds from the start in [0, duration_s], or ``phase`` : (n,) in [0, 1]
        duration_s : movement duration, seconds; ``None`` -> :attr:`duration_s`
        returns z (n,), dz/dt = 1 / duration_s (1/s)
        """
        T = self.duration_s if duration_s is None else check_positive(duration_s, "duration_s")
        if (t_s is None) == (phase is None):
            raise ValueError("give exactly one of t_s and phase")
        if phase is None:
            z = check_array(np.atleast_1d(t_s), "t_s", (None,), finite=True) / T
            return RBFBasis.check_phase(z, f"t_s / duration_s (duration_s = {T:g})"), 1.0 / T
        return RBFBasis.check_phase(phase), 1.0 / T

    def with_duration(self, duration_s: float) -> ProMP:
        """The same primitive executed in ``duration_s`` (time scaling: positions at equal phase are
        equal, velocities scale with 1 / duration_s)."""
        return replace(self, duration_s=check_positive(duration_s, "duration_s"))

    def _features(self, z: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
        phi, dphi = self.basis.evaluate(z)
        return phi, dphi * rate

    # ------------------------------------------------------------------ evaluation
    def mean_trajectory(self, t_s=None, *, phase=None, duration_s=None, weights=None) -> tuple[np.ndarray, np.ndarray]:
        """Mean positions and velocities.

        weights : (n_weights,) joint-major weights to evaluate instead of :attr:`mu_w` (e.g. a conditioned
            mean computed without building a new ProMP; trusted: the caller's own array)
        returns q (n, n_dims) rad, qd (n, n_dims) rad/s
        """
        z, rate = self.phase(t_s, phase=phase, duration_s=duration_s)
        phi, dphi = self._features(z, rate)
        W = (self.mu_w if weights is None else np.asarray(weights, float)).reshape(self.n_dims, -1).T  # (K, D)
        return phi @ W, dphi @ W

    def covariance(self, t_s=None, *, phase=None, duration_s=None, include_noise: bool = False) -> np.ndarray:
        """Covariance of [q; qd] at each time, (n, 2 n_dims, 2 n_dims) (rad, rad/s).

        include_noise adds Sigma_y to the position block (the spread of demonstrations themselves).
        """
        z, rate = self.phase(t_s, phase=phase, duration_s=duration_s)
        phi, dphi = self._features(z, rate)
        D, K = self.n_dims, self.basis.n_functions
        S4 = self.Sigma_w.reshape(D, K, D, K)
        F = np.stack([phi, dphi], axis=1)  # (n, 2, K): position and velocity features
        cov = np.einsum("nak,dkel,nbl->nadbe", F, S4, F).reshape(len(z), 2 * D, 2 * D)
        if include_noise:
            cov[:, :D, :D] += self.Sigma_y
        return cov

    def std(self, t_s=None, *, phase=None, duration_s=None, include_noise: bool = False):
        """Standard deviations of positions and velocities, each (n, n_dims)."""
        cov = self.covariance(t_s, phase=phase, duration_s=duration_s, include_noise=include_noise)
        sd = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))
        return sd[:, : self.n_dims], sd[:, self.n_dims :]

    def sample_weights(self, rng: np.random.Generator, n_samples: int) -> np.ndarray:
        """(n_samples, n_weights) weights drawn from N(mu_w, Sigma_w) (eigen-decomposition, so a
        singular covariance after exact conditioning is fine)."""
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) or n_samples < 0:
            raise ValueError(f"n_samples must be a non-negative integer, got {n_samples!r}")
        lam, V = np.linalg.eigh(self.Sigma_w)
        L = V * np.sqrt(np.clip(lam, 0.0, None))
        return self.mu_w + rng.standard_normal((int(n_samples), self.n_weights)) @ L.T

    def sample(self, rng: np.random.Generator, n_samples: int, t_s=None, *, phase=None, duration_s=None):
        """Trajectories drawn from the primitive.

        returns q (n_samples, n, n_dims), qd (n_samples, n, n_dims)
        """
        z, rate = self.phase(t_s, phase=phase, duration_s=duration_s)
        w = self.sample_weights(rng, n_samples).reshape(-1, self.n_dims, self.basis.n_functions)
        phi, dphi = self._features(z, rate)
        return np.einsum("tk,sdk->std", phi, w), np.einsum("tk,sdk->std", dphi, w)

    def task_marginal(self, t_s, fk, jacobian, *, duration_s=None) -> tuple[np.ndarray, np.ndarray]:
        """Linearised task-space distribution at each time: fk(mean q), J Sigma_q J^T.

        fk(q (n_dims,)) -> (m,), jacobian(q) -> (m, n_dims); returns x (n, m), x_cov (n, m, m)
        """
        q, _ = self.mean_trajectory(t_s, duration_s=duration_s)
        cov_q = self.covariance(t_s, duration_s=duration_s)[:, : self.n_dims, : self.n_dims]
        x, J = _cond.eval_kinematics(fk, jacobian, q, self.n_dims)
        return x, np.einsum("nid,nde,nje->nij", J, cov_q, J)

    # ------------------------------------------------------------------ conditioning
    def condition_on_joint(self, t_s: float, q_mean=None, q_cov=None, *, qd_mean=None, qd_cov=None,
                           duration_s=None) -> ProMP:
        """New ProMP conditioned on a joint-space via point at time ``t_s`` (Paraschos 2013, Eq. 5-6).

        q_mean : (n_dims,) rad, q_cov : (n_dims, n_dims) or None (exact); likewise qd_mean / qd_cov
        (rad/s) for velocities at the duration used. Give at least one of q_mean and qd_mean.
        """
        return _cond.condition_on_joint(self, t_s, q_mean, q_cov, qd_mean, qd_cov, duration_s)

    def condition_on_task(self, t_s: float, x_target, x_cov, fk, jacobian, *, iterations: int = 30,
                          tol: float = 1e-10, max_residual_m: float | None = 0.01, duration_s=None) -> ProMP:
        """New ProMP conditioned on a task-space via point x = fk(q(t_s)) ~ N(x_target, x_cov).

        fk(q (n_dims,)) -> (m,) and jacobian(q) -> (m, n_dims), e.g. the racket position (m = 3)
        or position and normal (m = 6). The nonlinear kinematics are linearised around the current
        posterior mean and the update iterated (iterated extended Kalman update = Gauss-Newton on
        the MAP of the weights); see docs/promp.md. Raises ValueError when the posterior mean misses
        the target by more than ``max_residual_m`` + 3 sqrt(largest eigenvalue of x_cov)
        (unreachable point under this primitive), ``None`` disables the check.
        """
        return _cond.condition_on_task(self, t_s, x_target, x_cov, fk, jacobian, iterations, tol,
                                       max_residual_m, duration_s)

    # ------------------------------------------------------------------ learning
    @classmethod
    def learn(cls, demos, times, n_basis: int = 10, *, width: float | None = None, n_poly: int = 0,
              prior: NIWPrior | None = NIWPrior(), max_iter: int = 200, tol: float = 1e-7,
              diagonal_sigma_y: bool = True, joint_names=(), robot_id: str = "") -> tuple[ProMP, EMInfo]:
        """Learn a ProMP from demonstrations by MAP-EM (``prior``) or ML-EM (``prior=None``).

        demos : list of (T_n, n_dims) joint trajectories (rad); times : list of (T_n,) seconds,
        strictly increasing; each demo is mapped to phase [0, 1] by its own duration.
        returns (ProMP, EMInfo)
        """
        basis = RBFBasis(n_basis, width, n_poly)
        if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
            raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
        tol = check_positive(tol, "tol", allow_zero=True)
        if prior is not None and not isinstance(prior, NIWPrior):
            raise ValueError(f"prior must be an NIWPrior or None, got {type(prior).__name__}")
        n_dims = len(joint_names) if joint_names else None
        demos, times = check_demos(demos, times, n_dims=n_dims, min_samples=basis.n_functions)
        if len(demos) < 2:
            raise ValueError(f"need at least 2 demonstrations to learn a distribution, got {len(demos)}")
        (mu_w, Sigma_w, Sigma_y), info = fit_em(basis, demos, times, prior=prior, max_iter=int(max_iter),
                                                tol=tol, diagonal_sigma_y=diagonal_sigma_y)
        durations = np.array([t[-1] - t[0] for t in times])
        promp = cls(basis, mu_w, Sigma_w, Sigma_y, float(durations.mean()), tuple(joint_names), robot_id,
                    float(durations.std()))
        return promp, info

    def log_likelihood(self, demos, times) -> np.ndarray:
        """(n_demos,) exact log-likelihood of each demonstration (each mapped to phase [0, 1] by its
        own duration) under this primitive, nats."""
        demos, times = check_demos(demos, times, n_dims=self.n_dims, min_samples=2)
        return demo_log_likelihood(self.basis, self.mu_w, self.Sigma_w, self.Sigma_y, demos, times)

    # ------------------------------------------------------------------ files
    def save(self, path) -> Path:
        """Write to ``path`` (.npz, see docs/promp.md for the fields); returns the path."""
        return _io.save(self, path)

    @classmethod
    def load(cls, path, *, robot_id: str | None = None, joint_names=None, n_dims: int | None = None) -> ProMP:
        """Read a file written by :meth:`save`. The expected ``robot_id``, ``joint_names`` or
        ``n_dims``, when given, must match the file's, else ValueError naming file and field."""
        return _io.load(cls, path, robot_id=robot_id, joint_names=joint_names, n_dims=n_dims)
