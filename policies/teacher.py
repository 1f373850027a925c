"""A scripted teacher: varied table-tennis hitting movements of an arm (the WAM by default) for varied hitting points.

It stands in for the human who, in Gomez-Gonzalez et al. 2020 (Sec. VI), moved the robot by hand
to teach hitting movements. One demonstration, for a requested hitting point ``x_hit`` (3,) m,
hitting time ``t_hit_s``, racket normal ``n`` (3,) and racket velocity ``v`` (3,) m/s (lab world):

1. Hitting posture q_hit: damped-least-squares IK (``robot_models``) of the racket frame at x_hit
   with its z axis along n, by continuation from the robot's home (ready) posture (the IK target
   moves from the home racket pose to the requested one in ``ik_steps`` steps), so that every
   demonstration uses the same arm configuration "style", as one teacher would. Then
   (``posture_refine_iters``) the posture moves within the null space of that task towards less
   time-weighted joint travel from rest, sum_j (q_j - q_rest_j)^2 / qddot_max_j, keeping away from the
   joint limits: the teacher swings with the fast distal joints rather than the slow shoulder. Human
   variability: a random null-space offset of the posture (std ``null_space_std_rad``), then IK again.
2. Hitting joint velocity qd_hit = J_v^+ v, the least-norm joint velocity giving the racket centre v.
3. How the racket gets from rest to the hit (``swing``, a key of ``SWINGS``):
   ``"direct"`` (default, fast strokes of 0.4-0.6 s for the playing sessions): one cubic Hermite segment
   rest -> hit; the teacher adds to qd_hit the null-space joint velocity (racket velocity and normal
   unchanged) that minimises the segment's start and end accelerations weighted by 1 / qddot_max
   (swing-through); a joint that must arrive fast swings back by itself. The back-swing knot is the
   cubic's own state ``backswing_frac`` t_hit before the hit (the curve is unchanged).
   ``"backswing"`` (the original teacher, slower): five knots as below.
   Either way: five knots joined by cubic Hermite segments (positions and velocities given at each knot):
   rest (qd = 0) -> back-swing (qd = 0) -> hit (q_hit, qd_hit) -> follow-through (qd = 0) -> rest
   (qd = 0). The back-swing posture is q_hit - qd_hit h_b / 2 and the follow-through posture
   q_hit + qd_hit h_f / 2 (clipped into the joint limits), which makes the swing segments of
   duration h_b and h_f constant joint accelerations (+-qd_hit / h). The teacher's habits are
   h_b = ``backswing_frac`` t_hit, h_f = ``follow_frac`` t_hit and a return to rest in
   ``return_frac`` t_hit (so the hit falls at a similar phase in every demonstration), each
   jittered by ``timing_jitter``. Every segment is checked against the WAM's joint, velocity and
   acceleration limits (times ``limit_margin``) on a grid of candidate durations at once: h_b is
   the feasible one nearest the habit (the preparation rest -> back-swing gets t_hit - h_b),
   follow-through and return are the shortest feasible ones at least as long as the habit.
4. Rest postures jittered by ``rest_std_rad``; recorded at ``rate_hz`` with encoder noise.

An unreachable point (IK fails), a swing leaving the joint limits, or one that cannot meet the
velocity/acceleration limits in the time available raises ValueError saying which.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from checks.arrays import check_array, check_positive

__all__ = ["Demonstration", "ScriptedTeacher", "TeacherOptions", "racket_fk_jacobian", "racket_kinematics"]

SWING_NAMES = ("backswing", "direct")  #: the keys of SWINGS (defined with the swings, below)


def racket_fk_jacobian(kin, *, with_normal: bool = True, frame: str = "racket"):
    """One callable q (7,) -> (x, J) of the racket from one kinematics evaluation: x (3,) racket centre in the
    lab world, m, or (6,) [centre; normal] with ``with_normal``; J (3, 7) or (6, 7), the normal's rows
    d z / dq = -[z]x J_w. Uses the trusted inner call (no joint-limit check), since a conditioned mean may
    graze a limit."""
    fid = kin.frame_id(frame)

    def fk_jacobian(q):
        T, J = kin.fk_and_jacobian(np.asarray(q, float), fid)
        if not with_normal:
            return T[:3, 3].copy(), J[:3].copy()
        z = T[:3, 2]
        skew = np.array([[0, -z[2], z[1]], [z[2], 0, -z[0]], [-z[1], z[0], 0]])
        return np.concatenate([T[:3, 3], z]), np.vstack([J[:3], -skew @ J[3:]])

    return fk_jacobian


def racket_kinematics(kin, *, with_normal: bool = False, frame: str = "racket"):
    """``(fk, jacobian)`` callables of the racket for :meth:`ProMP.condition_on_task` (the two halves of
    :func:`racket_fk_jacobian`).

    fk(q (7,)) -> (3,) racket centre in the lab world, m (or (6,) [centre; normal] with ``with_normal``)
    jacobian(q) -> (3, 7) (or (6, 7)); the normal's rows are d z / dq = -[z]x J_w.
    """
    both = racket_fk_jacobian(kin, with_normal=with_normal, frame=frame)
    return (lambda q: both(q)[0]), (lambda q: both(q)[1])


@dataclass(frozen=True)
class TeacherOptions:
    """How the scripted teacher moves. Times s, angles rad, lengths m (lab world)."""

    rate_hz: float = 200.0  #: sampling rate of a recorded demonstration
    backswing_frac: float = 0.45  #: back-swing -> hit segment, fraction of t_hit (rest -> back-swing: the rest)
    follow_frac: float = 0.35  #: hit -> end of follow-through, fraction of t_hit
    return_frac: float = 1.2  #: follow-through -> rest, fraction of t_hit
    timing_jitter: float = 0.05  #: relative std of the three fractions above (human variability)
    min_prepare_s: float = 0.1  #: rest -> back-swing takes at least this long
    null_space_std_rad: float = 0.05  #: random null-space offset of the hitting posture
    rest_std_rad: float = 0.02  #: jitter of the start and end rest postures
    encoder_noise_rad: float = 5e-4  #: white noise on the recorded joint angles
    limit_margin: float = 0.95  #: fraction of the WAM's velocity and acceleration limits the teacher uses
    ik_steps: int = 6  #: continuation steps from the reference (home) posture to the target
    swing: str = "direct"  #: how the racket gets from rest to the hit, a key of SWINGS ("direct" or "backswing")
    posture_refine_iters: int = 30  #: null-space steps towards less time-weighted joint travel from rest (0: off)

    def __post_init__(self):
        for name in ("rate_hz", "backswing_frac", "follow_frac", "return_frac", "min_prepare_s", "limit_margin"):
            check_positive(getattr(self, name), f"TeacherOptions.{name}")
        for name in ("timing_jitter", "null_space_std_rad", "rest_std_rad", "encoder_noise_rad"):
            check_positive(getattr(self, name), f"TeacherOptions.{name}", allow_zero=True)
        if not self.backswing_frac < 1.0 or not self.limit_margin <= 1.0:
            raise ValueError(f"TeacherOptions needs backswing_frac < 1 and limit_margin <= 1, got "
                             f"{self.backswing_frac}, {self.limit_margin}")
        if isinstance(self.ik_steps, bool) or not isinstance(self.ik_steps, int) or self.ik_steps < 1:
            raise ValueError(f"TeacherOptions.ik_steps must be a positive integer, got {self.ik_steps!r}")
        if self.swing not in SWING_NAMES:
            raise ValueError(f"unknown TeacherOptions.swing {self.swing!r}; valid: {sorted(SWING_NAMES)}")
        n = self.posture_refine_iters
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ValueError(f"TeacherOptions.posture_refine_iters must be a non-negative integer, got {n!r}")


@dataclass(frozen=True)
class Demonstration:
    """One recorded hitting movement.

    t_s : (n,) s from the start (t_hit_s is one of them); q, qd : (n, 7) recorded joint angles (rad,
    with encoder noise) and the noise-free velocities (rad/s); the request (x_hit_m, t_hit_s,
    normal, v_hit_m_s); q_hit (7,) and qd_hit (7,) the noise-free hitting state; knots_s (5,) the
    segment boundaries (rest, back-swing, hit, follow-through, rest).
    """

    t_s: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    x_hit_m: np.ndarray
    t_hit_s: float
    normal: np.ndarray
    v_hit_m_s: np.ndarray
    q_hit: np.ndarray
    qd_hit: np.ndarray
    knots_s: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    @property
    def hit_phase(self) -> float:
        return self.t_hit_s / self.duration_s


class ScriptedTeacher:
    """Produces :class:`Demonstration` s for requested hits. ``kin``: a ``robot_models`` WamKinematics
    (default: the lab's WAM). Its arm style is anchored at ``kin.q_home``."""

    def __init__(self, kin=None, options: TeacherOptions = TeacherOptions()):
        if kin is None:
            from robot_models.kinematics import WamKinematics

            kin = WamKinematics.default()
        if not isinstance(options, TeacherOptions):
            raise ValueError(f"options must be TeacherOptions, got {type(options).__name__}")
        self.kin = kin
        self.options = options
        self.robot_id = str(kin.model.name)
        self.joint_names = tuple(kin.joint_names)
        self._fid = kin.frame_id("racket")
        from robot_models.ik import IkOptions

        self._ik_step = IkOptions(restarts=0, max_iters=100)
        # The teacher's arm style is anchored at the robot's home (ready) posture: IK continues from it.
        self.q_ref = np.array(kin.q_home, dtype=float)
        T_ref, _ = kin.fk_and_jacobian(self.q_ref, self._fid)
        self._x_ref, self._n_ref = T_ref[:3, 3].copy(), T_ref[:3, 2].copy()

    # ---------------------------------------------------------------- hitting state
    def _ik(self, x, n, q0):
        q, info = self.kin.ik(x, "racket", normal_world=n, q0=q0, options=self._ik_step, seed=0)
        return q, info

    def hitting_posture(self, x_hit_m, normal, rng: np.random.Generator | None = None) -> np.ndarray:
        """(7,) joint angles putting the racket at ``x_hit_m`` with normal ``normal``, in the teacher's
        arm style; with ``rng`` a random null-space offset is added (human variability)."""
        x_hit = check_array(x_hit_m, "x_hit_m", (3,), finite=True)
        n = check_array(normal, "normal", (3,), finite=True)
        if np.linalg.norm(n) < 1e-9:
            raise ValueError(f"normal must be non-zero, got {n.tolist()}")
        n = n / np.linalg.norm(n)
        q = self.q_ref
        for s in np.linspace(0.0, 1.0, self.options.ik_steps + 1)[1:]:  # continuation from the reference
            ns = (1 - s) * self._n_ref + s * n
            q, info = self._ik(self._x_ref + s * (x_hit - self._x_ref), ns / np.linalg.norm(ns), q)
        if info.success and self.options.posture_refine_iters > 0:
            q = self._refine_posture(q, x_hit, n)
        if rng is not None and self.options.null_space_std_rad > 0:
            A = self._task_jacobian(q)
            null = np.eye(self.kin.n_joints) - np.linalg.pinv(A) @ A
            q_pert = q + null @ rng.normal(0.0, self.options.null_space_std_rad, self.kin.n_joints)
            q2, info2 = self._ik(x_hit, n, np.clip(q_pert, self.kin.q_min, self.kin.q_max))
            if info2.success:
                q, info = q2, info2
        if not info.success:
            raise ValueError(f"hitting point {x_hit.round(3).tolist()} m with normal {n.round(3).tolist()} is "
                             f"unreachable for the teacher's arm style (IK error {info.pos_err_m:.3g} m, "
                             f"{np.degrees(info.angle_err_rad):.2g} deg)")
        return q

    def _posture_cost(self, q) -> tuple[float, np.ndarray]:
        """Time-weighted joint travel from the rest posture, sum_j (q_j - q_rest_j)^2 / qddot_max_j (the
        squared rest-to-rest time of each joint, up to a factor), plus a quadratic penalty within
        ``_REFINE_LIMIT_ZONE_RAD`` of a joint limit; returns (cost, gradient (7,))."""
        kin = self.kin
        d = q - self.q_ref
        cost, grad = float(np.sum(d**2 / kin.qddot_max)), 2.0 * d / kin.qddot_max
        for dist, sign in ((q - kin.q_min, 1.0), (kin.q_max - q, -1.0)):
            inside = np.clip(_REFINE_LIMIT_ZONE_RAD - dist, 0.0, None) / _REFINE_LIMIT_ZONE_RAD
            cost += _REFINE_LIMIT_WEIGHT * float(np.sum(inside**2))
            grad -= sign * 2.0 * _REFINE_LIMIT_WEIGHT * inside / _REFINE_LIMIT_ZONE_RAD
        return cost, grad

    def _refine_posture(self, q, x_hit, n):
        """Move the hitting posture within the null space of the racket task (position and normal kept)
        towards less time-weighted travel from rest (:meth:`_posture_cost`): the teacher swings with the
        fast distal joints rather than the slow shoulder. Projected gradient steps of at most
        ``_REFINE_STEP_RAD``, each followed by IK to remove the drift; stops when the cost stops falling."""
        cost, grad = self._posture_cost(q)
        for _ in range(self.options.posture_refine_iters):
            A = self._task_jacobian(q)
            step = -(np.eye(self.kin.n_joints) - np.linalg.pinv(A) @ A) @ grad
            size = float(np.abs(step).max())
            if size < 1e-9:
                break
            q_try = np.clip(q + step * min(1.0, _REFINE_STEP_RAD / size), self.kin.q_min, self.kin.q_max)
            q_try, info = self._ik(x_hit, n, q_try)
            if not info.success:
                break
            cost_try, grad_try = self._posture_cost(q_try)
            if cost_try >= cost:
                break
            q, cost, grad = q_try, cost_try, grad_try
        return q

    def _task_jacobian(self, q):
        """(5, 7): racket position rows and the two rotations that tilt the normal (turning about
        the normal itself is free)."""
        T, J = self.kin.fk_and_jacobian(q, self._fid)
        tilt_axes = T[:3, :2].T  # racket x and y axes, both perpendicular to the normal z
        return np.vstack([J[:3], tilt_axes @ J[3:]])

    def hitting_velocity(self, q_hit, v_hit_m_s) -> np.ndarray:
        """(7,) least-norm joint velocity giving the racket centre the velocity ``v_hit_m_s``: J_v^+ v.
        (The racket may turn while it hits; in the ~1 ms of contact that changes its normal negligibly.)"""
        _, J = self.kin.fk_and_jacobian(np.asarray(q_hit, float), self._fid)
        return np.linalg.pinv(J[:3]) @ check_array(v_hit_m_s, "v_hit_m_s", (3,), finite=True)

    # ---------------------------------------------------------------- the movement
    def demonstrate(self, x_hit_m, t_hit_s: float, normal, v_hit_m_s, rng: np.random.Generator) -> Demonstration:
        """One hitting movement (see the module docstring); ``rng`` draws the human variability."""
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        opt, kin = self.options, self.kin
        t_hit = check_positive(t_hit_s, "t_hit_s")
        v_hit = check_array(v_hit_m_s, "v_hit_m_s", (3,), finite=True)
        where = f"hitting point {np.round(np.asarray(x_hit_m, float), 3).tolist()} m"
        q_hit = self.hitting_posture(x_hit_m, normal, rng)
        qd_hit = self.hitting_velocity(q_hit, v_hit)
        vmax, amax = opt.limit_margin * kin.qdot_max, opt.limit_margin * kin.qddot_max
        if (np.abs(qd_hit) > vmax).any():
            j = int(np.argmax(np.abs(qd_hit) / vmax))
            raise ValueError(f"{where}: racket velocity {v_hit.round(2).tolist()} m/s needs {kin.joint_names[j]} at "
                             f"{qd_hit[j]:.3g} rad/s, above its limit {vmax[j]:.3g} rad/s")
        jitter = np.clip(1.0 + opt.timing_jitter * rng.standard_normal(3), 0.5, 1.5)
        q_rest0 = kin.q_home + rng.normal(0.0, opt.rest_std_rad, kin.n_joints)
        q_rest1 = kin.q_home + rng.normal(0.0, opt.rest_std_rad, kin.n_joints)
        low, high = kin.q_min + _LIMIT_PAD_RAD, kin.q_max - _LIMIT_PAD_RAD
        zero = np.zeros(kin.n_joints)
        swing = SWINGS[opt.swing]
        h_b, q_back, qd_back, qd_hit = swing(self, q_rest0, q_hit, qd_hit, t_hit, opt.backswing_frac * jitter[0] * t_hit,
                                             vmax, amax, where, v_hit)
        # follow-through (constant deceleration, clipped) and return to rest: nominal length, longer if needed
        h_f = opt.follow_frac * jitter[1] * t_hit * np.geomspace(1.0, 8.0, 40)
        q_follow = np.clip(q_hit + 0.5 * h_f[:, None] * qd_hit, low, high)
        ok = _segment_ok(q_hit, qd_hit, q_follow, zero, h_f, vmax, amax, kin.q_min, kin.q_max)
        if not ok.any():
            raise ValueError(f"{where}: no follow-through stops from {v_hit.round(2).tolist()} m/s within the limits")
        i = int(np.argmax(ok))
        h_f, q_follow = float(h_f[i]), q_follow[i]
        h_r = opt.return_frac * jitter[2] * t_hit * np.geomspace(1.0, 20.0, 60)
        ok = _segment_ok(q_follow, zero, q_rest1, zero, h_r, vmax, amax, kin.q_min, kin.q_max)
        if not ok.any():
            raise ValueError(f"{where}: no return to rest from the follow-through stays within the limits")
        h_r = float(h_r[np.argmax(ok)])
        knots = np.cumsum([0.0, t_hit - h_b, h_b, h_f, h_r])
        Q = np.array([q_rest0, q_back, q_hit, q_follow, q_rest1])
        QD = np.zeros_like(Q)
        QD[1], QD[2] = qd_back, qd_hit
        spline = CubicHermiteSpline(knots, Q, QD)
        dt = 1.0 / opt.rate_hz
        grid = np.arange(0.0, knots[-1], dt)
        grid = grid[np.abs(grid - t_hit) > 0.25 * dt]
        t = np.union1d(np.append(grid, knots[-1]), [t_hit])
        q, qd = spline(t), spline(t, 1)
        if not kin.within_limits(q, tol_rad=1e-6).all():
            raise ValueError(f"{where}: the swing passes outside the joint limits")
        q_rec = q + opt.encoder_noise_rad * rng.standard_normal(q.shape)
        n = np.asarray(normal, float)
        return Demonstration(t, q_rec, qd, np.asarray(x_hit_m, float), t_hit, n / np.linalg.norm(n), v_hit,
                             q_hit, qd_hit, knots)


_LIMIT_PAD_RAD = 0.02  # knots stay this far inside the joint limits
_REFINE_STEP_RAD = 0.03  # largest joint step of one posture-refinement iteration
_REFINE_LIMIT_ZONE_RAD = 0.5  # posture refinement keeps joints out of this zone next to their limits ...
_REFINE_LIMIT_WEIGHT = 0.2  # ... with a penalty this large at the limit (cost units: rad^2 / (rad/s^2))


def _swing_backswing(teacher, q_rest, q_hit, qd_hit, t_hit, h_habit, vmax, amax, where, v_hit):
    """Rest -> back-swing (at rest) -> hit. The back-swing posture is q_hit - qd_hit h_b / 2 (constant
    acceleration into the hit), clipped into the limits. Among the back-swing durations h_b for which both
    the preparation (rest -> back-swing, in t_hit - h_b) and the swing stay within the velocity/acceleration
    limits, take the one nearest the teacher's habit ``h_habit``. Returns (h_b, q_back, qd_back = 0, qd_hit)."""
    opt, kin = teacher.options, teacher.kin
    low, high = kin.q_min + _LIMIT_PAD_RAD, kin.q_max - _LIMIT_PAD_RAD
    zero = np.zeros(kin.n_joints)
    if t_hit - opt.min_prepare_s <= 0.05 * t_hit:
        raise ValueError(f"{where}: hitting time {t_hit:.3g} s is too short: it leaves no time to prepare "
                         f"(min_prepare_s = {opt.min_prepare_s:g} s)")
    h_b = np.linspace(0.05 * t_hit, t_hit - opt.min_prepare_s, 80)
    q_back = np.clip(q_hit - 0.5 * h_b[:, None] * qd_hit, low, high)
    ok = (_segment_ok(q_back, zero, q_hit, qd_hit, h_b, vmax, amax, kin.q_min, kin.q_max)
          & _segment_ok(q_rest, zero, q_back, zero, t_hit - h_b, vmax, amax, kin.q_min, kin.q_max))
    if not ok.any():
        raise ValueError(f"{where}: hitting time {t_hit:.3g} s is too short to swing from rest to "
                         f"{v_hit.round(2).tolist()} m/s within the WAM's velocity and acceleration limits")
    i = int(np.argmin(np.where(ok, np.abs(h_b - h_habit), np.inf)))
    return float(h_b[i]), q_back[i], zero, qd_hit


def _swing_direct(teacher, q_rest, q_hit, qd_hit, t_hit, h_habit, vmax, amax, where, v_hit):
    """Rest -> hit in one cubic Hermite segment (no stop at a back-swing posture: a joint that must arrive
    fast swings back by itself, as the cubic's start acceleration turns negative). Swing-through habit: the
    teacher adds to qd_hit the joint velocity in the null space of the racket task (racket velocity and
    normal unchanged) that minimises the segment's squared start and end accelerations, each joint weighted
    by 1 / qddot_max (a cubic from rest has a(0) = 6 d / T^2 - 2 qd / T and a(T) = -6 d / T^2 + 4 qd / T,
    d = q_hit - q_rest, so this is linear least squares). The knot called back-swing is the cubic's own
    state ``h_habit`` before the hit (it splits the segment; the curve is unchanged).
    Returns (h_b, q_back, qd_back, qd_hit)."""
    kin = teacher.kin
    A = teacher._task_jacobian(q_hit)
    N = np.eye(kin.n_joints) - np.linalg.pinv(A) @ A
    d, T, W = q_hit - q_rest, t_hit, 1.0 / amax
    c0, c1 = 6 * d / T**2 - 2 * qd_hit / T, -6 * d / T**2 + 4 * qd_hit / T
    M = np.vstack([(-2.0 / T) * W[:, None] * N, (4.0 / T) * W[:, None] * N])
    zeta = np.linalg.lstsq(M, -np.concatenate([W * c0, W * c1]), rcond=None)[0]
    zero = np.zeros(kin.n_joints)
    for qd in (qd_hit + N @ zeta, qd_hit):  # with the swing-through habit; without it if that leaves the limits
        if _segment_ok(q_rest, zero, q_hit, qd, np.array([T]), vmax, amax, kin.q_min, kin.q_max)[0]:
            qd_hit = qd
            break
    else:
        raise ValueError(f"{where}: hitting time {t_hit:.3g} s is too short to swing from rest to "
                         f"{v_hit.round(2).tolist()} m/s within the WAM's velocity and acceleration limits")
    h_b = float(np.clip(h_habit, 0.05 * T, 0.95 * T))
    cubic = CubicHermiteSpline([0.0, T], np.array([q_rest, q_hit]), np.array([zero, qd_hit]))
    return h_b, cubic(T - h_b), cubic(T - h_b, 1), qd_hit


#: how the teacher gets from rest to the hit: name -> swing(teacher, q_rest, q_hit, qd_hit, t_hit, h_habit,
#: vmax, amax, where, v_hit) -> (h_b, q_back, qd_back, qd_hit); raises ValueError("... too short ...")
SWINGS = {"backswing": _swing_backswing, "direct": _swing_direct}
assert tuple(sorted(SWINGS)) == SWING_NAMES


def _segment_ok(p0, v0, p1, v1, h, vmax, amax, low, high, n_samples: int = 17) -> np.ndarray:
    """Which candidate cubic Hermite segments (p0, v0) -> (p1, v1) of duration h keep every joint's
    position within [low, high] and velocity and acceleration within vmax, amax (all (7,)).
    Arguments broadcast to (c, 7) / h (c,); all candidates are checked at once. Returns (c,) bool.
    """
    h = np.asarray(h, float)
    H = h[:, None, None]
    s = np.linspace(0.0, 1.0, n_samples)[None, :, None]
    n = np.shape(low)[-1]  # the arm's joints
    p0 = np.broadcast_to(np.asarray(p0, float), (h.size, n))[:, None, :]
    d = np.broadcast_to(np.asarray(p1, float), (h.size, n))[:, None, :] - p0
    v0 = np.broadcast_to(v0, (h.size, n))[:, None, :]
    v1 = np.broadcast_to(v1, (h.size, n))[:, None, :]
    # the cubic Hermite segment and its time derivatives at s = t / h in [0, 1]
    pos = p0 + d * (3 * s**2 - 2 * s**3) + H * v0 * (s - 2 * s**2 + s**3) + H * v1 * (s**3 - s**2)
    vel = d * (6 * s - 6 * s**2) / H + v0 * (1 - 4 * s + 3 * s**2) + v1 * (3 * s**2 - 2 * s)
    acc = d * (6 - 12 * s) / H**2 + v0 * (6 * s - 4) / H + v1 * (6 * s - 2) / H
    ok = (np.abs(vel) <= vmax + 1e-9) & (np.abs(acc) <= amax + 1e-9) & (pos >= low - 1e-9) & (pos <= high + 1e-9)
    return ok.all(axis=(1, 2)) & (h > 0)
