"""Writing playing sessions to MCAP (``harness.logs``): one file per configuration, one ball after another.

Ball i is placed at log time ``i * BALL_SLOT_S`` + its own session time, so every ball has its own
window on the file's timeline (``rt2 reevaluate`` and Foxglove read them back by window). Per ball:

* ``/ground_truth/ball`` at every WAM tick (the true ball), ``/robot/joint_states`` (the REPORTED
  joints), ``/robot/command`` (the commanded reference), ``/scene/arm`` and ``/scene/balls`` every
  ``scene_every`` ticks (the TRUE arm; the true and the filtered ball);
* ``/tracker/<tracker>/ball``: every observation, stamped with its capture time;
* ``/figures/filter``: the filter's verdict and state after each delivered observation
  (``t_deliver_s``, ``accepted``, ``reason``, ``position_m``, ``velocity_mps``, ``t_state_s``);
* ``/figures/plan``: each plan of the hitting policy (``t_plan_s``, ``t_start_s``, ``t_hit_s``,
  ``duration_s``, hitting point, racket position, normal and velocity, ``mahalanobis2``, ``replan``);
* ``/figures/ball``: the ball's result (``harness.experiments.play.session.BallResult`` fields) and its serve;
* images (vision source, ``--log-images``) on ``/camera/<cam>/image``.

Metadata ``session``: kind "play", seed, the configuration, ``ball_slot_s``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BALL_SLOT_S", "write_ball"]

BALL_SLOT_S = 10.0  #: log-time window of one ball, seconds (longer than any ball's session)


def _vec(v):
    return None if v is None else [float(x) for x in np.asarray(v, float).ravel()]


def write_ball(log, index: int, tracker: str, result, record, serve, *, kinematics=None, scene_every: int = 5) -> None:
    """Write ball ``index`` (its BallResult, BallRecord and Serve) to ``log`` (a SessionLogWriter)."""
    t0 = index * BALL_SLOT_S
    if record is not None:
        for k, (t, x, q, qd, qc) in enumerate(zip(record.truth_t_s, record.truth_m, record.q_reported,
                                                  record.qdot_reported, record.q_command)):
            log.write_ground_truth(t0 + t, x, q, qd, qc, k)
            if kinematics is not None and k % scene_every == 0:
                log.write_scene_arm(t0 + t, kinematics.link_points(record.q_true[k], check_limits=False))
                log.write_scene_balls(t0 + t, x)
        for k, (obs, upd) in enumerate(record.observations):
            log.write_observation(t0 + obs.t_s, tracker, obs, k)
        for (t_capture, state), (obs, upd) in zip(record.filter_states, record.observations):
            doc = {"t_capture_s": float(t_capture), "t_deliver_s": float(t_capture + obs.latency_s),
                   "accepted": bool(upd.accepted), "reason": str(upd.reason)}
            if state is not None:
                doc.update(t_state_s=float(state.t_s), position_m=_vec(state.position), velocity_mps=_vec(state.velocity))
            log.write_figures("filter", doc, t0 + t_capture + obs.latency_s)
        for p in record.plans:
            log.write_figures("plan", {
                "ball": int(index), "t_plan_s": p.t_plan_s, "t_start_s": p.t_start_s, "t_hit_s": p.t_hit_s,
                "duration_s": p.duration_s, "phase": p.phase, "ball_position_m": _vec(p.ball_position_m),
                "ball_velocity_mps": _vec(p.ball_velocity_mps), "racket_position_m": _vec(p.racket_position_m),
                "normal": _vec(p.normal), "racket_velocity_mps": _vec(p.racket_velocity_mps),
                "mahalanobis2": float(p.mahalanobis2) if np.isfinite(p.mahalanobis2) else None,
                "landing_xy_m": _vec(p.landing_xy_m), "replan": bool(p.replan)}, t0 + p.t_plan_s)
        for k, (t, images) in enumerate(record.images):
            for cam, img in images:
                log.write_image(t0 + t, cam, img, k)
    t_end = t0 + (record.truth_t_s[-1] if record is not None and record.truth_t_s else 0.0)
    doc = result.to_dict()
    doc.update(serve_state=_vec(serve.state), bounce_m=_vec(serve.bounce_m), t0_s=t0)
    log.write_figures("ball", doc, t_end)
