"""Drawing hitting requests and collecting the scripted teacher's demonstrations for ProMP learning.

A request is a hitting point in the robot's hitting region, a hitting time, a racket normal and a
racket velocity (lab world frame). Requests the WAM cannot meet (unreachable, joint or
velocity/acceleration limits) are rejected by the teacher and replaced by new draws; the count of
rejections is reported, so the learned primitive's coverage is stated, not hidden.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

__all__ = ["HitDistribution", "HitRequest", "collect_demonstrations"]


@dataclass(frozen=True)
class HitRequest:
    """x_hit_m (3,) m, t_hit_s s from the movement's start, normal (3,) unit, v_hit_m_s (3,) m/s; lab world."""

    x_hit_m: np.ndarray
    t_hit_s: float
    normal: np.ndarray
    v_hit_m_s: np.ndarray


@dataclass(frozen=True)
class HitDistribution:
    """Uniform ranges (low, high) of the requests.

    x_m, y_m, z_m : hitting region, lab world (robot's side of the table, x < -1.1 m)
    t_hit_s : time from the start of the movement (rest) to the hit
    speed_m_s : racket speed at the hit
    pitch_deg, yaw_deg : racket normal: elevation above the horizontal and azimuth from +x (towards
        the opponent); the velocity direction is drawn likewise from vel_pitch_deg, vel_yaw_deg
    """

    # Where and how the hitting policy (policies/hitting.py, docs/play.md) hits served balls: the launcher's
    # balls (harness/sim/launcher.py) pass x -1.1..-1.5 m within |y| < 0.25 m at z 0.95-1.3 m; the return rule
    # asks for racket normals and velocities pitched 5-35 deg up at 1.0-1.8 m/s; fast strokes (0.4-0.6 s
    # from rest to the hit) so that a movement started on the first predictions arrives in time.
    x_m: tuple = (-1.45, -1.1)
    y_m: tuple = (-0.25, 0.25)
    z_m: tuple = (0.95, 1.3)
    t_hit_s: tuple = (0.4, 0.6)
    speed_m_s: tuple = (1.0, 1.8)
    pitch_deg: tuple = (5.0, 35.0)
    yaw_deg: tuple = (-15.0, 15.0)
    vel_pitch_deg: tuple = (5.0, 35.0)
    vel_yaw_deg: tuple = (-15.0, 15.0)

    def __post_init__(self):
        for name in self.__dataclass_fields__:
            lo, hi = (float(v) for v in getattr(self, name))
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"HitDistribution.{name} must be (low, high) with low <= high, got {getattr(self, name)}")
        if self.t_hit_s[0] <= 0 or self.speed_m_s[0] < 0:
            raise ValueError(f"HitDistribution needs t_hit_s > 0 and speed_m_s >= 0, got {self.t_hit_s}, {self.speed_m_s}")

    def sample(self, rng: np.random.Generator) -> HitRequest:
        def u(name):
            return rng.uniform(*getattr(self, name))

        def direction(pitch_deg, yaw_deg):
            p, y = np.radians(pitch_deg), np.radians(yaw_deg)
            return np.array([np.cos(p) * np.cos(y), np.cos(p) * np.sin(y), np.sin(p)])

        x = np.array([u("x_m"), u("y_m"), u("z_m")])
        t_hit = u("t_hit_s")
        normal = direction(u("pitch_deg"), u("yaw_deg"))
        v = u("speed_m_s") * direction(u("vel_pitch_deg"), u("vel_yaw_deg"))
        return HitRequest(x, float(t_hit), normal, v)


def collect_demonstrations(teacher, n: int, rng: np.random.Generator, dist: HitDistribution = HitDistribution(),
                           *, max_attempts: int | None = None, progress: bool = True, desc: str = "demos"):
    """``n`` demonstrations for requests drawn from ``dist``; infeasible requests are redrawn.

    returns (list of Demonstration, n_rejected, {first words of the reason: count})
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n!r}")
    max_attempts = 20 * n + 20 if max_attempts is None else int(max_attempts)
    demos, reasons, attempts = [], {}, 0
    with tqdm(total=n, desc=desc, file=sys.stderr, disable=not progress, leave=False) as bar:
        while len(demos) < n:
            if attempts >= max_attempts:
                raise ValueError(f"only {len(demos)} of {n} demonstrations after {attempts} requests; the hitting "
                                 f"distribution is mostly infeasible for the arm: {reasons}")
            attempts += 1
            req = dist.sample(rng)
            try:
                demos.append(teacher.demonstrate(req.x_hit_m, req.t_hit_s, req.normal, req.v_hit_m_s, rng))
                bar.update(1)
            except ValueError as exc:
                key = _reason(str(exc))
                reasons[key] = reasons.get(key, 0) + 1
    return demos, attempts - n, reasons


def _reason(message: str) -> str:
    """The kind of a teacher's rejection, without the numbers: 'too short', 'unreachable', ..."""
    for key in ("unreachable", "too short", "follow-through", "above its limit", "joint limits", "back-swing",
                "prepare"):
        if key in message:
            return key
    return message.split(":")[-1].strip()[:40]
