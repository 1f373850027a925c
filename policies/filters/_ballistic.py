"""Kalman transition of ``ransac_kalman``: ballistic flight with linearised drag, and the table bounce.

State ``x = [p (3), v (3), a (3)]`` (m, m/s, m/s^2), ``a`` the acceleration the model does not
explain (Magnus lift of the unknown spin, drag errors), a random walk. docs/filters.md, sec. 3:

(F1) flight ``dp/dt = v``, ``dv/dt = -g z - c v + a``, ``da/dt = 0`` (+ noise), with the drag
     factor ``c = k_drag |v|`` frozen over a step ("linearised drag"): the step is exact for that
     linear system, ``x' = F x + B u`` with gravity ``u = -g z`` the control input and
     ``F = F_axis (x) I_3``, ``F_axis = [[1, phi1, phi2], [0, e^{-ch}, phi1], [0, 0, 1]]``,
     ``phi1 = (1 - e^{-ch}) / c``, ``phi2 = (h - phi1) / c``;
(F2) process noise ``Q = (q_acc Q_acc + q_jerk Q_jerk) (x) I_3`` (white acceleration on v, white
     jerk on a; the discrete forms of Bar-Shalom et al. 2001, sec. 6.2-6.3);
(F3) bounce: when the mean crosses ``z = surface_z + radius`` downwards with the contact point
     inside the table, the step is split at the crossing (linear in z) and the Coulomb bounce of
     docs/ball_physics.md eqs. (4)-(5) with the spin prior's mean ``w0`` (zero without one) is
     applied to the mean (``v_z' = -e v_z``, friction impulse ``min(mu (1+e) |v_z|, alpha/(1+alpha)
     |s|)`` against the contact slip ``s = v_xy - r (w0 x z)_xy``); the covariance goes through the
     map's Jacobian and is inflated: velocity variance ``(frac |v'| + floor)^2`` per axis, and the
     horizontal unexplained acceleration (lift, whose horizontal part flips with v_z) is reset to its
     prior: mean = the horizontal acceleration ``w0`` causes at the new velocity (eq. 1: Magnus and
     spin drag; 0 without a spin prior), variance ``accel_prior_var``; the vertical one swaps the
     spin part at the old velocity for that at the new one.

A numba kernel (:func:`propagate_nb`) and its plain numpy reference (:func:`propagate_np`), which
agree to rounding (tests/policies/test_filters_kalman.py). Private; inputs are trusted.
Coefficients ``c`` (23,): ``[g, k_drag, e, mu, alpha, z_contact, x_min, x_max, y_min, y_max,
q_acc, q_jerk, bounce_frac, bounce_floor_mps, accel_prior_var, max_step_s, w0x, w0y, w0z, k_magnus,
k_drag_spin r, spin_saturation r, radius]`` (:func:`coefficients`).
"""

from __future__ import annotations

import numba
import numpy as np
from checks.numba_cache import key_cache_on_callees

__all__ = ["N_COEFFS", "coefficients", "propagate_nb", "propagate_np"]

N_COEFFS = 23


def coefficients(params, table, *, q_acc, q_jerk, bounce_frac, bounce_floor_mps, accel_prior_var, max_step_s,
                 spin_rad_s=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(N_COEFFS,) packed coefficients from a ``BallParams``, a ``TableGeometry`` and the filter's noises."""
    p, tb = params, table
    return np.array(
        [p.gravity_mps2, p.k_drag, p.table_restitution, p.table_friction, p.inertia_factor,
         tb.surface_z_m + p.radius_m, tb.x_min_m, tb.x_max_m, tb.y_min_m, tb.y_max_m,
         q_acc, q_jerk, bounce_frac, bounce_floor_mps, accel_prior_var, max_step_s,
         *spin_rad_s, p.k_magnus, p.k_drag_spin * p.radius_m, p.spin_saturation * p.radius_m, p.radius_m], float)


def spin_acceleration_np(v: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(3,) acceleration the spin ``c[16:19]`` adds at velocity v (eq. 1: Magnus lift and spin drag)."""
    w = c[16:19]
    spin = float(np.linalg.norm(w))
    if spin == 0.0:
        return np.zeros(3)
    f = 1.0 / (1.0 + c[21] * spin / max(float(np.linalg.norm(v)), 1e-9))
    return f * c[19] * np.cross(w, v) - f * c[20] * spin * v


# --------------------------------------------------------------------------- numpy reference


def _phi(c: float, h: float) -> tuple[float, float, float]:
    """(e^{-ch}, phi1, phi2) of (F1); series for small ch (no cancellation)."""
    ch = c * h
    if ch < 1e-4:
        return np.exp(-ch), h * (1 - ch / 2 + ch * ch / 6), h * h * (0.5 - ch / 6 + ch * ch / 24)
    e = np.exp(-ch)
    phi1 = (1 - e) / c
    return e, phi1, (h - phi1) / c


def step_np(x: np.ndarray, P: np.ndarray, h: float, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One step of (F1)-(F2): x (9,), P (9, 9) -> x', P'."""
    drag = c[1] * np.linalg.norm(x[3:6])
    e, phi1, phi2 = _phi(drag, h)
    F = np.kron(np.array([[1.0, phi1, phi2], [0.0, e, phi1], [0.0, 0.0, 1.0]]), np.eye(3))  # (F1)
    Bu = np.zeros(9)
    Bu[2], Bu[5] = -c[0] * phi2, -c[0] * phi1  # gravity as control input
    q_acc = c[10] * np.array([[h**3 / 3, h**2 / 2, 0.0], [h**2 / 2, h, 0.0], [0.0, 0.0, 0.0]])
    q_jerk = c[11] * np.array([[h**5 / 20, h**4 / 8, h**3 / 6], [h**4 / 8, h**3 / 3, h**2 / 2],
                               [h**3 / 6, h**2 / 2, h]])
    Q = np.kron(q_acc + q_jerk, np.eye(3))  # (F2)
    return F @ x + Bu, F @ P @ F.T + Q


def bounce_np(x: np.ndarray, P: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F3) at the contact: Coulomb bounce of the mean, its Jacobian and the inflation of P."""
    e, mu, alpha = c[2], c[3], c[4]
    vz = x[5]
    s = x[3:5] + c[22] * np.array([-c[17], c[16]])  # contact slip v_xy - r (w0 x z)_xy
    slip = np.linalg.norm(s)
    jn = -(1.0 + e) * min(vz, 0.0)
    J = np.eye(9)
    J[5, 5] = -e
    J[6, 6] = J[7, 7] = 0.0  # horizontal unexplained acceleration reset to its prior mean
    x_new = x.copy()
    x_new[5] = -e * vz
    if slip > 0.0:
        u = s / slip
        if mu * jn < alpha / (1 + alpha) * slip:  # sliding: impulse mu (1+e)|vz|
            jt = mu * jn
            J[3:5, 3:5] = np.eye(2) - jt / slip * (np.eye(2) - np.outer(u, u))
            J[3:5, 5] = mu * (1.0 + e) * u  # d(-jt u)/dvz, jt = -mu (1+e) vz
        else:  # rolling: v_xy' = v_xy / (1 + alpha)
            jt = alpha / (1 + alpha) * slip
            J[3:5, 3:5] = np.eye(2) / (1 + alpha)
        x_new[3:5] = x[3:5] - jt * u
    a_old, a_new = spin_acceleration_np(x[3:6], c), spin_acceleration_np(x_new[3:6], c)
    x_new[6:8] = a_new[0:2]
    x_new[8] = x[8] - a_old[2] + a_new[2]
    P_new = J @ P @ J.T
    infl = (c[12] * np.abs(x_new[3:6]) + c[13]) ** 2
    P_new[3:6, 3:6] += np.diag(infl)
    P_new[6, 6] += c[14]
    P_new[7, 7] += c[14]
    return x_new, P_new


def _advance_np(x, P, dt, c):
    """Advance by dt >= 0 in steps <= max_step with bounce events; -> x, P, bounces."""
    n_b = 0
    while dt > 0.0:
        h = min(dt, c[15])
        x1, P1 = step_np(x, P, h, c)
        z0, z1 = x[2] - c[5], x1[2] - c[5]
        if z0 > 0.0 and z1 <= 0.0:
            tau = h * z0 / (z0 - z1)
            xc, Pc = step_np(x, P, tau, c)
            if c[6] <= xc[0] <= c[7] and c[8] <= xc[1] <= c[9]:
                xc, Pc = bounce_np(xc, Pc, c)
                n_b += 1
            x1, P1 = step_np(xc, Pc, h - tau, c)
        x, P = x1, P1
        dt -= h
    return x, P, n_b


def propagate_np(x, P, t0, t_query, c):
    """x (9,), P (9, 9) at t0 -> states (M, 9), covariances (M, 9, 9) at sorted t_query (M,), bounces."""
    M = len(t_query)
    X, Ps = np.empty((M, 9)), np.empty((M, 9, 9))
    t, n_b = t0, 0
    for k in range(M):
        x, P, nb = _advance_np(x, P, max(t_query[k] - t, 0.0), c)
        t = max(t, t_query[k])
        n_b += nb
        X[k], Ps[k] = x, P
    return X, Ps, n_b


# --------------------------------------------------------------------------- numba kernel


@numba.njit(cache=True)
def _step_nb(x, P, h, c, xo, Po):
    drag = c[1] * np.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2)
    ch = drag * h
    if ch < 1e-4:
        e = np.exp(-ch)
        phi1 = h * (1 - ch / 2 + ch * ch / 6)
        phi2 = h * h * (0.5 - ch / 6 + ch * ch / 24)
    else:
        e = np.exp(-ch)
        phi1 = (1 - e) / drag
        phi2 = (h - phi1) / drag
    Fa = np.array([[1.0, phi1, phi2], [0.0, e, phi1], [0.0, 0.0, 1.0]])
    Qa = np.empty((3, 3))
    qa, qj = c[10], c[11]
    h2, h3 = h * h, h * h * h
    Qa[0, 0] = qa * h3 / 3 + qj * h2 * h3 / 20
    Qa[0, 1] = Qa[1, 0] = qa * h2 / 2 + qj * h2 * h2 / 8
    Qa[0, 2] = Qa[2, 0] = qj * h3 / 6
    Qa[1, 1] = qa * h + qj * h3 / 3
    Qa[1, 2] = Qa[2, 1] = qj * h2 / 2
    Qa[2, 2] = qj * h
    # (F1) mean, block (F_axis (x) I_3) x + B u
    for d in range(3):
        for i in range(3):
            acc = 0.0
            for k in range(3):
                acc += Fa[i, k] * x[3 * k + d]
            xo[3 * i + d] = acc
    xo[2] -= c[0] * phi2
    xo[5] -= c[0] * phi1
    # P' = F P F^T + Q, blockwise: P'_ij = sum_kl Fa[i,k] Fa[j,l] P_kl (3x3 blocks)
    for i in range(3):
        for j in range(3):
            for a in range(3):
                for b in range(3):
                    acc = 0.0
                    for k in range(3):
                        fik = Fa[i, k]
                        if fik == 0.0:
                            continue
                        for l in range(3):
                            acc += fik * Fa[j, l] * P[3 * k + a, 3 * l + b]
                    Po[3 * i + a, 3 * j + b] = acc + (Qa[i, j] if a == b else 0.0)


@numba.njit(cache=True)
def _spin_acc_nb(vx, vy, vz, c, out):
    wx, wy, wz = c[16], c[17], c[18]
    spin = np.sqrt(wx * wx + wy * wy + wz * wz)
    if spin == 0.0:
        out[0] = out[1] = out[2] = 0.0
        return
    f = 1.0 / (1.0 + c[21] * spin / max(np.sqrt(vx * vx + vy * vy + vz * vz), 1e-9))
    km, kd = f * c[19], f * c[20] * spin
    out[0] = km * (wy * vz - wz * vy) - kd * vx
    out[1] = km * (wz * vx - wx * vz) - kd * vy
    out[2] = km * (wx * vy - wy * vx) - kd * vz


@numba.njit(cache=True)
def _bounce_nb(x, P, c):
    e, mu, alpha = c[2], c[3], c[4]
    vz = x[5]
    a_old = np.empty(3)
    _spin_acc_nb(x[3], x[4], x[5], c, a_old)
    sx, sy = x[3] - c[22] * c[17], x[4] + c[22] * c[16]
    slip = np.sqrt(sx * sx + sy * sy)
    jn = -(1.0 + e) * min(vz, 0.0)
    J = np.eye(9)
    J[5, 5] = -e
    J[6, 6] = 0.0
    J[7, 7] = 0.0
    x[5] = -e * vz
    if slip > 0.0:
        ux, uy = sx / slip, sy / slip
        if mu * jn < alpha / (1 + alpha) * slip:
            jt = mu * jn
            g = jt / slip
            J[3, 3] = 1.0 - g * (1.0 - ux * ux)
            J[4, 4] = 1.0 - g * (1.0 - uy * uy)
            J[3, 4] = J[4, 3] = g * ux * uy
            J[3, 5] = mu * (1.0 + e) * ux
            J[4, 5] = mu * (1.0 + e) * uy
        else:
            jt = alpha / (1 + alpha) * slip
            J[3, 3] = J[4, 4] = 1.0 / (1 + alpha)
        x[3] -= jt * ux
        x[4] -= jt * uy
    a_new = np.empty(3)
    _spin_acc_nb(x[3], x[4], x[5], c, a_new)
    x[6] = a_new[0]
    x[7] = a_new[1]
    x[8] += a_new[2] - a_old[2]
    Pn = J @ P @ J.T
    for i in range(3):
        Pn[3 + i, 3 + i] += (c[12] * abs(x[3 + i]) + c[13]) ** 2
    Pn[6, 6] += c[14]
    Pn[7, 7] += c[14]
    P[:, :] = Pn


@numba.njit(cache=True)
def propagate_nb(x0, P0, t0, t_query, c):
    """Numba twin of :func:`propagate_np`."""
    M = t_query.shape[0]
    X = np.empty((M, 9))
    Ps = np.empty((M, 9, 9))
    x, P = x0.copy(), P0.copy()
    x1, P1 = np.empty(9), np.empty((9, 9))
    xc, Pc = np.empty(9), np.empty((9, 9))
    t = t0
    n_b = 0
    for k in range(M):
        dt = t_query[k] - t
        while dt > 0.0:
            h = min(dt, c[15])
            _step_nb(x, P, h, c, x1, P1)
            z0, z1 = x[2] - c[5], x1[2] - c[5]
            if z0 > 0.0 and z1 <= 0.0:
                tau = h * z0 / (z0 - z1)
                _step_nb(x, P, tau, c, xc, Pc)
                if c[6] <= xc[0] <= c[7] and c[8] <= xc[1] <= c[9]:
                    _bounce_nb(xc, Pc, c)
                    n_b += 1
                _step_nb(xc, Pc, h - tau, c, x1, P1)
            x[:] = x1
            P[:, :] = P1
            dt -= h
        t = max(t, t_query[k])
        X[k] = x
        Ps[k] = P
    return X, Ps, n_b


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
