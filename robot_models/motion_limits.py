"""The motion-safety rule of a commanded joint trajectory: one rule, checked at both ends of the robot link.

``WamClient`` checks it before a trajectory leaves the harness and every bridge checks it again before the
controller sees it (docs/robot_link.md, "Motion safety"). A trajectory the arm cannot follow is refused with
a ValueError naming the sample, the joint, the value and the limit; nothing of it reaches the arm.

The rule, on the part of the trajectory the robot would execute (from the take-over time
``t_on = max(t_s[0], now)``; before ``now`` a trajectory is ignored, at ``t_on`` its position is the linear
interpolation of its samples):

* **velocity**: each segment's ``(q[i+1] - q[i]) / (t[i+1] - t[i])`` within ``qdot_max * (1 + tol)``;
* **acceleration**: the change of that velocity between consecutive segments over the distance of the
  segments' midpoints, and the same of the given ``qdot`` (when given) over each segment, within
  ``qddot_max * (1 + tol)``;
* **jerk**: the change of that acceleration over ``jerk_window_s`` (10 ms, so that a short interval where
  a planner joins two pieces does not divide a rounding error by a millisecond), within the arm's own jerk
  limits where its robot config gives them (``limits.qdddot_max_rad_s3``: ``limits.qdddot_max``), else
  ``qddot_max / jerk_ramp_s`` (the acceleration limit reached from rest in ``jerk_ramp_s``): an acceleration
  step of more than the limit is refused;
* **start**: the position at ``t_on`` within ``start_tol_rad`` of where the arm is driven at ``t_on`` (the
  caller's ``start``: the arm's state now, or the reference it follows at a later ``t_on``), and the first
  segment's velocity within ``qddot_max * start_blend_s`` of the start velocity -- no teleports, no steps;
* **end**: after its last sample the robot holds ``q[-1]``, so the last segment's velocity (and the given
  ``qdot[-1]``) must be one the arm stops from within ``stop_s`` at its acceleration limit;
* **braking**: from every sample, the arm stopped at its acceleration limit stays inside the joint limits
  (``q + v |v| / (2 qddot_max)``): a hold at any moment never drives a joint into its hard stop.

Tolerances (:class:`MotionRule`, defaults from the hitting policy's and the accuracy motion's trajectories,
which plan to 1.00 x the acceleration limit, reach 22 (hitting) and up to ~60 (the accuracy motion's
joins, over 10 ms) x ``qddot_max`` per second of jerk, start within 0.027 rad and 0.02 s x ``qddot_max`` of
the arm, and end at rest): 10 % on velocity and acceleration (finite differences of a curve planned at the
limit), ``jerk_ramp_s`` 0.01 s (100 x ``qddot_max`` per second), ``jerk_window_s`` 0.01 s,
``start_tol_rad`` 0.05 rad, ``start_blend_s`` 0.05 s, ``stop_s`` 0.01 s.

:func:`stop_ramp` is the hold both ends use: from the present state every joint's velocity ramps linearly
to zero together within ``hold_decel_share`` (90 %) of each joint's deceleration limit.

Numpy, and scipy's spline for a trajectory without ``qdot`` (the ROS bridge runs it under a system Python
with python3-scipy). ``limits`` is anything with ``joint_names``,
``q_min``, ``q_max``, ``qdot_max``, ``qddot_max`` and optionally ``qdddot_max`` (:class:`robot_models.ArmKinematics`,
:class:`robot_models.limits.JointLimits`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_RULE", "MotionRule", "check_motion", "state_at", "stop_ramp"]


@dataclass(frozen=True)
class MotionRule:
    """Tolerances of the motion-safety rule (module docstring); times s, angles rad, fractions of a limit."""

    tol: float = 0.10  #: finite-difference velocity and acceleration may exceed the limits by this share
    jerk_ramp_s: float = 0.01  #: jerk limit = qddot_max / jerk_ramp_s
    jerk_window_s: float = 0.01  #: jerk = change of the acceleration over at least this long
    start_tol_rad: float = 0.05  #: the take-over position may be this far from where the arm is driven
    start_blend_s: float = 0.05  #: the first velocity may differ from the arm's by qddot_max x this
    stop_s: float = 0.01  #: the final velocity must stop within this at the acceleration limit
    hold_decel_share: float = 0.9  #: a hold ramps down at this share of the deceleration limit

    def __post_init__(self):
        for name in ("tol", "jerk_ramp_s", "jerk_window_s", "start_tol_rad", "start_blend_s", "stop_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= float(v) <= 10:
                raise ValueError(f"MotionRule.{name} must be a number in [0, 10], got {v!r}")
        if not 0 < float(self.hold_decel_share) <= 1:
            raise ValueError(f"MotionRule.hold_decel_share must be in (0, 1], got {self.hold_decel_share!r}")


DEFAULT_RULE = MotionRule()


def _spline_slopes(t: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """(N, n) velocities at the samples of the not-a-knot cubic spline through ``Q`` (the robot's interpolation
    of a trajectory without ``qdot``: ``robot_models.joint_reference``, the ROS bridge)."""
    if t.shape[0] == 2:
        return np.repeat(np.diff(Q, axis=0) / np.diff(t)[0], 2, 0)
    from scipy.interpolate import CubicSpline

    return CubicSpline(t, Q, axis=0)(t, 1)


def _take_over(t: np.ndarray, now_s: float | None) -> int:
    """The first sample of the executed part: 0 when the trajectory starts at or after ``now_s``, else the
    sample that opens the segment holding ``now_s`` (that segment is checked whole, so that every end of the
    link, whatever its ``now``, checks a tail of the same samples)."""
    if now_s is None or now_s <= t[0]:
        return 0
    return int(min(np.searchsorted(t, now_s, side="right") - 1, t.shape[0] - 2))


def _first_over(values: np.ndarray, limit: np.ndarray):
    """(row, joint) of the first entry with ``|value| > limit`` (rows in time order; row 0 of a vector), or None."""
    over = np.atleast_2d(np.abs(values) > limit)
    if not over.any():
        return None
    i, j = np.argwhere(over)[0]
    return int(i), int(j)


def check_motion(limits, t_s: np.ndarray, q: np.ndarray, qdot: np.ndarray | None = None, *, now_s: float | None = None,
                 start=None, rule: MotionRule = DEFAULT_RULE) -> None:
    """Raise ValueError if the arm cannot follow the trajectory (the rule of the module docstring).

    t_s : (N,) s strictly increasing, q : (N, n) rad, qdot : (N, n) rad/s or None -- already checked for shape,
    finiteness and joint/velocity limits (``check_joint_trajectory``). now_s : robot time now (None: the whole
    trajectory is executed). start : ``(q (n,), qdot (n,))`` where the arm is driven at the take-over time, or
    None to skip the start check. The message names the sample (index into ``t_s``), the joint and the limit.
    """
    names = limits.joint_names
    qd_max = np.asarray(limits.qdot_max, float)
    qdd_max = np.asarray(limits.qddot_max, float)
    own_jerk = getattr(limits, "qdddot_max", None)  # an arm's published jerk limits, else the rule's ramp
    jerk_max = None if not rule.jerk_ramp_s and own_jerk is None else (
        np.asarray(own_jerk, float) if own_jerk is not None else qdd_max / rule.jerk_ramp_s)
    jerk_how = "its limit" if own_jerk is not None else f"its limit (acceleration limit / {rule.jerk_ramp_s:g} s"
    t_all, Q_all = np.asarray(t_s, float), np.asarray(q, float)
    Qd_all = None if qdot is None else np.asarray(qdot, float)
    slopes_all = Qd_all if Qd_all is not None else _spline_slopes(t_all, Q_all)  # the reference's velocity at samples
    base = _take_over(t_all, now_s)
    t, Q, slopes = t_all[base:], Q_all[base:], slopes_all[base:]
    Qd = None if Qd_all is None else Qd_all[base:]
    t_on = t_all[0] if now_s is None else max(float(t_all[0]), float(now_s))
    w = 0.0 if t_on <= t[0] else (t_on - t[0]) / (t[1] - t[0])
    q_on = Q[0] + w * (Q[1] - Q[0])  # where the trajectory takes over, and how fast (linear between samples)
    v_on = slopes[0] + w * (slopes[1] - slopes[0])
    tol = 1.0 + rule.tol
    dt = np.diff(t)

    def fail(sample: int, j: int, what: str, value: float, unit: str, limit: float, how: str) -> None:
        raise ValueError(f"sample {sample}: {names[j]} {what} {value:.4g} {unit} exceeds {how} {limit:.4g} {unit}")

    if start is not None:
        q0, qd0 = (np.asarray(x, float) for x in start)
        gap = np.abs(q_on - q0)
        j = int(np.argmax(gap))
        if gap[j] > rule.start_tol_rad:
            raise ValueError(f"sample {base}: {names[j]} starts {q_on[j] - q0[j]:+.4g} rad from where the arm is "
                             f"({q0[j]:.4g} rad); the limit is {rule.start_tol_rad:g} rad (a trajectory must start at "
                             f"the arm: no teleports)")
    if t.shape[0] < 2:
        return
    v = np.diff(Q, axis=0) / dt[:, None]  # (M, n) segment velocities
    hit = _first_over(v / qd_max, np.full(v.shape[1], tol))
    if hit:
        fail(base + hit[0] + 1, hit[1], "velocity", v[hit], "rad/s", qd_max[hit[1]] * tol,
             f"its limit (x{tol:g} tolerance, finite difference to the previous sample)")
    _check_cubic(names, t, Q, slopes, base, qd_max * tol, qdd_max * tol, jerk_max)
    v_last = v[-1] if Qd is None else Qd[-1]  # the velocity at the last sample
    if start is not None:
        dv = v_on - qd0
        hit = _first_over(dv, qdd_max * rule.start_blend_s)
        if hit:
            j = hit[1]
            raise ValueError(f"sample {base}: {names[j]} starts at {v_on[j]:.4g} rad/s while the arm moves at "
                             f"{qd0[j]:.4g} rad/s; the step exceeds {qdd_max[j] * rule.start_blend_s:.4g} rad/s "
                             f"(its acceleration limit over {rule.start_blend_s:g} s): no velocity steps")
    tm = 0.5 * (t[1:] + t[:-1])
    if v.shape[0] >= 2:
        a = np.diff(v, axis=0) / np.diff(tm)[:, None]
        hit = _first_over(a / qdd_max, np.full(a.shape[1], tol))
        if hit:
            fail(base + hit[0] + 1, hit[1], "acceleration", a[hit], "rad/s^2", qdd_max[hit[1]] * tol,
                 f"its limit (x{tol:g} tolerance, finite difference of the neighbouring samples)")
        if a.shape[0] >= 2 and jerk_max is not None:
            ta = t[1:-1]  # the stamps of the accelerations
            later = np.searchsorted(ta, ta + rule.jerk_window_s - 1e-9)  # the first stamp a window later
            i = np.flatnonzero(later < ta.shape[0])
            jerk = (a[later[i]] - a[i]) / (ta[later[i]] - ta[i])[:, None]
            hit = _first_over(jerk, jerk_max)
            if hit:
                how = f"{jerk_how}, over {rule.jerk_window_s:g} s" + (")" if own_jerk is None else "")
                fail(base + int(i[hit[0]]) + 1, hit[1], "jerk", jerk[hit], "rad/s^3", jerk_max[hit[1]], how)
    if Qd is not None:
        ad = np.diff(Qd, axis=0) / dt[:, None]
        hit = _first_over(ad / qdd_max, np.full(ad.shape[1], tol))
        if hit:
            fail(base + hit[0] + 1, hit[1], "acceleration of the given qdot", ad[hit], "rad/s^2",
                 qdd_max[hit[1]] * tol, f"its limit (x{tol:g} tolerance)")
    v_end = np.abs(v_last)
    hit = _first_over(v_end, qdd_max * rule.stop_s)
    if hit:
        j = hit[1]
        raise ValueError(f"sample {base + t.shape[0] - 1}: {names[j]} ends moving at {v_end[j]:.4g} rad/s, but the "
                         f"robot holds the last sample: a trajectory must end at rest (at most "
                         f"{qdd_max[j] * rule.stop_s:.4g} rad/s, its acceleration limit over {rule.stop_s:g} s)")
    vel = np.vstack([v[:1], v]) if Qd is None else Qd  # at each sample
    stop = Q + vel * np.abs(vel) / (2.0 * qdd_max)
    q_min, q_max = np.asarray(limits.q_min, float), np.asarray(limits.q_max, float)
    out = (stop > q_max + 1e-9) | (stop < q_min - 1e-9)
    if out.any():
        i, j = (int(x) for x in np.argwhere(out)[0])
        bound = q_max[j] if stop[i, j] > q_max[j] else q_min[j]
        raise ValueError(f"sample {base + i}: {names[j]} at {Q[i, j]:.4g} rad moving {vel[i, j]:.4g} rad/s cannot "
                         f"stop before its limit {bound:g} rad at its acceleration limit {qdd_max[j]:g} rad/s^2 "
                         f"(it would stop at {stop[i, j]:.4g} rad)")


def _check_cubic(names, t, Q, Qd, base, v_lim, a_lim, j_lim) -> None:
    """The cubic the robot interpolates between samples (a Hermite through the velocities ``Qd`` at the samples:
    the given qdot, else the spline's slopes): per segment its accelerations at both ends (the extremes: it is
    linear in between), its velocity extremum and its jerk (constant) within the limits."""
    h = np.diff(t)[:, None]
    d = np.diff(Q, axis=0) / h
    v0, v1 = Qd[:-1], Qd[1:]
    a0 = (6 * d - 4 * v0 - 2 * v1) / h
    a1 = (-6 * d + 2 * v0 + 4 * v1) / h
    a = np.where(np.abs(a0) >= np.abs(a1), a0, a1)
    hit = _first_over(a / a_lim, np.ones(a.shape[1]))
    if hit:
        i, j = hit
        raise ValueError(f"samples {base + i}..{base + i + 1}: {names[j]} acceleration {a[i, j]:.4g} rad/s^2 of the "
                         f"interpolated reference exceeds its limit {a_lim[j]:.4g} rad/s^2 (with tolerance)")
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = (a0 * a1 < 0)
        v_peak = np.where(inside, v0 - a0 * a0 * h / (2 * (a1 - a0)), 0.0)
    hit = _first_over(v_peak / v_lim, np.ones(a.shape[1]))
    if hit:
        i, j = hit
        raise ValueError(f"samples {base + i}..{base + i + 1}: {names[j]} velocity {v_peak[i, j]:.4g} rad/s of the "
                         f"interpolated reference exceeds its limit {v_lim[j]:.4g} rad/s (with tolerance)")
    if j_lim is not None:
        jerk = (a1 - a0) / h
        hit = _first_over(jerk / j_lim, np.ones(a.shape[1]))
        if hit:
            i, j = hit
            raise ValueError(f"samples {base + i}..{base + i + 1}: {names[j]} jerk {jerk[i, j]:.4g} rad/s^3 of the "
                             f"interpolated reference exceeds its limit {j_lim[j]:.4g} rad/s^3")


def stop_ramp(limits, t_now_s: float, q: np.ndarray, qdot: np.ndarray, dt_s: float,
              rule: MotionRule = DEFAULT_RULE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The hold trajectory from state ``(q, qdot)`` at ``t_now_s``: every joint's velocity ramps linearly to zero
    over one common time ``T = max_j |qdot_j| / (hold_decel_share * qddot_max_j)`` (at least 2 samples),
    sampled every ``dt_s``; positions clipped into the joint limits. Returns ``t_s (N,), q (N, n), qdot (N, n)``."""
    q, qdot = np.asarray(q, float), np.asarray(qdot, float)
    decel = rule.hold_decel_share * np.asarray(limits.qddot_max, float)
    T = float(np.max(np.abs(qdot) / decel))
    n = max(int(np.ceil(T / dt_s)), 1)
    T = n * dt_s
    tau = np.arange(n + 1) * dt_s
    vel = qdot[None, :] * (1.0 - tau[:, None] / T)
    pos = q[None, :] + qdot[None, :] * (tau[:, None] - tau[:, None] ** 2 / (2 * T))
    pos = np.clip(pos, np.asarray(limits.q_min, float), np.asarray(limits.q_max, float))
    return t_now_s + tau, pos, vel


def state_at(t_s: np.ndarray, q: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Where a trajectory ``t_s (N,), q (N, n)`` drives the arm at time ``t``: ``(q (n,), qdot (n,))`` by linear
    interpolation and the velocity of the segment holding ``t``; after the end ``(q[-1], 0)`` (the robot holds
    it), before the start ``(q[0], 0)``."""
    t_s, q = np.asarray(t_s, float), np.asarray(q, float)
    if t >= t_s[-1]:
        return q[-1].copy(), np.zeros(q.shape[1])
    if t <= t_s[0]:
        return q[0].copy(), np.zeros(q.shape[1])
    k = int(np.searchsorted(t_s, t, side="right"))
    v = (q[k] - q[k - 1]) / (t_s[k] - t_s[k - 1])
    return q[k - 1] + v * (t - t_s[k - 1]), v
