"""What the hitting policy's tests share (their fixtures -- the robot, the shipped primitive, the ball model -- are
in conftest.py): a perfect ball prediction, and a robot stand-in that reports rest and records what it is sent."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from policies import TableGeometry, simulate


@dataclass
class Prediction:
    t_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    covariance_m2: np.ndarray


def predictor(state, t0, params, std_m=0.005):
    """A perfect ball prediction from the true state at t0 (with a small isotropic covariance)."""

    def predict(t_query):
        t = np.asarray(t_query, float)
        out, _ = simulate(state, t, params, TableGeometry(), t0_s=t0)
        cov = np.broadcast_to(np.eye(3) * std_m**2, (len(t), 3, 3)).copy()
        return Prediction(t, out[:, :3], out[:, 3:6], cov)

    return predict


class RecordingWam:
    """Records commands; reports a fixed rest posture."""

    control_rate_hz, n_joints = 500.0, 7

    def __init__(self, q):
        self.q = np.asarray(q, float)
        self.commands = []

    def read_state(self):
        from robot_models.robot_interface import JointState

        return JointState(0.0, self.q.copy(), np.zeros(7))

    def command_trajectory(self, t_s, q, qdot=None):
        self.commands.append((np.asarray(t_s), np.asarray(q), qdot))
