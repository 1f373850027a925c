"""Warming up a hitting policy and its ball filter before the first real ball (real-time processes).

A fresh process pays one-time costs at its first ball: numba kernels compiled or loaded from their cache
(ball flight, the return's outcome), scipy's solvers and pinocchio called for the first time. In process
the playing session does not count them; live they arrive exactly when the first ball's first
observations do: in ``rt2 play --live`` the first ball's filter and policy fell ~0.2 s behind and the
ball was lost in every run. :func:`warm_up` pays them beforehand, on a nominal served ball, against a
robot stand-in that only reports rest and keeps what it is sent (nothing reaches a real robot).
"""

from __future__ import annotations

import time

import numpy as np

from policies.ball_model import BallParams, TableGeometry, simulate
from robot_models.robot_interface import JointSamples, JointState

__all__ = ["warm_up"]

#: a served ball of the simulated lab's launcher (from x = 1.7 m towards the robot; bounces at x ~ -0.7 m)
NOMINAL_SERVE = np.array([1.7, 0.0, 1.05, -4.2, 0.0, 2.9, 0.0, 0.0, 0.0])


class _RestingRobot:
    """The robot for a warm-up: at rest at ``q``; commands are kept, never sent anywhere."""

    def __init__(self, q: np.ndarray, control_rate_hz: float):
        self.q = np.asarray(q, float)
        self.control_rate_hz, self.n_joints = float(control_rate_hz), len(self.q)
        self.commands = 0

    def read_state(self) -> JointState:
        return JointState(0.0, self.q.copy(), np.zeros(self.n_joints))

    def command_trajectory(self, t_s, q, qdot=None) -> None:
        self.commands += 1

    def advance_to(self, t_s: float) -> JointSamples:
        n = self.n_joints
        return JointSamples(np.zeros(0), np.zeros((0, n)), np.zeros((0, n)))


def warm_up(policy, ball_filter, *, rate_hz: float = 180.0, params: BallParams | None = None,
            noise_m: float = 1e-3, seed: int = 0) -> dict:
    """Play one nominal served ball through ``ball_filter`` and ``policy`` (observations at ``rate_hz`` with
    ``noise_m`` of noise, a policy step every 2 ms of ball time until it commits), then reset both.

    Returns {"seconds": wall time, "plans": plans made, "commands": trajectories the stand-in received}."""
    from tracker import BallObservation, Status

    t0 = time.perf_counter()
    params = params or BallParams.load()
    rng = np.random.default_rng(seed)
    t_obs = np.arange(1.0, 1.2 * rate_hz) / rate_hz
    truth, _ = simulate(NOMINAL_SERVE, t_obs, params, TableGeometry())
    robot = _RestingRobot(policy.q_ready, policy.options.control_rate_hz)
    cov = np.eye(3) * noise_m**2
    ball_filter.reset()
    policy.reset(q_ready=robot.q)
    k, plans = 0, 0
    for t in np.arange(0.0, 1.2, 1.0 / policy.options.control_rate_hz):
        while k < len(t_obs) and t_obs[k] <= t:
            pos = truth[k, :3] + rng.normal(0.0, noise_m, 3)
            ball_filter.update(BallObservation(float(t_obs[k]), pos, cov, 3, np.ones(3, bool), Status.OK, 0.0,
                                               "warm-up"))
            k += 1
        step = policy.step(float(t), ball_filter.predict, robot)
        plans += step.plan is not None
        if step.status in ("committed", "done"):  # PolicyStatus values (a StrEnum; policies.hitting imports this module)
            break
    ball_filter.reset()
    policy.reset(q_ready=robot.q)
    return {"seconds": time.perf_counter() - t0, "plans": plans, "commands": robot.commands}
