"""Per-tick joint tracking of the simulated WAM: numba kernel and its plain numpy reference.

Each joint is a closed loop with natural frequency ``omega`` (rad/s) and damping ``zeta`` around the
reference, with feedforward of the reference acceleration scaled by ``k_ff`` (1 = perfect inverse
dynamics), saturated in acceleration and velocity, held constant over the tick (exact integration of
a constant acceleration) and stopped at the joint limits (hard stops). Tick k goes from t_{k-1} to t_k
with the state and reference at t_{k-1}::

    a     = clip(k_ff qdd_ref + omega^2 (q_ref - q) + 2 zeta omega (qd_ref - qd), +-qdd_max)
    qd'   = clip(qd + a dt, +-qd_max)
    q    <- q + (qd + qd') dt / 2;  qd <- qd';  at a limit: q = limit, qd = 0

The loop is sequential in time, so it is compiled with numba; the numpy twin loops over ticks with
the joints vectorised and is the reference the tests compare against.
"""

from __future__ import annotations

import numba
import numpy as np
from checks.numba_cache import key_cache_on_callees

__all__ = ["TRACKERS", "track_numba", "track_numpy"]


def track_numpy(q0, qd0, q_ref, qd_ref, qdd_ref, omega, zeta, k_ff, qd_max, qdd_max, q_min, q_max, dt):
    """Track a block of ticks.

    q0, qd0 : (7,) state before the block; q_ref, qd_ref, qdd_ref : (n, 7) reference at the start of each tick;
    omega, zeta, qd_max, qdd_max, q_min, q_max : (7,); k_ff, dt : float.
    Returns ``q (n, 7), qd (n, 7), saturated (7,) int`` (ticks with acceleration or velocity saturation).
    """
    n = q_ref.shape[0]
    q_out = np.empty((n, q0.shape[0]))
    qd_out = np.empty_like(q_out)
    sat = np.zeros(q0.shape[0], dtype=np.int64)
    q, qd = q0.copy(), qd0.copy()
    for k in range(n):
        a = k_ff * qdd_ref[k] + omega * omega * (q_ref[k] - q) + 2.0 * zeta * omega * (qd_ref[k] - qd)
        a_sat = np.clip(a, -qdd_max, qdd_max)
        qd_free = qd + a_sat * dt
        qd_new = np.clip(qd_free, -qd_max, qd_max)
        sat += (a_sat != a) | (qd_new != qd_free)
        q = q + 0.5 * (qd + qd_new) * dt
        qd = qd_new
        stop = (q < q_min) | (q > q_max)
        q = np.clip(q, q_min, q_max)
        qd = np.where(stop, 0.0, qd)
        q_out[k] = q
        qd_out[k] = qd
    return q_out, qd_out, sat


@numba.njit(cache=True)
def track_numba(q0, qd0, q_ref, qd_ref, qdd_ref, omega, zeta, k_ff, qd_max, qdd_max, q_min, q_max, dt):
    """Compiled twin of :func:`track_numpy` (same arguments, same results)."""
    n, m = q_ref.shape
    q_out = np.empty((n, m))
    qd_out = np.empty((n, m))
    sat = np.zeros(m, dtype=np.int64)
    q = q0.copy()
    qd = qd0.copy()
    for k in range(n):
        for j in range(m):
            a = k_ff * qdd_ref[k, j] + omega[j] * omega[j] * (q_ref[k, j] - q[j]) \
                + 2.0 * zeta * omega[j] * (qd_ref[k, j] - qd[j])
            saturated = False
            if a > qdd_max[j]:
                a = qdd_max[j]
                saturated = True
            elif a < -qdd_max[j]:
                a = -qdd_max[j]
                saturated = True
            v = qd[j] + a * dt
            if v > qd_max[j]:
                v = qd_max[j]
                saturated = True
            elif v < -qd_max[j]:
                v = -qd_max[j]
                saturated = True
            if saturated:
                sat[j] += 1
            p = q[j] + 0.5 * (qd[j] + v) * dt
            if p < q_min[j]:
                p = q_min[j]
                v = 0.0
            elif p > q_max[j]:
                p = q_max[j]
                v = 0.0
            q[j] = p
            qd[j] = v
            q_out[k, j] = p
            qd_out[k, j] = v
    return q_out, qd_out, sat


#: ``backend=`` choices of :class:`harness.sim.robot.SimulatedWam`.
TRACKERS = {"numba": track_numba, "numpy": track_numpy}


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
