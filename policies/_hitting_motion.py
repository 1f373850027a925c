"""From a chosen hit to a commanded joint trajectory: conditioning the ProMP, sampling it, checking it.

The hitting movement is the ProMP executed with duration T from its start time t_start (time scaling:
phase z = (t - t_start) / T). It is conditioned, in this order (each a new ProMP; Paraschos et al.
2013 Eq. 5-6 for joint via points, the iterated task-space update of docs/promp.md sec. 3 for the
racket):

    (M1) the present: q(t_now) = q_now, qd(t_now) = qd_now exactly -- at rest at phase 0 before the
         movement starts; the commanded reference at the current phase when re-planning a movement
         already under way (so the new reference continues the old one without a jump);
    (M2) the end: back at rest at the ready posture, q(T) = q_ready, qd(T) = 0 (return to rest);
    (M3) the hit: racket centre and normal [x_racket; n] at t_hit (racket_kinematics with the normal;
         ValueError if the conditioned mean misses it by more than 1 cm: out of reach);
    (M4) the racket velocity at t_hit: with q_hit the conditioned mean there and J its racket
         Jacobian, the joint velocity closest to the mean that gives the racket velocity v_r,
         qd* = qd_mean + J^+ (v_r - J qd_mean), conditioned exactly together with q_hit.

The conditioned mean is sampled at the control rate; it is feasible if it stays inside the joint
limits and its velocities and (finite-difference) accelerations stay within ``margin`` x the WAM's
limits. If only velocity or acceleration limits are broken, a slower execution (time scaling: the
duration T times s, velocities / s, accelerations / s^2) fixes it when the movement can still start
early enough; the policy tries that. The simulated WAM enforces the limits anyway; a plan that would
break them is not sent.

Fast form (``method="fast"``, the default; ``"reference"`` is the ProMP API in sequence). A plan is made
up to ~10 times per second and every conditioning of the ProMP API builds a new primitive with its full
(n_weights x n_weights) covariance, 4 times per try and up to 9 tries per first plan. Only the final
*mean* is executed, and every via point observes the weights through I_D (x) f^T for a feature row f, so
the same posterior mean follows from the products of the prior covariance with the six feature rows
(one n_weights x 6 D product): (M1) and (M2) become one exact update, (M3)'s Gauss-Newton iteration
runs in the 7 joints of the hit instead of the weights (one kinematics call per iteration for the
position, normal and Jacobian), and (M4) needs only the covariance's products with the hit's rows.
Same result as the reference to rounding (tests/policies/test_hitting_planner.py); with the compiled
return outcome, a planning step takes 2.4x less time (``rt2 bench policy``).
"""

from __future__ import annotations

import numpy as np

from policies._promp_condition import block, jittered

__all__ = ["METHODS", "check_feasible", "condition_hit", "sample_mean"]

METHODS = ("fast", "reference")  #: how (M1)-(M4) are computed (same result to rounding; module docstring)
_MAX_STEP_RAD = 0.5  # as ProMP.condition_on_task: the longest joint-space step of one (M3) iteration
_ITERATIONS, _TOL_RAD, _MAX_MISS = 30, 1e-10, 0.01  # ProMP.condition_on_task's defaults


def condition_hit(promp, *, duration_s, t_rel_now, q_now, qd_now, q_ready, t_rel_hit, x_racket, normal,
                  v_racket, racket, method: str = "fast") -> np.ndarray:
    """(M1)-(M4): the ProMP's weight mean conditioned on the present, the end at rest, and the hit.

    Times are seconds from the movement's start; racket(q (7,)) -> ([centre; normal] (6,), Jacobian (6, 7))
    (:func:`policies.teacher.racket_fk_jacobian`). Returns the conditioned weight mean (n_weights,)
    (:func:`sample_mean` samples it); raises ValueError when the hit is out of the primitive's reach.

    ``method="reference"`` runs the four conditionings one after the other with the ProMP API
    (each a new ProMP with its full covariance, :meth:`ProMP.condition_on_task` for (M3)).
    ``"fast"`` computes the same posterior mean in a reduced form (module docstring, "Fast form")."""
    if method == "reference":
        return _condition_sequential(promp, float(duration_s), float(t_rel_now), q_now, qd_now, q_ready,
                                     float(t_rel_hit), x_racket, normal, v_racket, racket)
    if method != "fast":
        raise ValueError(f"unknown conditioning method {method!r}; valid: {list(METHODS)}")
    return _condition_reduced(promp, float(duration_s), float(t_rel_now), np.asarray(q_now, float),
                              np.asarray(qd_now, float), np.asarray(q_ready, float), float(t_rel_hit),
                              np.concatenate([x_racket, normal]), np.asarray(v_racket, float), racket)


def _condition_sequential(promp, T, t_now, q_now, qd_now, q_ready, t_hit, x_racket, normal, v_racket, racket):
    p = promp.condition_on_joint(t_now, q_now, None, qd_mean=qd_now, duration_s=T)  # (M1)
    p = p.condition_on_joint(T, q_ready, None, qd_mean=np.zeros(promp.n_dims), duration_s=T)  # (M2)
    target = np.concatenate([x_racket, normal])
    p = p.condition_on_task(t_hit, target, None, lambda q: racket(q)[0], lambda q: racket(q)[1], duration_s=T,
                            iterations=_ITERATIONS, tol=_TOL_RAD, max_residual_m=_MAX_MISS)  # (M3)
    q_hit, qd_hit = (a[0] for a in p.mean_trajectory([t_hit], duration_s=T))
    J = racket(q_hit)[1][:3]
    qd_star = qd_hit + np.linalg.pinv(J) @ (np.asarray(v_racket, float) - J @ qd_hit)  # (M4)
    return p.condition_on_joint(t_hit, q_hit, None, qd_mean=qd_star, duration_s=T).mu_w


def _condition_reduced(promp, T, t_now, q_now, qd_now, q_ready, t_hit, target, v_racket, racket):
    """The fast form. Every via point observes O_r w with O_r = I_D (x) f_r^T for a feature row f_r (positions
    phi(z), velocities dphi/dz(z) / T), so one product S O^T (n_weights x 6 D) with all six rows carries every
    covariance the four updates need; (M3) iterates in the D joints of the hit: with q = Psi w, B = Sigma Psi^T
    and S_q = Psi Sigma Psi^T, the update (C3) is q' = q0 + S_q J^T S^-1 (x* - f(q) - J (q0 - q)),
    S = J S_q J^T, and w' = mu + B J^T S^-1 (...)."""
    D = promp.n_dims
    z = np.clip(np.array([t_now, T, t_hit]) / T, 0.0, 1.0)
    phi, dphi = promp.basis.evaluate(z)
    F = np.stack([phi[0], dphi[0] / T, phi[1], dphi[1] / T, phi[2], dphi[2] / T])  # (6, K)
    O = np.concatenate([block(f, D) for f in F])  # (6 D, D K): rows (M1 q, qd), (M2 q, qd), hit (q, qd)
    mu, Sigma = promp.mu_w, promp.Sigma_w
    SO = Sigma @ O.T
    G = O @ SO
    a, h, p = slice(0, 4 * D), slice(4 * D, 6 * D), slice(0, D)
    # (M1) + (M2): exact joint via points, one update (sequential exact updates give the same posterior)
    Saa = jittered(G[a, a])
    y = np.concatenate([q_now, qd_now, q_ready, np.zeros(D)])
    mu = mu + SO[:, a] @ np.linalg.solve(Saa, y - O[a] @ mu)
    Gah = np.linalg.solve(Saa, G[a, h])
    B = SO[:, h] - SO[:, a] @ Gah  # Sigma' O_h^T after (M1)+(M2), (D K, 2 D)
    C = G[h, h] - G[h, a] @ Gah  # O_h Sigma' O_h^T, (2 D, 2 D)
    C = 0.5 * (C + C.T)
    # (M3): iterated update in the joints of the hit; u: w = mu + B_q u, q = q0 + S_q u
    Sq, q0 = C[p, p], O[4 * D : 5 * D] @ mu
    u, q = np.zeros(D), q0.copy()
    f, J = racket(q)
    for _ in range(_ITERATIONS):
        r = np.linalg.solve(jittered(J @ Sq @ J.T), target - f - J @ (q0 - q))
        u_new = J.T @ r
        q_new = q0 + Sq @ u_new
        step = float(np.linalg.norm(q_new - q))
        if step > _MAX_STEP_RAD:
            u_new = u + (_MAX_STEP_RAD / step) * (u_new - u)
            q_new = q0 + Sq @ u_new
        u, q = u_new, q_new
        f, J = racket(q)
        if step <= _TOL_RAD:
            break
    miss = float(np.linalg.norm(f - target))
    if not miss <= _MAX_MISS:
        raise ValueError(f"task-space via point {np.round(target, 4).tolist()} at t_s = {t_hit:g} s is unreachable "
                         f"under this ProMP: the conditioned mean misses it by {miss:.4g} (allowed {_MAX_MISS:.4g})")
    mu = mu + B[:, p] @ u
    # the covariance after (M3) at the last linearisation, as its products with O_h
    JC = J @ C[p, :]
    Sy = jittered(J @ Sq @ J.T)
    C3 = C - JC.T @ np.linalg.solve(Sy, JC)
    B3 = B - (B[:, p] @ J.T) @ np.linalg.solve(Sy, JC)
    # (M4): the racket velocity at the hit, with q_hit = the conditioned mean there
    qd_hit, J3 = O[5 * D :] @ mu, J[:3]
    qd_star = qd_hit + np.linalg.pinv(J3) @ (v_racket - J3 @ qd_hit)
    return mu + B3 @ np.linalg.solve(jittered(C3), np.concatenate([q, qd_star]) - O[h] @ mu)


def sample_mean(promp, mu_w, duration_s, t_rel_from, rate_hz):
    """The trajectory of weight mean ``mu_w`` (n_weights,) from ``t_rel_from`` to the end on the control
    grid (the end included), executed in ``duration_s``.

    returns t_rel (N,), q (N, D), qd (N, D)"""
    T = float(duration_s)
    dt = 1.0 / float(rate_hz)
    t = np.arange(float(t_rel_from), T, dt)
    t = np.append(t[t < T - 0.25 * dt], T)
    if t.size < 2:
        t = np.array([max(T - dt, 0.0), T])
    q, qd = promp.mean_trajectory(t, duration_s=T, weights=mu_w)
    return t, q, qd


def check_feasible(kin, t, q, qd, margin: float) -> tuple[str, float]:
    """('', 1) if the sampled trajectory keeps the joint, velocity and acceleration limits (velocity and
    acceleration times ``margin``), else (a reason naming the joint, the value and the limit, the time
    scale that would fix it: a movement slower by s has velocities / s and accelerations / s^2, so
    s = max(velocity ratio, sqrt(acceleration ratio)); inf for a joint-limit violation)."""
    names = kin.joint_names
    low, high = q < kin.q_min, q > kin.q_max
    if low.any() or high.any():
        i, j = (int(v) for v in np.argwhere(low | high)[0])
        return (f"joint limits: {names[j]} reaches {q[i, j]:.3f} rad outside [{kin.q_min[j]:.2f}, "
                f"{kin.q_max[j]:.2f}]"), np.inf
    v_ratio = np.abs(qd) / (margin * kin.qdot_max)
    a_ratio = np.zeros_like(v_ratio[:1])
    if len(t) > 2:
        qdd = np.diff(qd, axis=0) / np.diff(t)[:, None]
        a_ratio = np.abs(qdd) / (margin * kin.qddot_max)
    scale = max(float(v_ratio.max()), float(np.sqrt(a_ratio.max())))
    if scale <= 1.0:
        return "", 1.0
    if v_ratio.max() >= a_ratio.max():
        i, j = np.unravel_index(int(np.argmax(v_ratio)), v_ratio.shape)
        return f"velocity limit: {names[j]} needs {qd[i, j]:.3g} rad/s, limit {margin * kin.qdot_max[j]:.3g}", scale
    i, j = np.unravel_index(int(np.argmax(a_ratio)), a_ratio.shape)
    return f"acceleration limit: {names[j]} needs {qdd[i, j]:.3g} rad/s^2, limit {margin * kin.qddot_max[j]:.3g}", scale
