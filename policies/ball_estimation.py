"""Estimating the ball's state [p, v, w] from observed 3D positions, for prediction.

Two estimators over the physical model of :mod:`policies.ball_model` (docs/ball_physics.md, sec. 4):

* :func:`fit_initial_state` -- maximum a posteriori least squares over a window of observations:
  the state at the first sample is chosen so that the simulated flight (eqs. 1-6) passes through
  the observed positions (residuals scaled by ``position_noise_m``, soft-L1 robust loss against
  tracker outliers), with a Gaussian prior on the spin, which only the Magnus curvature (eq. 1)
  and the spin drag observe -- and the spin component along the velocity not at all.
* :class:`BallEKF` -- an online extended Kalman filter over the same state, initialised by
  :func:`fit_initial_state` on its first samples; its transition is the integrator itself (so the
  table bounce is handled), linearised by batched finite differences.

Both return a :class:`BallEstimate` (state at a time, covariance, and a ``predict`` method), the
type the hitting policy consumes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from policies.ball_model import BallParams, TableGeometry, _check_times, simulate

__all__ = ["BallEKF", "BallEstimate", "EKFOptions", "EstimatorOptions", "FitInfo", "fit_initial_state", "fit_initial_state_mixture",
           "spin_prior_from_spins"]

# Forward-difference steps for the state Jacobians: position (m), velocity (m/s), spin (rad/s).
_FD_STEP = np.array([1e-6] * 3 + [1e-6] * 3 + [1e-4] * 3)


@dataclass(frozen=True)
class EstimatorOptions:
    """Options of :func:`fit_initial_state`.

    position_noise_m : std of one observed coordinate (tracker noise), metres: a number, or three
        numbers (x, y, z) when the noise differs per axis (e.g. timestamp jitter along the flight)
    estimate_spin : False fits position and velocity only, spin fixed at the prior mean
    spin_prior_mean_rad_s, spin_prior_std_rad_s : Gaussian prior on the spin (world frame)
    spin_prior_cov_rad2_s2 : None, or a full (3, 3) prior covariance (tuple of 3 rows, rad^2/s^2,
        symmetric positive definite) used instead of ``spin_prior_std_rad_s``: the spin prior of a
        launcher learned from fitted flights (:func:`spin_prior_from_spins`), tight across the flight
        and loose along it, where the flight does not observe the spin
    robust_scale : soft-L1 scale in units of ``position_noise_m``; None for plain least squares
    dt_s : integrator step; max_nfev : iteration budget of the solver
    """

    position_noise_m: float | tuple = 0.001
    estimate_spin: bool = True
    spin_prior_mean_rad_s: tuple = (0.0, 0.0, 0.0)
    spin_prior_std_rad_s: float = 30.0
    spin_prior_cov_rad2_s2: tuple | None = None
    robust_scale: float | None = 3.0
    dt_s: float = 2e-3
    max_nfev: int = 60

    def __post_init__(self):
        noise = np.broadcast_to(np.asarray(self.position_noise_m, float), (3,)) if np.ndim(self.position_noise_m) < 2 \
            else None
        if noise is None or not (noise > 0).all():
            raise ValueError(f"position_noise_m must be > 0 (a number or 3 numbers), got {self.position_noise_m!r}")
        if not (self.spin_prior_std_rad_s > 0 and self.dt_s > 0 and self.max_nfev > 0):
            raise ValueError(f"EstimatorOptions need positive noise, prior std, dt_s and max_nfev; got {self}")
        if np.shape(self.spin_prior_mean_rad_s) != (3,):
            raise ValueError(f"spin_prior_mean_rad_s must have 3 values, got {self.spin_prior_mean_rad_s!r}")
        if self.robust_scale is not None and not self.robust_scale > 0:
            raise ValueError(f"robust_scale must be > 0 or None, got {self.robust_scale!r}")
        if self.spin_prior_cov_rad2_s2 is not None:
            check_spin_cov(self.spin_prior_cov_rad2_s2, "spin_prior_cov_rad2_s2")

    def spin_prior_cov(self) -> np.ndarray:
        """(3, 3) prior covariance of the spin, rad^2/s^2."""
        if self.spin_prior_cov_rad2_s2 is not None:
            return np.asarray(self.spin_prior_cov_rad2_s2, float)
        return np.eye(3) * self.spin_prior_std_rad_s**2


def check_spin_cov(cov, name: str) -> np.ndarray:
    """A (3, 3) symmetric positive definite covariance, or ValueError quoting what was received."""
    try:
        C = np.asarray(cov, float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a (3, 3) numeric matrix, got {cov!r:.120}") from exc
    if C.shape != (3, 3) or not np.isfinite(C).all() or not np.allclose(C, C.T, rtol=1e-9, atol=1e-9):
        raise ValueError(f"{name} must be a finite symmetric (3, 3) matrix, got {cov!r:.120}")
    if np.linalg.eigvalsh(C).min() <= 0:
        raise ValueError(f"{name} must be positive definite, got eigenvalues {np.linalg.eigvalsh(C).round(6).tolist()}")
    return C


@dataclass(frozen=True)
class BallEstimate:
    """A ball state estimate and how to predict from it.

    t_s : time of ``state``, seconds (clock of the observations)
    state : (9,) [p, v, w] world frame, m, m/s, rad/s
    covariance : (9, 9) covariance of ``state``
    """

    t_s: float
    state: np.ndarray
    covariance: np.ndarray
    params: BallParams = field(default_factory=BallParams)
    table: TableGeometry = field(default_factory=TableGeometry)
    dt_s: float = 1e-3

    @property
    def position(self) -> np.ndarray:
        return self.state[0:3]

    @property
    def velocity(self) -> np.ndarray:
        return self.state[3:6]

    @property
    def spin(self) -> np.ndarray:
        return self.state[6:9]

    def predict(self, t_query) -> tuple[np.ndarray, np.ndarray]:
        """t_query (M,) absolute times >= t_s -> positions (M, 3), velocities (M, 3)."""
        out, _ = simulate(self.state, t_query, self.params, self.table, t0_s=self.t_s, dt_s=self.dt_s)
        return out[:, 0:3], out[:, 3:6]

    def first_bounce(self, horizon_s: float = 1.5) -> np.ndarray:
        """(5,) ``[t_s, x, y, z, n_bounces]`` of the next table contact within ``horizon_s`` (NaN if none)."""
        _, bounce = simulate(self.state, [self.t_s + horizon_s], self.params, self.table, t0_s=self.t_s,
                             dt_s=self.dt_s)
        return bounce


def _check_observations(t_s, X_world) -> tuple[np.ndarray, np.ndarray]:
    t = _check_times(t_s, "t_s")
    try:
        X = np.asarray(X_world, float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"X_world must be numeric, got {X_world!r:.80}") from exc
    if X.ndim != 2 or X.shape[1] != 3 or X.shape[0] != t.shape[0]:
        raise ValueError(f"X_world must have shape (N, 3) with N = len(t_s) = {t.shape[0]}, got shape {X.shape}")
    if not np.isfinite(X).all():
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(X))[0])
        raise ValueError(f"X_world must be finite; found {X[idx]!r} at index {idx}")
    if t.shape[0] < 4:
        raise ValueError(f"need at least 4 observations to estimate a ball state, got {t.shape[0]}")
    if not (np.diff(t) > 0).all():
        i = int(np.argmax(np.diff(t) <= 0))
        raise ValueError(f"t_s must be strictly increasing; t_s[{i + 1}] = {t[i + 1]!r} <= t_s[{i}] = {t[i]!r}")
    return t, X


def _polynomial_guess(t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(6,) position and velocity at t[0] from a per-axis quadratic fit."""
    coef = np.polynomial.polynomial.polyfit(t - t[0], X, 2)  # (3 coefficients, 3 axes)
    return np.concatenate([coef[0], coef[1]])


def _propagate_with_jacobian(state, t_from, t_to, params, table, dt_s):
    """State at t_to and d state(t_to) / d state(t_from) (9, 9), batched forward differences."""
    batch = np.repeat(state[None], 10, axis=0)
    batch[1:] += np.diag(_FD_STEP)
    out, _ = simulate(batch, [t_to], params, table, t0_s=t_from, dt_s=dt_s)
    end = out[:, 0]
    return end[0], ((end[1:] - end[0]) / _FD_STEP[:, None]).T


@dataclass(frozen=True)
class FitInfo:
    """What :func:`fit_initial_state` (and the mixture fit) found besides the estimate.

    residuals_m : (N, 3) fitted minus observed positions, metres; rms_m : their RMS; state_t0 : (9,)
    the fitted state at the first observation time; nfev : residual evaluations; success : the
    least-squares solver converged; cost : its final cost (half the sum of squared whitened residuals);
    logdet_hessian : log det of the Gauss-Newton Hessian (inf when singular); component, scores : for
    :func:`fit_initial_state_mixture`, the chosen spin-prior component and every component's score
    (None and () otherwise)
    """

    residuals_m: np.ndarray
    rms_m: float
    state_t0: np.ndarray
    nfev: int
    success: bool
    cost: float
    logdet_hessian: float
    component: int | None = None
    scores: tuple = ()


def fit_initial_state(t_s, X_world, params: BallParams | None = None, table: TableGeometry | None = None,
                      options: EstimatorOptions = EstimatorOptions()) -> tuple[BallEstimate, FitInfo]:
    """MAP estimate of the ball state from observed positions (docs/ball_physics.md, eq. 7).

    t_s : (N,) strictly increasing observation times, seconds
    X_world : (N, 3) observed ball centres, world frame, metres
    Returns ``(estimate, info)``: the estimate is at the **last** observation time (what a policy
    predicts from), with its covariance propagated from the fit; ``info`` is a :class:`FitInfo`.
    """
    t, X = _check_observations(t_s, X_world)
    params = params or BallParams.load()  # fitted defaults, data/ball_params.yaml
    table = table or TableGeometry()
    sigma = np.broadcast_to(np.asarray(options.position_noise_m, float), (3,))
    w0 = np.asarray(options.spin_prior_mean_rad_s, float)
    # eq. (7): prior residual W (w - w0) with W^T W = Sigma_w^-1 (W = L^-1, Sigma_w = L L^T)
    W = np.linalg.inv(np.linalg.cholesky(options.spin_prior_cov()))
    n_free = 9 if options.estimate_spin else 6

    def full(x):
        return np.concatenate([x, w0]) if n_free == 6 else x

    def residuals(x):
        out, _ = simulate(full(x), t, params, table, t0_s=t[0], dt_s=options.dt_s)
        r = ((out[:, 0:3] - X) / sigma).ravel()
        if n_free == 9:  # eq. (7): spin prior
            r = np.concatenate([r, W @ (x[6:9] - w0)])
        return r

    def jacobian(x):
        batch = np.repeat(full(x)[None], n_free + 1, axis=0)
        batch[1:, :n_free] += np.diag(_FD_STEP[:n_free])
        out, _ = simulate(batch, t, params, table, t0_s=t[0], dt_s=options.dt_s)
        J = ((out[1:, :, 0:3] - out[0, :, 0:3]) / (sigma * _FD_STEP[:n_free, None, None])).reshape(n_free, -1).T
        if n_free == 9:
            J = np.vstack([J, np.hstack([np.zeros((3, 6)), W])])
        return J

    x0 = _polynomial_guess(t, X)
    if n_free == 9:
        x0 = np.concatenate([x0, w0])
    loss = "linear" if options.robust_scale is None else "soft_l1"
    res = least_squares(residuals, x0, jac=jacobian, loss=loss, f_scale=options.robust_scale or 1.0,
                        x_scale="jac", max_nfev=options.max_nfev, method="trf")
    J = res.jac
    H = J.T @ J  # Gauss-Newton Hessian
    cov_free = np.linalg.pinv(H)  # Laplace approximation, unit-variance residuals
    sign, logdet_h = np.linalg.slogdet(H)
    cov0 = np.zeros((9, 9))
    cov0[:n_free, :n_free] = cov_free
    state0 = full(res.x)
    state_end, Phi = _propagate_with_jacobian(state0, t[0], t[-1], params, table, options.dt_s)
    estimate = BallEstimate(t_s=float(t[-1]), state=state_end, covariance=Phi @ cov0 @ Phi.T, params=params,
                            table=table)
    out, _ = simulate(state0, t, params, table, t0_s=t[0], dt_s=options.dt_s)
    resid = out[:, 0:3] - X
    info = FitInfo(residuals_m=resid, rms_m=float(np.sqrt(np.mean(resid**2))), state_t0=state0, nfev=int(res.nfev),
                   success=bool(res.success), cost=float(res.cost),
                   logdet_hessian=float(logdet_h) if sign > 0 else float("inf"))
    return estimate, info


def fit_initial_state_mixture(t_s, X_world, spin_priors, params: BallParams | None = None,
                              table: TableGeometry | None = None,
                              options: EstimatorOptions = EstimatorOptions()) -> tuple[BallEstimate, FitInfo]:
    """MAP estimate under a Gaussian-mixture spin prior (docs/ball_physics.md, eq. 8).

    spin_priors : sequence of ``(weight, mean (3,) rad/s, std)`` components, ``std`` a number (rad/s,
    isotropic) or a (3, 3) covariance (rad^2/s^2), e.g. the spins a launcher produces, learned from
    fitted flights (:func:`spin_prior_from_spins`). Each component is fitted with
    :func:`fit_initial_state`; the one with the largest Laplace evidence is returned (eq. 8: smallest
    ``cost + log det(H)/2 + log det(Sigma_k)/2 - log weight``, H the Gauss-Newton Hessian at the
    component's optimum), ``info.component`` its index and ``info.scores`` every component's score.
    """
    comps = list(spin_priors)
    if not comps:
        raise ValueError("spin_priors must hold at least one (weight, mean, std) component, got none")
    best, scores = None, []
    for k, comp in enumerate(comps):
        try:
            weight, mean = float(comp[0]), tuple(float(m) for m in comp[1])
            spread = np.asarray(comp[2], float)
        except (TypeError, ValueError, IndexError) as exc:
            raise ValueError(f"spin_priors[{k}] must be (weight, (3,) mean, std or (3, 3) cov), got {comp!r}") from exc
        if spread.ndim == 0:
            if not spread > 0:
                raise ValueError(f"spin_priors[{k}] needs std > 0, got {comp!r}")
            cov = np.eye(3) * float(spread) ** 2
        else:
            cov = check_spin_cov(spread, f"spin_priors[{k}] covariance")
        if not (weight > 0 and len(mean) == 3):
            raise ValueError(f"spin_priors[{k}] needs weight > 0 and a (3,) mean, got {comp!r}")
        opts = dataclasses.replace(options, spin_prior_mean_rad_s=mean, estimate_spin=True,
                                   spin_prior_cov_rad2_s2=tuple(map(tuple, cov)))
        est, info = fit_initial_state(t_s, X_world, params, table, opts)
        score = info.cost + 0.5 * info.logdet_hessian + 0.5 * np.linalg.slogdet(cov)[1] - np.log(weight)
        scores.append(float(score))
        if best is None or score < best[0]:
            best = (score, est, dataclasses.replace(info, component=k))
    return best[1], dataclasses.replace(best[2], scores=tuple(scores))


def spin_prior_from_spins(spins_rad_s, *, min_std_rad_s: float = 3.0, inflation: float = 1.0
                          ) -> tuple[tuple, tuple]:
    """Gaussian spin prior ``(mean (3,), covariance (3, 3) as tuples)`` from fitted spins (n, 3), rad/s.

    The sample mean and ``inflation`` x the sample covariance plus ``min_std_rad_s**2`` on the
    diagonal (so that a handful of flights, or one, gives a proper prior). What the estimator knows
    of a launcher setting: the spins fitted to its earlier flights (``rt2 sim fit-flight``).
    """
    S = np.asarray(spins_rad_s, float)
    if S.ndim != 2 or S.shape[1] != 3 or S.shape[0] < 1 or not np.isfinite(S).all():
        raise ValueError(f"spins_rad_s must be a finite (n >= 1, 3) array, got shape {S.shape}")
    if not (min_std_rad_s > 0 and inflation >= 0):
        raise ValueError(f"need min_std_rad_s > 0 and inflation >= 0, got {min_std_rad_s!r}, {inflation!r}")
    mean = S.mean(axis=0)
    cov = np.cov(S.T, bias=True) if S.shape[0] > 1 else np.zeros((3, 3))
    cov = inflation * cov + np.eye(3) * min_std_rad_s**2
    return tuple(mean.tolist()), tuple(map(tuple, cov.tolist()))


@dataclass(frozen=True)
class EKFOptions:
    """Options of :class:`BallEKF`.

    init_samples : observations collected before the first estimate (by :func:`fit_initial_state`)
    accel_noise_mps2 : std of the white acceleration noise the model misses (drag/lift errors)
    spin_noise_rad_s2 : std of the white spin-rate noise (random-walk spin)
    gate_chi2 : innovations with a larger squared Mahalanobis distance are rejected as outliers
    """

    init_samples: int = 10
    accel_noise_mps2: float = 1.0
    spin_noise_rad_s2: float = 20.0
    gate_chi2: float = 16.27  # chi^2(3) at 0.999
    estimator: EstimatorOptions = EstimatorOptions()

    def __post_init__(self):
        if self.init_samples < 4 or self.accel_noise_mps2 < 0 or self.spin_noise_rad_s2 < 0 or self.gate_chi2 <= 0:
            raise ValueError(f"EKFOptions need init_samples >= 4 and non-negative noises, got {self}")


class BallEKF:
    """Online EKF over [p, v, w] with the physical transition of eqs. (1)-(6) (docs/ball_physics.md, sec. 4).

    Feed observations in time order with :meth:`update`; :attr:`estimate` is ``None`` until
    ``init_samples`` observations have arrived. Built on ``filterpy``'s ExtendedKalmanFilter,
    with the integrator as the state transition.
    """

    def __init__(self, params: BallParams | None = None, table: TableGeometry | None = None,
                 options: EKFOptions = EKFOptions()):
        from filterpy.kalman import ExtendedKalmanFilter

        self.params = params or BallParams.load()  # fitted defaults, data/ball_params.yaml
        self.table = table or TableGeometry()
        self.options = options
        self._kf = ExtendedKalmanFilter(dim_x=9, dim_z=3)
        self._kf.R = np.diag(np.broadcast_to(np.asarray(options.estimator.position_noise_m, float), (3,)) ** 2)
        self._buffer_t: list[float] = []
        self._buffer_x: list[np.ndarray] = []
        self._t: float | None = None
        self.n_rejected = 0

    @property
    def estimate(self) -> BallEstimate | None:
        if self._t is None:
            return None
        return BallEstimate(t_s=self._t, state=self._kf.x[:, 0].copy(), covariance=self._kf.P.copy(),
                            params=self.params, table=self.table)

    def _process_noise(self, dt: float) -> np.ndarray:
        qa, qw = self.options.accel_noise_mps2**2, self.options.spin_noise_rad_s2**2
        Q = np.zeros((9, 9))
        for a in range(3):  # discrete white-noise acceleration per axis
            Q[a, a] = dt**3 / 3 * qa
            Q[a, a + 3] = Q[a + 3, a] = dt**2 / 2 * qa
            Q[a + 3, a + 3] = dt * qa
        Q[6:, 6:] = np.eye(3) * dt * qw
        return Q

    def update(self, t_s: float, position_m) -> BallEstimate | None:
        """Add one observation (time, (3,) world position); returns the current estimate (or None)."""
        z = np.asarray(position_m, float)
        if z.shape != (3,) or not np.isfinite(z).all() or not np.isfinite(t_s):
            raise ValueError(f"update needs a finite time and a (3,) position, got t_s={t_s!r}, position {z!r}")
        last = self._t if self._t is not None else (self._buffer_t[-1] if self._buffer_t else -np.inf)
        if t_s <= last:
            raise ValueError(f"observations must arrive in increasing time; got t_s={t_s!r} after {last!r}")
        if self._t is None:
            self._buffer_t.append(float(t_s))
            self._buffer_x.append(z)
            if len(self._buffer_t) >= self.options.init_samples:
                est, _ = fit_initial_state(self._buffer_t, self._buffer_x, self.params, self.table,
                                           self.options.estimator)
                self._kf.x = est.state[:, None].copy()
                self._kf.P = est.covariance + np.eye(9) * 1e-12
                self._t = est.t_s
            return self.estimate
        dt = float(t_s) - self._t
        x_new, F = _propagate_with_jacobian(self._kf.x[:, 0], self._t, float(t_s), self.params, self.table, 1e-3)
        self._kf.F = F
        self._kf.Q = self._process_noise(dt)
        self._kf.predict_x = lambda u=0: None  # the transition is the integrator: x set below
        self._kf.x = x_new[:, None]
        self._kf.predict()
        self._t = float(t_s)
        H = np.hstack([np.eye(3), np.zeros((3, 6))])
        innovation = z - x_new[0:3]
        S = H @ self._kf.P @ H.T + self._kf.R
        if innovation @ np.linalg.solve(S, innovation) > self.options.gate_chi2:
            self.n_rejected += 1
            return self.estimate
        self._kf.update(z[:, None], lambda x: H, lambda x: H @ x)
        return self.estimate
