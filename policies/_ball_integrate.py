"""Integrator of the ball flight with table-bounce events: a numba kernel and its numpy twin.

Both integrate the state ``[x, y, z, vx, vy, vz, wx, wy, wz]`` (world frame, m, m/s, rad/s) with
classical RK4 on a fixed step ``dt_s`` that is shortened to land exactly on every query time, so
no output is interpolated. A table contact is an event: when the ball centre crosses the plane
``z = surface_z_m + radius_m`` downwards inside the table's x/y extent, the contact time is found
by bisection (re-integrating from the step start, ``N_BISECT`` halvings, i.e. ~1e-15 s), the
bounce map of :func:`policies.ball_model.surface_contact` is applied and the rest of the step is
integrated from the post-bounce state. See docs/ball_physics.md, eqs. (1)-(6).

Private: the public entry points are in :mod:`policies.ball_model`. Inputs are trusted here.
Coefficient layout (``coeffs``, float64 (11,)): ``[g, k_drag, k_magnus, spin_decay, e, mu,
alpha, radius, k_drag_spin * radius, spin_saturation, spin_transfer]``; table layout (``table``, float64 (5,)): ``[surface_z, x_min, x_max, y_min, y_max]``.
"""

from __future__ import annotations

import numba
import numpy as np
from checks.numba_cache import key_cache_on_callees

N_BISECT = 48

# --------------------------------------------------------------------------- numba kernel


@numba.njit(cache=True, fastmath=False)
def _deriv_nb(s, c, out):
    # Eq. (1): a = -g z - (k_d |v| + f k_ds r |w|) v + f k_m (w x v), f = 1 / (1 + S / S_sat),
    # S = r |w| / |v| (saturation of the spin effects); eq. (2): dw/dt = -lambda w.
    vx, vy, vz = s[3], s[4], s[5]
    wx, wy, wz = s[6], s[7], s[8]
    speed = np.sqrt(vx * vx + vy * vy + vz * vz)
    spin = np.sqrt(wx * wx + wy * wy + wz * wz)
    f = 1.0 / (1.0 + c[9] * c[7] * spin / max(speed, 1e-9))
    kd = c[1] * speed + f * c[8] * spin
    km = f * c[2]
    lam = c[3]
    out[0] = vx
    out[1] = vy
    out[2] = vz
    out[3] = -kd * vx + km * (wy * vz - wz * vy)
    out[4] = -kd * vy + km * (wz * vx - wx * vz)
    out[5] = -c[0] - kd * vz + km * (wx * vy - wy * vx)
    out[6] = -lam * wx
    out[7] = -lam * wy
    out[8] = -lam * wz


@numba.njit(cache=True)
def _rk4_nb(s, h, c, out, k1, k2, k3, k4, tmp):
    _deriv_nb(s, c, k1)
    for i in range(9):
        tmp[i] = s[i] + 0.5 * h * k1[i]
    _deriv_nb(tmp, c, k2)
    for i in range(9):
        tmp[i] = s[i] + 0.5 * h * k2[i]
    _deriv_nb(tmp, c, k3)
    for i in range(9):
        tmp[i] = s[i] + h * k3[i]
    _deriv_nb(tmp, c, k4)
    for i in range(9):
        out[i] = s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@numba.njit(cache=True)
def _bounce_nb(s, c):
    # Eqs. (4)-(6) with n = +z and a resting surface: Coulomb impulse, sliding or rolling.
    e, mu, alpha, r = c[4], c[5], c[6], c[7]
    vn = s[5]
    jn = -(1.0 + e) * vn
    cx = s[3] - r * s[7]  # contact-point slip velocity v_t - r (w x n)
    cy = s[4] + r * s[6]
    slip = np.sqrt(cx * cx + cy * cy)
    jt = min(mu * jn, slip * alpha / (1.0 + alpha))
    if slip > 0.0:
        jx = -jt * cx / slip
        jy = -jt * cy / slip
    else:
        jx = 0.0
        jy = 0.0
    s[3] += jx
    s[4] += jy
    s[5] += jn
    # w' = w - kappa (n x J_t) / (alpha r), n x J_t = (-jy, jx, 0)
    s[6] += c[10] * jy / (alpha * r)
    s[7] -= c[10] * jx / (alpha * r)


@numba.njit(cache=True)
def _step_nb(s, h, c, tb, k1, k2, k3, k4, tmp, nxt):
    """Advance ``s`` in place by ``h``; return the contact time within the step or -1."""
    _rk4_nb(s, h, c, nxt, k1, k2, k3, k4, tmp)
    zc = tb[0] + c[7]
    if s[2] - zc >= 0.0 and nxt[2] - zc < 0.0:
        lo = 0.0
        hi = h
        for _ in range(N_BISECT):
            mid = 0.5 * (lo + hi)
            _rk4_nb(s, mid, c, tmp, k1, k2, k3, k4, nxt)
            if tmp[2] - zc >= 0.0:
                lo = mid
            else:
                hi = mid
        _rk4_nb(s, lo, c, nxt, k1, k2, k3, k4, tmp)
        if tb[1] <= nxt[0] <= tb[2] and tb[3] <= nxt[1] <= tb[4] and nxt[5] < 0.0:
            _bounce_nb(nxt, c)
            rest = h - lo
            if rest > 0.0:
                _rk4_nb(nxt, rest, c, s, k1, k2, k3, k4, tmp)
            else:
                for i in range(9):
                    s[i] = nxt[i]
            return lo
        _rk4_nb(s, h, c, nxt, k1, k2, k3, k4, tmp)
    for i in range(9):
        s[i] = nxt[i]
    return -1.0


@numba.njit(cache=True)
def simulate_nb(states, t_query, c, tb, dt):
    """states (N, 9) at t = 0; t_query (M,) ascending >= 0 -> out (N, M, 9), bounces (N, 5)."""
    n = states.shape[0]
    m = t_query.shape[0]
    out = np.empty((n, m, 9))
    bounces = np.full((n, 5), np.nan)  # [t, x, y, z, count] of the first bounce
    k1 = np.empty(9)
    k2 = np.empty(9)
    k3 = np.empty(9)
    k4 = np.empty(9)
    tmp = np.empty(9)
    nxt = np.empty(9)
    s = np.empty(9)
    for b in range(n):
        for i in range(9):
            s[i] = states[b, i]
        t = 0.0
        count = 0
        for q in range(m):
            tq = t_query[q]
            while t < tq:
                h = min(dt, tq - t)
                if tq - (t + h) < 1e-12:
                    h = tq - t
                tc = _step_nb(s, h, c, tb, k1, k2, k3, k4, tmp, nxt)
                if tc >= 0.0:
                    if count == 0:  # nxt holds the post-bounce state at contact
                        bounces[b, 0] = t + tc
                        bounces[b, 1] = nxt[0]
                        bounces[b, 2] = nxt[1]
                        bounces[b, 3] = nxt[2]
                    count += 1
                t = t + h if h < tq - t else tq
            for i in range(9):
                out[b, q, i] = s[i]
        bounces[b, 4] = count
    return out, bounces


# --------------------------------------------------------------------------- numpy reference


def deriv_np(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(N, 9) -> (N, 9) time derivative, eqs. (1)-(2)."""
    v, w = s[:, 3:6], s[:, 6:9]
    speed = np.linalg.norm(v, axis=1, keepdims=True)
    spin = np.linalg.norm(w, axis=1, keepdims=True)
    f = 1.0 / (1.0 + c[9] * c[7] * spin / np.maximum(speed, 1e-9))
    a = -(c[1] * speed + f * c[8] * spin) * v + f * c[2] * np.cross(w, v)
    a[:, 2] -= c[0]
    return np.concatenate([v, a, -c[3] * w], axis=1)


def rk4_np(s: np.ndarray, h, c: np.ndarray) -> np.ndarray:
    """One RK4 step of (N, 9) states by ``h`` (scalar or (N,))."""
    h = np.broadcast_to(np.asarray(h, float), (s.shape[0],))[:, None]
    k1 = deriv_np(s, c)
    k2 = deriv_np(s + 0.5 * h * k1, c)
    k3 = deriv_np(s + 0.5 * h * k2, c)
    k4 = deriv_np(s + h * k3, c)
    return s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def bounce_np(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Table bounce of (N, 9) states, eqs. (4)-(6) with n = +z; returns new states."""
    e, mu, alpha, r = c[4], c[5], c[6], c[7]
    out = s.copy()
    jn = -(1.0 + e) * s[:, 5]
    slip_v = np.stack([s[:, 3] - r * s[:, 7], s[:, 4] + r * s[:, 6]], axis=1)
    slip = np.linalg.norm(slip_v, axis=1)
    jt = np.minimum(mu * jn, slip * alpha / (1.0 + alpha))
    unit = np.divide(slip_v, slip[:, None], out=np.zeros_like(slip_v), where=slip[:, None] > 0)
    j = -jt[:, None] * unit
    out[:, 3:5] += j
    out[:, 5] += jn
    out[:, 6] += c[10] * j[:, 1] / (alpha * r)
    out[:, 7] -= c[10] * j[:, 0] / (alpha * r)
    return out


def step_np(s: np.ndarray, h: float, c: np.ndarray, tb: np.ndarray):
    """Advance (N, 9) states by ``h`` with bounce events.

    Returns (states (N, 9), contact time in the step or -1 (N,), contact position (N, 3), NaN if none).
    """
    nxt = rk4_np(s, h, c)
    zc = tb[0] + c[7]
    tc = np.full(s.shape[0], -1.0)
    pc = np.full((s.shape[0], 3), np.nan)
    cross = (s[:, 2] - zc >= 0.0) & (nxt[:, 2] - zc < 0.0)
    if cross.any():
        s0 = s[cross]
        lo = np.zeros(s0.shape[0])
        hi = np.full(s0.shape[0], float(h))
        for _ in range(N_BISECT):
            mid = 0.5 * (lo + hi)
            above = rk4_np(s0, mid, c)[:, 2] - zc >= 0.0
            lo = np.where(above, mid, lo)
            hi = np.where(above, hi, mid)
        at = rk4_np(s0, lo, c)
        inside = (tb[1] <= at[:, 0]) & (at[:, 0] <= tb[2]) & (tb[3] <= at[:, 1]) & (at[:, 1] <= tb[4]) & (at[:, 5] < 0)
        post = rk4_np(bounce_np(at, c), h - lo, c)
        sub = nxt[cross]
        sub[inside] = post[inside]
        nxt[cross] = sub
        tcs = tc[cross]
        tcs[inside] = lo[inside]
        tc[cross] = tcs
        pcs = pc[cross]
        pcs[inside] = at[inside, :3]
        pc[cross] = pcs
    return nxt, tc, pc


def simulate_np(states: np.ndarray, t_query: np.ndarray, c: np.ndarray, tb: np.ndarray, dt: float):
    """Numpy twin of :func:`simulate_nb` (same grid, same events), vectorised over states."""
    s = np.array(states, float)
    n, m = s.shape[0], t_query.shape[0]
    out = np.empty((n, m, 9))
    bounces = np.full((n, 5), np.nan)
    count = np.zeros(n)
    t = 0.0
    for q in range(m):
        tq = float(t_query[q])
        while t < tq:
            h = min(dt, tq - t)
            if tq - (t + h) < 1e-12:
                h = tq - t
            s, tc, pc = step_np(s, h, c, tb)
            hit = tc >= 0
            first = hit & (count == 0)
            bounces[first, 0] = t + tc[first]
            bounces[first, 1:4] = pc[first]
            count += hit
            t = t + h if h < tq - t else tq
        out[:, q] = s
    bounces[:, 4] = count
    return out, bounces


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
