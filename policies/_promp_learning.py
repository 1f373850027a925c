"""Learning a ProMP from demonstrations: MAP-EM with conjugate priors, or plain maximum likelihood.

Model (Paraschos et al. 2013; Gomez-Gonzalez et al. 2020, Sec. III), demonstration n with samples
t = 1..T_n at phases z_nt = (t_nt - t_n0) / (t_nT - t_n0) (each demonstration its own duration):

    w_n ~ N(mu_w, Sigma_w),         y_nt = Psi(z_nt) w_n + eps,   eps ~ N(0, Sigma_y),

with Psi(z) = I_D (x) phi(z)^T the block-diagonal basis of D joints (weights joint-major:
w[d*K + k]). The w_n are latent. Priors (Gomez-Gonzalez et al. 2020, Sec. III-B):

    (mu_w, Sigma_w) ~ NIW(m0, kappa0, S0, nu0):   Sigma_w ~ IW(S0, nu0),  mu_w | Sigma_w ~ N(m0, Sigma_w / kappa0)
    Sigma_y ~ IW(S_y0, nu_y0)

(kappa0 = 0 drops the prior on mu_w). EM (Dempster et al. 1977; MAP variant: Bishop PRML 9.4):

E-step (posterior of each demonstration's weights, PRML Eq. 2.116-2.117):
    P_n = Sigma_w^-1 + Sigma_y^-1 (x) G_n,      G_n = sum_t phi_t phi_t^T            (E1)
    S_n = P_n^-1,  m_n = S_n (Sigma_w^-1 mu_w + vec(H_n Sigma_y^-1)),  H_n = sum_t phi_t y_t^T   (E2)
M-step (mode of the NIW / IW posterior given the expected sufficient statistics; Murphy 2007,
"Conjugate Bayesian analysis of the Gaussian distribution", Sec. 9):
    mu_w    = (kappa0 m0 + sum_n m_n) / (kappa0 + N)                                 (M1)
    Sigma_w = (S0 + kappa0 (mu_w - m0)(.)^T + sum_n [S_n + (m_n - mu_w)(.)^T]) / (N + n0)   (M2)
              n0 = nu0 + dim(w) + 1 + [kappa0 > 0]
    Sigma_y = (S_y0 + sum_n E[sum_t (y_t - Psi_t w_n)(.)^T]) / (sum_n T_n + nu_y0 + D + 1)  (M3)
              E[...] = R_n^T R_n + C_n,  R_n = Y_n - B_n M_n,  C_n[d,e] = tr(S_n[d,e] G_n)
Maximum likelihood drops S0, S_y0, kappa0 and uses N and sum_n T_n as denominators.

The objective reported per iteration is the exact log-likelihood sum_n log N(y_n | Psi_n mu_w,
Psi_n Sigma_w Psi_n^T + I (x) Sigma_y) (Woodbury identity and determinant lemma, so no
(T D)^2 matrix is formed) plus the unnormalised log prior; EM never decreases it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from policies._promp_basis import RBFBasis
from checks.arrays import check_array, check_positive

__all__ = ["EMInfo", "NIWPrior", "check_demos", "demo_log_likelihood", "fit_em"]

_LOG_2PI = float(np.log(2.0 * np.pi))


def _scale_joint_iso(W: np.ndarray, n_dims: int, K: int) -> np.ndarray:
    """Per joint one variance, the mean variance of that joint's least-squares weights."""
    var = W.var(axis=0).reshape(n_dims, K).mean(axis=1)
    return np.repeat(var, K)


def _scale_diag(W: np.ndarray, n_dims: int, K: int) -> np.ndarray:
    """Per weight its own least-squares variance."""
    return W.var(axis=0)


#: prior-mode choices for Sigma_w: name -> f(least-squares weights (N, d), n_dims, K) -> (d,) variances
PRIOR_SCALES = {"joint_iso": _scale_joint_iso, "diag": _scale_diag}


@dataclass(frozen=True)
class NIWPrior:
    """Conjugate priors of MAP-EM (Gomez-Gonzalez et al. 2020, Sec. III-B).

    The prior mode of Sigma_w is the diagonal matrix Sigma0 chosen by ``scale`` from the spread of
    the demonstrations' least-squares weights (empirical Bayes, as the authors' ``mean_cov_mle``):
    ``"joint_iso"`` one variance per joint, ``"diag"`` one per weight; ``scale_floor`` is added to
    it. S0 = n0 Sigma0 with n0 = nu0 + dim(w) + 1 + [kappa0 > 0], so that (M2) shrinks the
    weight covariance towards Sigma0 as n0 pseudo-demonstrations would.

    kappa0 : pseudo-count of the prior on mu_w (mean m0 = 0); 0 = flat prior on the mean
    nu0 : IW degrees of freedom; ``None`` -> such that n0 = ``pseudo_demos``. Values below
          dim(w) - 1 make the prior improper, which MAP estimation allows (only the mode is used)
    pseudo_demos : n0 when ``nu0`` is None
    nu_y0 : IW degrees of freedom of Sigma_y; ``None`` -> n_dims + 2
    sigma_y0 : prior mode of the observation noise standard deviation (joint units, rad)
    """

    kappa0: float = 0.0
    nu0: float | None = None
    pseudo_demos: float = 2.0
    scale: str = "joint_iso"
    scale_floor: float = 1e-8
    nu_y0: float | None = None
    sigma_y0: float = 1e-3

    def __post_init__(self):
        if self.scale not in PRIOR_SCALES:
            raise ValueError(f"unknown prior scale {self.scale!r}; valid: {sorted(PRIOR_SCALES)}")
        check_positive(self.kappa0, "NIWPrior.kappa0", allow_zero=True)
        check_positive(self.pseudo_demos, "NIWPrior.pseudo_demos")
        check_positive(self.scale_floor, "NIWPrior.scale_floor", allow_zero=True)
        check_positive(self.sigma_y0, "NIWPrior.sigma_y0")
        for name in ("nu0", "nu_y0"):
            value = getattr(self, name)
            if value is not None and not np.isfinite(float(value)):
                raise ValueError(f"NIWPrior.{name} must be finite or None, got {value!r}")

    def n0(self, n_weights: int) -> float:
        """Pseudo-count of Sigma_w in (M2)."""
        if self.nu0 is None:
            return float(self.pseudo_demos)
        n0 = float(self.nu0) + n_weights + 1 + (self.kappa0 > 0)
        if n0 <= 0:
            raise ValueError(f"NIWPrior.nu0 = {self.nu0!r} too small for {n_weights} weights: n0 = {n0:g} <= 0")
        return n0

    def ny0(self, n_dims: int) -> float:
        """Pseudo-count of Sigma_y in (M3): nu_y0 + D + 1."""
        nu_y0 = n_dims + 2.0 if self.nu_y0 is None else float(self.nu_y0)
        ny0 = nu_y0 + n_dims + 1
        if ny0 <= 0:
            raise ValueError(f"NIWPrior.nu_y0 = {self.nu_y0!r} too small for {n_dims} joints")
        return ny0


@dataclass(frozen=True, eq=False)
class EMInfo:
    """What :func:`fit_em` reports.

    objective : (n_iter + 1,) log-posterior (MAP, up to a constant) or log-likelihood (ML) of the
                parameters before the first and after every M-step; non-decreasing
    log_likelihood : (n_iter + 1,) the data log-likelihood part of ``objective``
    iterations : number of M-steps run
    converged : the relative change of ``objective`` fell below ``tol``
    mode : ``"map"`` or ``"ml"``
    """

    objective: np.ndarray
    log_likelihood: np.ndarray
    iterations: int
    converged: bool
    mode: str


@dataclass(frozen=True)
class _Stats:
    """Sufficient statistics of N demonstrations (per demo, stacked)."""

    G: np.ndarray  # (N, K, K)  sum_t phi_t phi_t^T
    H: np.ndarray  # (N, K, D)  sum_t phi_t y_t^T
    YY: np.ndarray  # (N, D, D) sum_t y_t y_t^T
    T: np.ndarray  # (N,)       samples per demo


def _stats(basis: RBFBasis, demos: list, times: list) -> _Stats:
    G, H, YY = [], [], []
    for q, t in zip(demos, times):
        B = basis((t - t[0]) / (t[-1] - t[0]))  # phase of each demo from its own duration
        G.append(B.T @ B)
        H.append(B.T @ q)
        YY.append(q.T @ q)
    return _Stats(np.array(G), np.array(H), np.array(YY), np.array([len(t) for t in times], dtype=float))


def _chol_logdet_inv(A: np.ndarray) -> tuple[float | np.ndarray, np.ndarray]:
    """log|A| and A^-1 for (batched) symmetric positive-definite A."""
    L = np.linalg.cholesky(A)
    logdet = 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(axis=-1)
    eye = np.broadcast_to(np.eye(A.shape[-1]), A.shape)
    Linv = np.linalg.solve(L, eye)
    inv = np.swapaxes(Linv, -1, -2) @ Linv
    return logdet, inv


def _e_step(st: _Stats, mu_w, Sigma_w, Sigma_y):
    """(E1)-(E2) for all demos at once, plus each demo's exact log marginal likelihood.

    returns m (N, d), S (N, d, d), loglik (N,)
    """
    N, K, D = st.H.shape
    logdet_w, Lw = _chol_logdet_inv(Sigma_w)
    logdet_y, Ly = _chol_logdet_inv(Sigma_y)
    P = Lw[None] + np.einsum("de,nkl->ndkel", Ly, st.G).reshape(N, D * K, D * K)  # (E1)
    logdet_P, S = _chol_logdet_inv(P)
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    HL = np.einsum("nkd,de->nek", st.H, Ly).reshape(N, D * K)  # vec(H_n Sigma_y^-1), joint-major
    m = np.einsum("nij,nj->ni", S, (Lw @ mu_w)[None] + HL)  # (E2)
    # log N(y_n | Psi mu_w, Psi Sigma_w Psi^T + Sigma_y (x) I) via Woodbury / determinant lemma
    M0 = mu_w.reshape(D, K).T  # (K, D)
    HtM = np.einsum("nkd,ke->nde", st.H, M0)
    R0 = st.YY - HtM - np.swapaxes(HtM, 1, 2) + np.einsum("kd,nkl,le->nde", M0, st.G, M0)
    u = np.einsum("nkd,de->nek", st.H - st.G @ M0, Ly).reshape(N, D * K)
    quad = np.einsum("de,ned->n", Ly, R0) - np.einsum("ni,nij,nj->n", u, S, u)
    loglik = -0.5 * (st.T * D * _LOG_2PI + st.T * logdet_y + logdet_w + logdet_P + quad)
    return m, S, loglik


def _log_prior(prior: NIWPrior | None, hyper, mu_w, Sigma_w, Sigma_y) -> float:
    """Unnormalised log NIW(mu_w, Sigma_w) + log IW(Sigma_y); 0 for maximum likelihood."""
    if prior is None:
        return 0.0
    S0, n0, m0, Sy0, ny0 = hyper
    logdet_w, Lw = _chol_logdet_inv(Sigma_w)
    logdet_y, Ly = _chol_logdet_inv(Sigma_y)
    lp = -0.5 * (n0 * logdet_w + np.sum(S0 * Lw))  # IW(S0, nu0) and, if kappa0 > 0, |Sigma_w/kappa0|^-1/2
    if prior.kappa0 > 0:
        dm = mu_w - m0
        lp -= 0.5 * prior.kappa0 * dm @ Lw @ dm
    lp -= 0.5 * (ny0 * logdet_y + np.sum(Sy0 * Ly))
    return float(lp)


def _m_step(st: _Stats, m, S, prior: NIWPrior | None, hyper, diagonal_sigma_y: bool):
    """(M1)-(M3)."""
    N, K, D = st.H.shape
    kappa0 = 0.0 if prior is None else prior.kappa0
    if prior is None:
        mu_w = m.mean(axis=0)
    else:
        mu_w = (kappa0 * hyper[2] + m.sum(axis=0)) / (kappa0 + N)  # (M1)
    dm = m - mu_w
    scatter = S.sum(axis=0) + dm.T @ dm
    if prior is None:
        Sigma_w = scatter / N
    else:
        S0, n0, m0 = hyper[:3]
        d0 = mu_w - m0
        Sigma_w = (S0 + kappa0 * np.outer(d0, d0) + scatter) / (N + n0)  # (M2)
    Mn = np.swapaxes(m.reshape(N, D, K), 1, 2)  # (N, K, D)
    HtM = np.einsum("nkd,nke->nde", st.H, Mn)
    RR = st.YY - HtM - np.swapaxes(HtM, 1, 2) + np.einsum("nkd,nkl,nle->nde", Mn, st.G, Mn)
    C = np.einsum("ndkel,nlk->nde", S.reshape(N, D, K, D, K), st.G)
    resid = (RR + C).sum(axis=0)
    if prior is None:
        Sigma_y = resid / st.T.sum()
    else:
        Sigma_y = (hyper[3] + resid) / (st.T.sum() + hyper[4])  # (M3)
    if diagonal_sigma_y:
        Sigma_y = np.diag(np.diag(Sigma_y))
    return mu_w, 0.5 * (Sigma_w + Sigma_w.T), 0.5 * (Sigma_y + Sigma_y.T)


def _least_squares_weights(st: _Stats) -> np.ndarray:
    """(N, d) ridge least-squares weights of each demo, joint-major."""
    N, K, D = st.H.shape
    ridge = 1e-8 * np.trace(st.G, axis1=1, axis2=2)[:, None, None] / K
    W = np.linalg.solve(st.G + ridge * np.eye(K), st.H)  # (N, K, D)
    return np.swapaxes(W, 1, 2).reshape(N, D * K)


def fit_em(basis: RBFBasis, demos: list, times: list, *, prior: NIWPrior | None, max_iter: int,
           tol: float, diagonal_sigma_y: bool = True):
    """MAP-EM (``prior`` given) or ML-EM (``prior=None``) on validated demos.

    returns (mu_w (d,), Sigma_w (d, d), Sigma_y (D, D)), EMInfo
    """
    st = _stats(basis, demos, times)
    N, K, D = st.H.shape
    d = D * K
    W = _least_squares_weights(st)
    # Initialisation: least-squares weights' mean and covariance, residual covariance.
    floor_w = 1e-6 * max(float(W.var(axis=0).mean()), 1e-12) + 1e-12
    mu_w = W.mean(axis=0)
    Sigma_w = np.cov(W.T, bias=True).reshape(d, d) + floor_w * np.eye(d)
    Mn = np.swapaxes(W.reshape(N, D, K), 1, 2)
    HtM = np.einsum("nkd,nke->nde", st.H, Mn)
    RR = st.YY - HtM - np.swapaxes(HtM, 1, 2) + np.einsum("nkd,nkl,nle->nde", Mn, st.G, Mn)
    Sigma_y = RR.sum(axis=0) / st.T.sum() + 1e-12 * np.eye(D)
    if diagonal_sigma_y:
        Sigma_y = np.diag(np.diag(Sigma_y))
    hyper = None
    if prior is not None:
        n0 = prior.n0(d)
        sigma0 = PRIOR_SCALES[prior.scale](W, D, K) + prior.scale_floor
        if not (sigma0 > 0).all():
            raise ValueError("NIWPrior: the demonstrations do not vary and scale_floor is 0; set scale_floor > 0")
        ny0 = prior.ny0(D)
        hyper = (n0 * np.diag(sigma0), n0, np.zeros(d), ny0 * prior.sigma_y0**2 * np.eye(D), ny0)
    objective, loglik = [], []
    m, S, ll = _e_step(st, mu_w, Sigma_w, Sigma_y)
    loglik.append(float(ll.sum()))
    objective.append(loglik[-1] + _log_prior(prior, hyper, mu_w, Sigma_w, Sigma_y))
    converged, it = False, 0
    for it in range(1, max_iter + 1):
        mu_w, Sigma_w, Sigma_y = _m_step(st, m, S, prior, hyper, diagonal_sigma_y)
        m, S, ll = _e_step(st, mu_w, Sigma_w, Sigma_y)
        loglik.append(float(ll.sum()))
        objective.append(loglik[-1] + _log_prior(prior, hyper, mu_w, Sigma_w, Sigma_y))
        if abs(objective[-1] - objective[-2]) <= tol * max(1.0, abs(objective[-1])):
            converged = True
            break
    info = EMInfo(np.array(objective), np.array(loglik), it, converged, "ml" if prior is None else "map")
    return (mu_w, Sigma_w, Sigma_y), info


def demo_log_likelihood(basis: RBFBasis, mu_w, Sigma_w, Sigma_y, demos: list, times: list) -> np.ndarray:
    """(N,) exact log marginal likelihood of each validated demo under N(mu_w, Sigma_w), Sigma_y."""
    _, _, ll = _e_step(_stats(basis, demos, times), mu_w, Sigma_w, Sigma_y)
    return ll


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
        q = check_array(q, f"demos[{n}]", (None, n_dims), finite=True)
        if n_dims is None:
            n_dims = q.shape[1]
        if n_dims < 1:
            raise ValueError(f"demos[{n}] has no joints: shape {q.shape}")
        t = check_array(t, f"times[{n}]", (None,), finite=True)
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
