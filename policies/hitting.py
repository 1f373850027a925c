"""The hitting policy: from the ball filter's prediction to a ProMP hitting movement on the WAM.

Gomez-Gonzalez et al. 2018 ("Adaptation and robust learning of probabilistic movement primitives"):
a ProMP learned from a teacher is conditioned on the predicted ball and executed. Each call of
:meth:`HittingPolicy.step` (at most every ``replan_period_s``, until the commit point):

1. predict the ball over the next ``horizon_s`` (the filter's ``predict``: positions, velocities,
   covariances);
2. choose the hitting time and phase by the decision rule of ``_hitting_select`` (the largest
   likelihood of the ball under the racket distribution of the ProMP, among hits a movement can
   still reach in time; too far -> no plan, reason recorded);
3. choose the racket normal and velocity that return the ball to ``target_xy_m`` on the opponent's
   half (``_hitting_return``: mirror law, refined on the ball model), and put the racket centre one
   ball radius behind the ball centre along the normal;
4. condition the ProMP on the present state, the return to rest and the hit (``_hitting_motion``),
   sample its mean at the control rate, check joint, velocity and acceleration limits; the first of
   the best ``max_candidates`` candidates that passes is commanded on the WAM (``command_trajectory``,
   absolute times, 500 Hz samples). The movement ends back at the ready posture (return to rest);
5. re-plan with every new prediction until ``commit_before_hit_s`` before the hit (the commit point).
   Before the movement starts everything may change (time, duration, point); once it has started the
   hitting time and duration stay, and the re-plan conditions on the commanded reference so the new
   trajectory continues it without a jump. A failed re-plan keeps the previous plan.

Never raises during a session for a ball it cannot play: no prediction, a ball that never reaches the
hitting region, a hit out of reach or beyond the WAM's limits all leave the policy WAITING with the
reason in :attr:`HittingPolicy.reason`; the session reports "no attempt" with it. Bad construction
arguments (a ProMP for another robot, wrong options) raise ValueError.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from policies._hitting_motion import check_feasible, condition_hit, sample_mean
from policies._hitting_options import PLANNERS, HittingOptions
from policies._hitting_return import solve_return
from policies._hitting_select import Candidate, score_candidates
from policies.ball_model import BallParams, TableGeometry
from policies.teacher import racket_fk_jacobian, racket_kinematics
from robot_models.robot_interface import WamInterface

__all__ = ["NO_PREDICTION", "PLANNERS", "HitPlan", "HittingOptions", "HittingPolicy", "PolicyStatus", "PolicyStep"]


NO_PREDICTION = "no ball prediction yet"  #: the reason of a step before the filter predicts: nothing was planned


class PolicyStatus(StrEnum):
    WAITING = "waiting"  #: no movement commanded (yet); :attr:`HittingPolicy.reason` says why
    PLANNED = "planned"  #: a hitting movement is commanded (maybe not started yet); still re-planned
    COMMITTED = "committed"  #: past the commit point: the movement runs unchanged
    DONE = "done"  #: the movement (hit, follow-through, return to rest) has ended


@dataclass(frozen=True)
class HitPlan:
    """One planned hitting movement (session clock, lab world frame).

    t_plan_s : when it was planned; t_start_s, duration_s : the ProMP's start and duration T;
    t_hit_s, phase : hitting time and its phase; ball_position_m / ball_velocity_mps (3,) predicted at
    t_hit_s; racket_position_m (3,), normal (3,), racket_velocity_mps (3,) the racket at the hit;
    mahalanobis2 : of the ball under the racket distribution (decision rule S2);
    landing_xy_m (2,) predicted landing of the return; t_s (N,), q (N, 7), qd (N, 7) the commanded
    reference (from the first commanded sample on); replan : True if the movement had already started.
    """

    t_plan_s: float
    t_start_s: float
    duration_s: float
    t_hit_s: float
    phase: float
    ball_position_m: np.ndarray
    ball_velocity_mps: np.ndarray
    racket_position_m: np.ndarray
    normal: np.ndarray
    racket_velocity_mps: np.ndarray
    mahalanobis2: float
    landing_xy_m: np.ndarray
    t_s: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    replan: bool = False

    @property
    def t_end_s(self) -> float:
        return self.t_start_s + self.duration_s


@dataclass(frozen=True)
class PolicyStep:
    """What one :meth:`HittingPolicy.step` did: status after it, the new plan (or None), and the reason
    when it made none."""

    t_s: float
    status: PolicyStatus
    plan: HitPlan | None = None
    reason: str = ""

    @property
    def planned(self) -> bool:
        """The step did planning work: it made a plan, or failed to with a reason other than
        :data:`NO_PREDICTION` (not a step skipped by the re-plan period, not one before any prediction)."""
        return self.plan is not None or self.reason not in ("", NO_PREDICTION)


def _check_prediction(pred, m: int):
    """The filter's prediction (duck-typed: t_s, position_m, velocity_mps, covariance_m2) as arrays."""
    try:
        X = np.asarray(pred.position_m, float)
        V = np.asarray(pred.velocity_mps, float)
        C = np.asarray(pred.covariance_m2, float)
        t = np.asarray(pred.t_s, float)
    except AttributeError as exc:
        raise ValueError(f"a ball prediction needs t_s, position_m, velocity_mps, covariance_m2; got {pred!r:.80}") from exc
    if X.shape != (m, 3) or V.shape != (m, 3) or C.shape != (m, 3, 3) or t.shape != (m,):
        raise ValueError(f"ball prediction shapes must be t_s ({m},), position_m ({m}, 3), velocity_mps ({m}, 3), "
                         f"covariance_m2 ({m}, 3, 3); got {t.shape}, {X.shape}, {V.shape}, {C.shape}")
    if not (np.isfinite(X).all() and np.isfinite(V).all() and np.isfinite(C).all()):
        raise ValueError("ball prediction contains non-finite values")
    return t, X, V, C


class HittingPolicy:
    """ProMP hitting policy (see the module docstring and docs/play.md).

    promp : :class:`policies.ProMP` over the arm's joints, learned from hitting demonstrations; its
        ``metadata["hit_phase_mean"]`` / ``["hit_phase_std"]`` give the phase of the hit
    kinematics : :class:`robot_models.WamKinematics`; must be the robot the ProMP was learned for
    options : :class:`HittingOptions`; ball_params / table : the policy's ball model (defaults: the
        fitted parameters, the lab table)
    """

    def __init__(self, promp, kinematics, options: HittingOptions = HittingOptions(), *,
                 ball_params: BallParams | None = None, table: TableGeometry | None = None):
        if not isinstance(options, HittingOptions):
            raise ValueError(f"options must be HittingOptions, got {type(options).__name__}")
        if promp.robot_id and promp.robot_id != str(kinematics.model.name):
            raise ValueError(f"the ProMP was learned for robot {promp.robot_id!r}, not {kinematics.model.name!r}")
        if tuple(promp.joint_names) != tuple(kinematics.joint_names):
            raise ValueError(f"the ProMP's joints {list(promp.joint_names)} are not the robot's "
                             f"{list(kinematics.joint_names)}")
        meta = promp.metadata
        if "hit_phase_mean" not in meta:
            raise ValueError("the ProMP's metadata has no 'hit_phase_mean' (learn it with `rt2 learn promp`)")
        z0, sz = float(meta["hit_phase_mean"]), float(meta.get("hit_phase_std", 0.0))
        if not 0.05 < z0 < 0.95:
            raise ValueError(f"the ProMP's hit_phase_mean must be in (0.05, 0.95), got {z0}")
        self.promp, self.kin, self.options = promp, kinematics, options
        self.params = ball_params or BallParams.load()
        self.table = table or TableGeometry()
        self.phases = np.unique(np.clip(z0 + sz * np.array([-2.0, -1.0, 0.0, 1.0, 2.0]), 0.05, 0.95))
        self._racket = racket_fk_jacobian(kinematics, with_normal=True)
        fk3, jac3 = racket_kinematics(kinematics)
        # (S1): the racket marginal per phase (independent of the duration for positions)
        self._mu_r, self._S_r = promp.task_marginal(self.phases * promp.duration_s, fk3, jac3)
        self.reset()

    # ---------------------------------------------------------------- state
    def reset(self, q_ready=None) -> None:
        """Forget the last ball. ``q_ready`` (7,): the rest posture the movement returns to (default: the
        ProMP's mean start)."""
        q0 = self.promp.mean_trajectory([0.0])[0][0] if q_ready is None else q_ready
        self.q_ready = self.kin.check_q(q0, "q_ready")
        self.status = PolicyStatus.WAITING
        self.plan: HitPlan | None = None
        self.plans: list[HitPlan] = []
        self.reason = NO_PREDICTION
        self.reason_counts: dict[str, int] = {}  #: why steps made no plan: first words of the reason -> count
        self._t_last_plan = -np.inf
        self._t_now = -np.inf
        self._last_return = None

    def warm_up(self, ball_filter, **options) -> dict:
        """Pay a fresh process's one-time costs (compiled kernels, first solver calls) before the first real
        ball: play a nominal served ball through ``ball_filter`` and this policy against a robot stand-in
        that only reports rest, then reset both. For real-time use (``rt2 play --live``); options and
        return value: :func:`policies._hitting_warmup.warm_up`."""
        from policies._hitting_warmup import warm_up

        return warm_up(self, ball_filter, **options)

    @property
    def attempted(self) -> bool:
        """True once a commanded movement has started."""
        return self.plan is not None and self._t_now >= self.plan.t_start_s

    # ---------------------------------------------------------------- one control step
    def step(self, t_now_s: float, predict, wam: WamInterface) -> PolicyStep:
        """Advance the policy to ``t_now_s`` (session clock).

        predict : callable t_query (M,) -> prediction (t_s, position_m (M, 3), velocity_mps (M, 3),
            covariance_m2 (M, 3, 3)) or None -- e.g. a ball filter's ``predict``
        wam : :class:`robot_models.robot_interface.WamInterface` (``read_state()``, ``command_trajectory(t_s, q, qdot)``),
            in process or over the robot link
        """
        t = float(t_now_s)
        self._t_now = t
        o, plan = self.options, self.plan
        if plan is not None and t >= plan.t_end_s:
            self.status = PolicyStatus.DONE
        elif plan is not None and t >= plan.t_hit_s - o.commit_before_hit_s:
            self.status = PolicyStatus.COMMITTED
        if self.status in (PolicyStatus.DONE, PolicyStatus.COMMITTED) or t - self._t_last_plan < o.replan_period_s:
            return PolicyStep(t, self.status)
        self._t_last_plan = t
        try:
            new, reason = self._plan(t, predict, wam)
        except (np.linalg.LinAlgError, FloatingPointError) as exc:  # numerical trouble is a failed plan, not a crash
            new, reason = None, f"numerical failure while planning: {exc}"
        if new is None:
            self.reason = reason
            key = reason.split(":")[0]
            self.reason_counts[key] = self.reason_counts.get(key, 0) + 1
            return PolicyStep(t, self.status, None, reason)
        wam.command_trajectory(new.t_s, new.q, new.qd)
        self.plan = new
        self.plans.append(new)
        self.status, self.reason = PolicyStatus.PLANNED, ""
        return PolicyStep(t, self.status, new)

    def _plan(self, t, predict, wam: WamInterface):
        o, plan = self.options, self.plan
        t_earliest = t + o.min_lead_s
        started = plan is not None and t_earliest >= plan.t_start_s
        t_grid = t + np.arange(0.0, o.horizon_s, o.candidate_dt_s)
        pred = predict(t_grid)
        if pred is None:
            return None, NO_PREDICTION
        t_s, X, V, C = _check_prediction(pred, len(t_grid))
        offset = -self.params.radius_m * np.array([1.0, 0.0, 0.0])
        if started:  # the hit time and duration stay; only the point follows the prediction
            k = int(np.argmin(np.abs(t_s - plan.t_hit_s)))
            if abs(t_s[k] - plan.t_hit_s) > o.candidate_dt_s:
                return None, "the prediction does not cover the planned hit"
            cands = [Candidate(k, plan.t_hit_s, plan.phase, plan.duration_s, plan.t_start_s, np.nan, np.nan)]
        else:
            cands, reason = score_candidates(
                t_s, X, V, C, self._mu_r, self._S_r, self.phases, region_min=np.asarray(o.region_min_m),
                region_max=np.asarray(o.region_max_m), nominal_duration_s=self.promp.duration_s,
                min_time_scale=o.min_time_scale, t_earliest_start_s=t_earliest, offset_m=offset,
                limit=o.max_candidates)
            if not cands:
                return None, reason
            if cands[0].mahalanobis2 > o.max_mahalanobis2:
                return None, (f"out of reach: the best hitting point {np.round(X[cands[0].index], 3).tolist()} m is "
                              f"{np.sqrt(cands[0].mahalanobis2):.1f} sigma from the ProMP's racket distribution")
        reasons = []
        for c in cands:
            try:
                return self._build(t, c, X[c.index], V[c.index], started, wam), ""
            except ValueError as exc:
                reasons.append(str(exc))
        return None, "no feasible movement: " + "; ".join(dict.fromkeys(reasons))

    def _build(self, t, c, x_ball, v_ball, started, wam: WamInterface) -> HitPlan:
        o, plan = self.options, self.plan
        ret = solve_return(x_ball, v_ball, np.zeros(3), o.target_xy_m, self.params, self.table,
                           restitution=o.racket_restitution, friction=o.racket_friction,
                           net_top_z_m=self.table.surface_z_m + self.table.net_height_m, net_clearance_m=o.net_clearance_m,
                           warm_start=self._last_return, method=o.planner)
        if ret.residual_m > o.max_return_residual_m:
            raise ValueError(f"no racket state returns the ball to {list(o.target_xy_m)} (residual {ret.residual_m:.3f} m)")
        self._last_return = ret
        x_racket = x_ball - self.params.radius_m * ret.normal
        T, t_start = c.duration_s, c.t_start_s
        for _ in range(1 + o.max_time_scalings):
            if started:  # continue the commanded reference from its first sample after now + lead
                i = int(np.searchsorted(plan.t_s, t + o.min_lead_s))
                if i >= len(plan.t_s) - 1:
                    raise ValueError("the movement is about to end")
                t_from, q_now, qd_now = plan.t_s[i], plan.q[i], plan.qd[i]
            else:
                t_from, q_now, qd_now = t_start, np.asarray(wam.read_state().q, float), np.zeros(self.kin.n_joints)
            mu_w = condition_hit(self.promp, duration_s=T, t_rel_now=t_from - t_start, q_now=q_now, qd_now=qd_now,
                                 q_ready=self.q_ready, t_rel_hit=c.t_hit_s - t_start, x_racket=x_racket,
                                 normal=ret.normal, v_racket=ret.racket_velocity_mps, racket=self._racket,
                                 method=o.planner)
            t_rel, q, qd = sample_mean(self.promp, mu_w, T, t_from - t_start, o.control_rate_hz)
            bad, scale = check_feasible(self.kin, t_rel, q, qd, o.limit_margin)
            if not bad:
                break
            # time scaling: a slower movement (duration x scale) that starts earlier, if it still can
            T_slow = T * scale * 1.02
            if started or not np.isfinite(scale) or c.t_hit_s - c.phase * T_slow < t + o.min_lead_s:
                raise ValueError(bad)
            T, t_start = T_slow, c.t_hit_s - c.phase * T_slow
        else:
            raise ValueError(bad)
        return HitPlan(t, t_start, T, c.t_hit_s, c.phase, np.asarray(x_ball, float).copy(),
                       np.asarray(v_ball, float).copy(), x_racket, ret.normal, ret.racket_velocity_mps,
                       c.mahalanobis2, ret.landing_xy_m, t_start + t_rel, q, qd, started)
