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
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_feasible", "condition_hit", "sample_mean"]


def condition_hit(promp, *, duration_s, t_rel_now, q_now, qd_now, q_ready, t_rel_hit, x_racket, normal,
                  v_racket, fk6, jac6, jac3):
    """(M1)-(M4): the ProMP conditioned on the present, the end at rest, and the hit. Times are seconds
    from the movement's start; raises ValueError when the hit is out of the primitive's reach."""
    T = float(duration_s)
    p = promp.condition_on_joint(float(t_rel_now), q_now, None, qd_mean=qd_now, duration_s=T)  # (M1)
    p = p.condition_on_joint(T, q_ready, None, qd_mean=np.zeros(promp.n_dims), duration_s=T)  # (M2)
    target = np.concatenate([x_racket, normal])
    p = p.condition_on_task(float(t_rel_hit), target, None, fk6, jac6, duration_s=T)  # (M3)
    q_hit, qd_hit = (a[0] for a in p.mean_trajectory([t_rel_hit], duration_s=T))
    J = jac3(q_hit)
    qd_star = qd_hit + np.linalg.pinv(J) @ (np.asarray(v_racket, float) - J @ qd_hit)  # (M4)
    return p.condition_on_joint(float(t_rel_hit), q_hit, None, qd_mean=qd_star, duration_s=T)


def sample_mean(promp, duration_s, t_rel_from, rate_hz):
    """The conditioned mean from ``t_rel_from`` to the end on the control grid (the end included).

    returns t_rel (N,), q (N, D), qd (N, D)"""
    T = float(duration_s)
    dt = 1.0 / float(rate_hz)
    t = np.arange(float(t_rel_from), T, dt)
    t = np.append(t[t < T - 0.25 * dt], T)
    if t.size < 2:
        t = np.array([max(T - dt, 0.0), T])
    q, qd = promp.mean_trajectory(t, duration_s=T)
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
