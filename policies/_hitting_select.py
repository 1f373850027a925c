"""Choosing the hitting time: where the ProMP's racket distribution makes the ball most likely reached.

Decision rule (docs/play.md, "decision rule"; Gomez-Gonzalez et al. 2016/2018 choose the hitting time
the same way): the ProMP's racket-centre distribution at phase z is the linearised task marginal

    x_r(z) ~ N(mu_r(z), Sigma_r(z)),   mu_r = fk(mean q(z)),  Sigma_r = J Sigma_q(z) J^T         (S1)

(``ProMP.task_marginal``; positions at equal phase do not depend on the duration, so it is computed
once per phase). The filter predicts the ball at time t as N(x_b(t), Sigma_b(t)). The probability
density that the racket at phase z meets the ball at time t is

    L(t, z) = N(x_b(t) - r n0 ; mu_r(z), Sigma_r(z) + Sigma_b(t))                                 (S2)

(r n0: the racket centre sits one ball radius behind the ball centre, along the nominal normal n0).
Candidates are the prediction's times t_k (every ``candidate_dt_s``) where the ball is inside the
hitting region and moving towards the robot, crossed with the phases z_j at which the
demonstrations hit (their mean +- 1 and 2 standard deviations). A pair is *timely* if a movement
of duration T in [min_time_scale, 1] x the nominal duration, hitting at phase z_j, can still start
at or after ``t_earliest_start``: z_j T <= t_k - t_earliest_start. Among timely pairs the policy takes
the largest L; its squared Mahalanobis distance D^2 must not exceed ``max_mahalanobis2`` (else
the ball is out of the racket's reach under this primitive). The duration is the nominal one if
there is time (the movement then starts later and sees more observations), else the shortest
that fits.

All candidates are scored in one batched computation (no loop per candidate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Candidate", "score_candidates"]


@dataclass(frozen=True)
class Candidate:
    """One scored (time, phase) pair: index into the prediction, hit time (s, session clock),
    phase z, duration T (s), start time (s), squared Mahalanobis distance and log-likelihood of (S2)."""

    index: int
    t_hit_s: float
    phase: float
    duration_s: float
    t_start_s: float
    mahalanobis2: float
    log_likelihood: float


def score_candidates(t_s, X_ball, V_ball, C_ball, mu_r, S_r, phases, *, region_min, region_max, nominal_duration_s,
                     min_time_scale, t_earliest_start_s, offset_m, limit: int = 8) -> tuple[list[Candidate], str]:
    """Rank hitting candidates by (S2), best first.

    t_s : (M,) prediction times; X_ball, V_ball : (M, 3) predicted position, velocity; C_ball : (M, 3, 3)
    mu_r : (P, 3), S_r : (P, 3, 3) racket marginal at the P ``phases`` (P,)
    offset_m : (3,) added to the ball position (the racket centre's place relative to the ball)
    returns (the ``limit`` best timely candidates by log-likelihood, descending; reason when there are none)
    """
    inside = np.all((X_ball >= region_min) & (X_ball <= region_max), axis=1) & (V_ball[:, 0] < 0.0)
    if not inside.any():
        return [], "the predicted ball does not reach the hitting region"
    k = np.nonzero(inside)[0]
    z = np.asarray(phases, float)
    lead = t_s[k][:, None] - t_earliest_start_s  # (K, 1) time left until each candidate hit
    T = np.minimum(nominal_duration_s, lead / z[None, :])  # (K, P): nominal if there is time, else shorter
    timely = T >= min_time_scale * nominal_duration_s
    if not timely.any():
        return [], "too late: no movement can reach the predicted ball in time"
    d = (X_ball[k] + offset_m)[:, None, :] - mu_r[None, :, :]  # (K, P, 3)
    S = C_ball[k][:, None, :, :] + S_r[None, :, :, :]  # (K, P, 3, 3)
    L = np.linalg.cholesky(S + 1e-12 * np.eye(3))
    y = np.linalg.solve(L, d[..., None])[..., 0]
    m2 = np.sum(y**2, axis=-1)  # (K, P)
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    ll = -0.5 * (m2 + logdet + 3.0 * np.log(2.0 * np.pi))
    ll = np.where(timely, ll, -np.inf)
    order = np.argsort(-ll, axis=None)
    out = []
    for flat in order[: min(int(timely.sum()), int(limit))]:
        i, j = np.unravel_index(flat, ll.shape)
        t_hit = float(t_s[k[i]])
        out.append(Candidate(int(k[i]), t_hit, float(z[j]), float(T[i, j]), t_hit - float(z[j] * T[i, j]),
                             float(m2[i, j]), float(ll[i, j])))
    return out, ""
