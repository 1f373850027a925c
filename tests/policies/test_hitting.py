"""The hitting policy (policies/hitting.py): decision rule, return rule, conditioning, no-attempt reasons.

Sections: smoke, decision rule (batched candidates), return rule on the ball model, conditioning hits
the point, the policy on a served ball (plan commanded within the limits), no attempt (no prediction,
a ball that never arrives, out of reach), bad input.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from policies import TableGeometry, racket_kinematics, simulate
from policies._hitting_motion import check_feasible, condition_hit, sample_mean
from policies._hitting_return import solve_return
from policies._hitting_select import score_candidates
from policies.hitting import HittingOptions, HittingPolicy, PolicyStatus
from policies.teacher import racket_fk_jacobian
from tests.policies.hitting_util import Prediction, RecordingWam, predictor


def _served(seed=0):
    """The state of a launcher serve at its launch (t = 0)."""
    from harness.sim.launcher import BallLauncher

    return BallLauncher(seed=seed).serve().state


# ----------------------------------------------------------------------------- smoke
def test_smoke(promp, kin, params):
    policy = HittingPolicy(promp, kin, HittingOptions(), ball_params=params)
    assert policy.status == PolicyStatus.WAITING and not policy.attempted
    assert 0.3 < policy.phases.mean() < 0.5 and len(policy.phases) >= 1
    assert policy._mu_r.shape == (len(policy.phases), 3) and policy._S_r.shape == (len(policy.phases), 3, 3)


# ----------------------------------------------------------------------------- decision rule (S1-S2)
def test_decision_rule_picks_the_most_likely_reachable_time():
    t = np.linspace(0.5, 1.0, 51)
    X = np.stack([-0.8 - 1.2 * (t - 0.5), np.zeros_like(t), np.full_like(t, 1.1)], axis=1)  # x -0.8 .. -1.4
    V = np.tile([-2.4, 0.0, 0.0], (len(t), 1))
    C = np.tile(np.eye(3) * 1e-4, (len(t), 1, 1))
    mu = np.array([[-1.2, 0.0, 1.1]])
    S = np.eye(3)[None] * 0.01
    common = dict(region_min=np.array([-1.75, -0.8, 0.85]), region_max=np.array([-1.0, 0.8, 1.5]), nominal_duration_s=1.0,
                  min_time_scale=0.9, offset_m=np.zeros(3))
    cands, reason = score_candidates(t, X, V, C, mu, S, np.array([0.4]), t_earliest_start_s=0.0, **common)
    assert reason == "" and len(cands) >= 1
    best = cands[0]
    assert abs(X[best.index, 0] - (-1.2)) < 0.013  # the point nearest the racket mean
    assert best.duration_s == pytest.approx(1.0) and best.t_start_s == pytest.approx(best.t_hit_s - 0.4)
    assert all(c.log_likelihood <= best.log_likelihood for c in cands)
    # too late: nothing can start in time
    none, reason = score_candidates(t, X, V, C, mu, S, np.array([0.4]), t_earliest_start_s=0.9, **common)
    assert none == [] and "too late" in reason
    # moving away from the robot: never a candidate
    none, reason = score_candidates(t, X, -V, C, mu, S, np.array([0.4]), t_earliest_start_s=0.0, **common)
    assert none == [] and "does not reach" in reason


def test_decision_rule_compresses_the_duration_when_late():
    t = np.array([0.8])
    X, V, C = np.array([[-1.2, 0, 1.1]]), np.array([[-2.0, 0, 0]]), np.eye(3)[None] * 1e-4
    cands, _ = score_candidates(t, X, V, C, X.copy(), np.eye(3)[None] * 0.01, np.array([0.5]),
                                region_min=np.array([-2, -1, 0.5]), region_max=np.array([-1, 1, 2]),
                                nominal_duration_s=1.0, min_time_scale=0.9, t_earliest_start_s=0.33, offset_m=np.zeros(3))
    assert cands[0].duration_s == pytest.approx(0.94) and cands[0].t_start_s == pytest.approx(0.33)


# ----------------------------------------------------------------------------- return rule
def test_return_rule_lands_on_the_target(params):
    p, v = np.array([-1.25, 0.05, 1.1]), np.array([-2.4, -0.1, 0.3])
    sol = solve_return(p, v, np.zeros(3), (0.6, 0.0), params, TableGeometry(), restitution=0.78, friction=0.25,
                       net_top_z_m=0.76 + 0.1525, net_clearance_m=0.3)
    assert sol.residual_m < 0.01 and np.linalg.norm(sol.landing_xy_m - [0.6, 0.0]) < 0.01
    assert sol.normal[0] > 0.7 and abs(np.linalg.norm(sol.normal) - 1) < 1e-9
    assert 0.5 < np.linalg.norm(sol.racket_velocity_mps) < 3.0
    np.testing.assert_allclose(np.cross(sol.racket_velocity_mps, sol.normal), 0.0, atol=1e-9)  # along the normal
    assert sol.net_clearance_m == pytest.approx(0.3, abs=0.01)


# ----------------------------------------------------------------------------- conditioning hits the point
def test_conditioning_hits_point_normal_and_velocity(promp, kin):
    fk6, _ = racket_kinematics(kin, with_normal=True)
    _, jac3 = racket_kinematics(kin)
    z = promp.metadata["hit_phase_mean"]
    T = promp.duration_s
    x = np.array([-1.25, 0.08, 1.12])
    n = np.array([0.95, 0.0, 0.31]) / np.linalg.norm([0.95, 0.0, 0.31])
    v = 1.3 * n
    mu_w = condition_hit(promp, duration_s=T, t_rel_now=0.0, q_now=kin.q_home, qd_now=np.zeros(7), q_ready=kin.q_home,
                         t_rel_hit=z * T, x_racket=x, normal=n, v_racket=v, racket=racket_fk_jacobian(kin))
    cond = replace(promp, mu_w=mu_w)
    q, qd = (a[0] for a in cond.mean_trajectory([z * T], duration_s=T))
    f = fk6(q)
    assert np.linalg.norm(f[:3] - x) < 1e-3
    assert np.degrees(np.arccos(np.clip(f[3:] @ n, -1, 1))) < 1.0
    np.testing.assert_allclose(jac3(q) @ qd, v, atol=1e-3)
    q0, qd0 = (a[0] for a in cond.mean_trajectory([0.0], duration_s=T))
    np.testing.assert_allclose(q0, kin.q_home, atol=1e-6)  # starts where the robot is, at rest
    np.testing.assert_allclose(qd0, 0.0, atol=1e-6)
    t, Q, QD = sample_mean(promp, mu_w, T, 0.0, 500.0)
    assert np.diff(t)[:-1].max() <= 0.002 + 1e-12 and np.diff(t)[-1] <= 1.25 * 0.002 and t[-1] == pytest.approx(T)
    np.testing.assert_allclose(Q[-1], kin.q_home, atol=1e-6)  # back at rest


def test_check_feasible_names_the_broken_limit(kin):
    t = np.arange(0, 0.2, 0.002)
    q = np.tile(kin.q_home, (len(t), 1))
    q[:, 0] += 0.5 * 20.0 * t**2  # joint_1 at 20 rad/s^2 > 6.8
    qd = np.gradient(q, t, axis=0)
    reason, scale = check_feasible(kin, t, q, qd, 1.0)
    assert "acceleration limit: joint_1" in reason and scale == pytest.approx(np.sqrt(20 / 6.8), rel=0.05)
    assert check_feasible(kin, t, np.tile(kin.q_home, (len(t), 1)), np.zeros_like(q), 1.0) == ("", 1.0)
    q_bad = np.tile(kin.q_home, (len(t), 1))
    q_bad[5, 3] = 3.5
    assert check_feasible(kin, t, q_bad, np.zeros_like(q), 1.0)[1] == np.inf


# ----------------------------------------------------------------------------- the policy on a served ball
def test_policy_plans_a_reachable_hit_and_commands_it(promp, kin, params):
    state = _served(3)
    wam = RecordingWam(kin.q_home)
    policy = HittingPolicy(promp, kin, HittingOptions(), ball_params=params)
    policy.reset(kin.q_home)
    predict = predictor(state, 0.0, params)
    plan = None
    for t in np.arange(0.15, 0.6, 0.02):
        step = policy.step(t, predict, wam)
        plan = step.plan or plan
    assert plan is not None, policy.reason
    assert wam.commands and policy.status in (PolicyStatus.PLANNED, PolicyStatus.COMMITTED)
    t_cmd, q_cmd, qd_cmd = wam.commands[-1]
    assert np.all(np.diff(t_cmd) > 0) and np.diff(t_cmd).max() <= 1.25 * 0.002 + 1e-9
    assert kin.within_limits(q_cmd).all() and (np.abs(qd_cmd) <= kin.qdot_max + 1e-9).all()
    lo, hi = np.array(HittingOptions().region_min_m), np.array(HittingOptions().region_max_m)
    assert np.all(plan.ball_position_m >= lo) and np.all(plan.ball_position_m <= hi)
    # the planned racket meets the true ball at t_hit: the ball centre one radius in front of the racket face
    out, _ = simulate(state, [plan.t_hit_s], params, TableGeometry())
    np.testing.assert_allclose(plan.ball_position_m, out[0, :3], atol=1e-6)
    fk6, _ = racket_kinematics(kin, with_normal=True)
    i = int(np.argmin(np.abs(plan.t_s - plan.t_hit_s)))
    assert np.linalg.norm(fk6(plan.q[i])[:3] - plan.racket_position_m) < 0.01
    assert plan.t_start_s <= plan.t_hit_s - 0.3  # a real stroke, not a jump


# ----------------------------------------------------------------------------- no attempt, with a reason
def test_no_prediction_no_command(promp, kin, params):
    wam = RecordingWam(kin.q_home)
    policy = HittingPolicy(promp, kin, ball_params=params)
    step = policy.step(0.1, lambda t: None, wam)
    assert step.plan is None and step.reason == "no ball prediction yet" and not wam.commands


def test_ball_that_never_arrives(promp, kin, params):
    away = np.array([0.5, 0.0, 1.1, 4.0, 0.0, 1.0, 0, 0, 0])  # flying to the opponent
    wam = RecordingWam(kin.q_home)
    policy = HittingPolicy(promp, kin, ball_params=params)
    step = policy.step(0.0, predictor(away, 0.0, params), wam)
    assert step.plan is None and "does not reach the hitting region" in step.reason and not wam.commands


def test_unreachable_ball_is_out_of_reach(promp, kin, params):
    wide = np.array([0.0, 0.72, 1.2, -2.5, 0.0, 1.5, 0, 0, 0])  # bounces and passes the robot 0.72 m to its left
    wam = RecordingWam(kin.q_home)
    policy = HittingPolicy(promp, kin, ball_params=params)
    step = policy.step(0.0, predictor(wide, 0.0, params), wam)
    assert step.plan is None and not wam.commands and policy.status == PolicyStatus.WAITING
    assert step.reason.startswith("out of reach: the best hitting point") and "sigma" in step.reason
    assert policy.reason_counts == {"out of reach": 1}


# ----------------------------------------------------------------------------- bad input
def test_bad_input(promp, kin, params):
    import dataclasses

    with pytest.raises(ValueError, match="learned for robot 'kuka'"):
        HittingPolicy(dataclasses.replace(promp, robot_id="kuka"), kin)
    with pytest.raises(ValueError, match="hit_phase_mean"):
        HittingPolicy(dataclasses.replace(promp, metadata={}), kin)
    with pytest.raises(ValueError, match="options must be HittingOptions"):
        HittingPolicy(promp, kin, {"horizon_s": 1.0})
    with pytest.raises(ValueError, match="HittingOptions.target_xy_m"):
        HittingOptions(target_xy_m=(-0.5, 0.0))
    with pytest.raises(ValueError, match="HittingOptions.region_min_m must be below"):
        HittingOptions(region_min_m=(0, 0, 0), region_max_m=(-1, 1, 1))
    with pytest.raises(ValueError, match="HittingOptions.min_time_scale"):
        HittingOptions(min_time_scale=1.5)
    policy = HittingPolicy(promp, kin, ball_params=params)
    bad = lambda t: Prediction(t, np.zeros((len(t), 2)), np.zeros((len(t), 3)), np.zeros((len(t), 3, 3)))  # noqa: E731
    with pytest.raises(ValueError, match="ball prediction shapes"):
        policy.step(0.0, bad, RecordingWam(kin.q_home))
