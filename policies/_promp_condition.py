"""Conditioning a ProMP on via points: Gaussian conditioning of the weights (a Kalman update).

Joint space (Paraschos et al. 2013, Eq. 5-6): observing y = O w with O = I_D (x) phi(z)^T
(positions) and/or I_D (x) dphi/dz(z)^T / T (velocities), y ~ N(y*, R):

    S = O Sigma_w O^T + R,   K = Sigma_w O^T S^-1
    mu_w'    = mu_w + K (y* - O mu_w)                                   (C1)
    Sigma_w' = (I - K O) Sigma_w (I - K O)^T + K R K^T  (Joseph form)   (C2)

Task space (Gomez-Gonzalez et al. 2020, Sec. IV; the kinematics are nonlinear): observing
x = f(Psi w) ~ N(x*, R), linearise f around the current estimate w_i with H_i = J(Psi w_i) Psi
and iterate the update from the prior (the iterated extended Kalman update, Bell & Cathey 1993,
which is Gauss-Newton on the MAP of w):

    K_i = Sigma_w H_i^T (H_i Sigma_w H_i^T + R)^-1
    w_{i+1} = mu_w + K_i (x* - f(Psi w_i) - H_i (mu_w - w_i))           (C3)

until the joint-space step |Psi (w_{i+1} - w_i)| < tol; steps longer than ``_MAX_STEP_RAD`` are
shortened. The covariance is (C2) with the last linearisation.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from checks.arrays import check_array, check_covariance, check_positive

__all__ = ["block", "condition_on_joint", "condition_on_task", "eval_kinematics", "jittered"]

_MAX_STEP_RAD = 0.5  # longest joint-space step of one task-space iteration (keeps Gauss-Newton stable)


def _scalar_time(t_s) -> float:
    if np.ndim(t_s) != 0:
        raise ValueError(f"t_s must be one time in seconds, got shape {np.shape(t_s)}")
    try:
        return float(t_s)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"t_s must be a number of seconds, got {t_s!r}") from exc


def block(row: np.ndarray, n_dims: int) -> np.ndarray:
    """I_D (x) row^T: (n_dims, n_dims * K) from a (K,) feature row."""
    return np.kron(np.eye(n_dims), row[None, :])


def jittered(S: np.ndarray) -> np.ndarray:
    """S symmetrised, plus a relative jitter on the diagonal that keeps it invertible for exact (R = 0) or
    repeated via points."""
    return 0.5 * (S + S.T) + 1e-12 * (np.trace(S) / len(S) + 1e-300) * np.eye(len(S))


def _kalman(mu_w, Sigma_w, O, y, R):
    """(C1)-(C2)."""
    S = jittered(O @ Sigma_w @ O.T + R)
    K = np.linalg.solve(S, O @ Sigma_w).T
    mu = mu_w + K @ (y - O @ mu_w)
    A = np.eye(len(mu_w)) - K @ O
    cov = A @ Sigma_w @ A.T + K @ R @ K.T
    return mu, 0.5 * (cov + cov.T)


def condition_on_joint(promp, t_s, q_mean, q_cov, qd_mean, qd_cov, duration_s):
    """See :meth:`ProMP.condition_on_joint`."""
    D = promp.n_dims
    z, rate = promp.phase(_scalar_time(t_s), duration_s=duration_s)
    phi, dphi = promp.basis.evaluate(z)
    rows, ys, covs = [], [], []
    for name, mean, cov, feat in (("q", q_mean, q_cov, phi[0]), ("qd", qd_mean, qd_cov, dphi[0] * rate)):
        if mean is None:
            if cov is not None:
                raise ValueError(f"{name}_cov given without {name}_mean")
            continue
        rows.append(block(feat, D))
        ys.append(check_array(mean, f"{name}_mean", (D,), finite=True))
        covs.append(np.zeros((D, D)) if cov is None else check_covariance(cov, f"{name}_cov", D))
    if not rows:
        raise ValueError("give q_mean and/or qd_mean to condition on")
    R = np.zeros((len(covs) * D, len(covs) * D))
    for i, c in enumerate(covs):
        R[i * D : (i + 1) * D, i * D : (i + 1) * D] = c
    mu, cov = _kalman(promp.mu_w, promp.Sigma_w, np.vstack(rows), np.concatenate(ys), R)
    return replace(promp, mu_w=mu, Sigma_w=cov)


def eval_kinematics(fk, jacobian, q: np.ndarray, n_dims: int):
    """Evaluate user kinematics at each row of q (n, n_dims); check the shapes they return.

    returns x (n, m), J (n, m, n_dims)
    """
    if not callable(fk) or not callable(jacobian):
        raise ValueError(f"fk and jacobian must be callables, got {type(fk).__name__} and {type(jacobian).__name__}")
    xs, Js = [], []
    for qi in np.atleast_2d(q):
        x = check_array(fk(qi.copy()), "fk(q)", (None,), finite=True)
        J = check_array(jacobian(qi.copy()), "jacobian(q)", (x.size, n_dims), finite=True)
        xs.append(x)
        Js.append(J)
    return np.array(xs), np.array(Js)


def condition_on_task(promp, t_s, x_target, x_cov, fk, jacobian, iterations, tol, max_residual_m, duration_s):
    """See :meth:`ProMP.condition_on_task`."""
    D = promp.n_dims
    x_target = check_array(x_target, "x_target", (None,), finite=True)
    m = x_target.size
    R = np.zeros((m, m)) if x_cov is None else check_covariance(x_cov, "x_cov", m)
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise ValueError(f"iterations must be a positive integer, got {iterations!r}")
    tol = check_positive(tol, "tol", allow_zero=True)
    z, _ = promp.phase(_scalar_time(t_s), duration_s=duration_s)
    Psi = block(promp.basis(z)[0], D)  # (D, d)
    mu0, S0 = np.asarray(promp.mu_w), np.asarray(promp.Sigma_w)
    w = mu0.copy()
    f, J = eval_kinematics(fk, jacobian, Psi @ w, D)
    if f.shape[1] != m:
        raise ValueError(f"fk(q) returns {f.shape[1]} values but x_target has {m}")
    for _ in range(int(iterations)):
        H = J[0] @ Psi
        S = jittered(H @ S0 @ H.T + R)
        K = np.linalg.solve(S, H @ S0).T
        w_new = mu0 + K @ (x_target - f[0] - H @ (mu0 - w))  # (C3)
        step = float(np.linalg.norm(Psi @ (w_new - w)))
        if step > _MAX_STEP_RAD:
            w_new = w + (_MAX_STEP_RAD / step) * (w_new - w)
        w = w_new
        f, J = eval_kinematics(fk, jacobian, Psi @ w, D)
        if step <= tol:
            break
    H = J[0] @ Psi
    S = jittered(H @ S0 @ H.T + R)
    K = np.linalg.solve(S, H @ S0).T
    A = np.eye(len(w)) - K @ H
    cov = A @ S0 @ A.T + K @ R @ K.T  # (C2) at the last linearisation
    if max_residual_m is not None:
        miss = float(np.linalg.norm(f[0] - x_target))
        allowed = float(max_residual_m) + 3.0 * float(np.sqrt(max(np.linalg.eigvalsh(R)[-1], 0.0)))
        if not miss <= allowed:
            raise ValueError(
                f"task-space via point {np.round(x_target, 4).tolist()} at t_s = {float(t_s):g} s is unreachable "
                f"under this ProMP: the conditioned mean misses it by {miss:.4g} (allowed {allowed:.4g})")
    return replace(promp, mu_w=w, Sigma_w=0.5 * (cov + cov.T))
