"""Distractors that come and go: a second orange ball in the person's hand, stray balls rolling on the floor.

A static orange object larger than the ball would win RTBlob's arg-max in every frame; a real lab
session is different: now and then someone plays with a ball, a stray ball rolls by, and each camera
sees it for a while, partly hidden by the person, the table or the robot, or not at all. The
:class:`DistractorSchedule` draws these *episodes* from the session seed, as a function of time only
(any worker can ask for any frame; the schedule extends itself in time order, so the answer does not
depend on the order of the questions):

* **held orange ball** (``orange_ball_gap_s``): the person takes an orange ball out and holds it closed
  in the right hand (about half of it visible from above; the hand keeps moving over the table corner
  next to the robot) for ``orange_ball_hold_s``;
  in a share ``p_toss`` of the episodes they toss it straight up and catch it again and again (apex
  0.15-0.45 m above the hand, a pause of 0.3-0.8 s in the hand between tosses). Then it goes back into
  a pocket (not drawn). During an episode it replaces the white ball the hand holds otherwise;
* **rolling ball** (``rolling_ball_gap_s``): an orange ball rolls across the floor at
  ``rolling_speed_mps`` (slowing by 0.1 m/s^2), passing a point drawn on the floor of the court
  (x -3.5..3.0 m, y -2.5..2.5 m) halfway through its 2-5 s, never within 0.5 m of the robot's base;
  the ceiling cameras over one end see the
  floor of the other end, the table top hides it from above, the robot and the person now and then;
  afterwards it is picked up (not drawn).

Gaps between episodes are exponential with the given means (None: never). ``summary(duration_s)``
gives the share of time each kind is present; how often a camera actually sees it is measured by the
experiment (docs/accuracy.md).
"""

from __future__ import annotations

import numpy as np

from harness.sim import lab
from harness.sim.render.scene_state import Ball

__all__ = ["DistractorSchedule", "GRAVITY_MPS2", "ROLL_DECEL_MPS2"]

GRAVITY_MPS2 = 9.81
ROLL_DECEL_MPS2 = 0.1


class DistractorSchedule:
    """The episodes of one session (see the module docstring).

    options : :class:`harness.experiments.accuracy.session_scene.SceneOptions` (fields ``orange_ball_gap_s``,
    ``orange_ball_hold_s``, ``p_toss``, ``rolling_ball_gap_s``, ``rolling_speed_mps``)
    seed_sequence : a ``numpy.random.SeedSequence`` of this session's schedule
    """

    def __init__(self, options, seed_sequence: np.random.SeedSequence):
        held_seq, roll_seq = seed_sequence.spawn(2)
        self._held = _Stream(options.orange_ball_gap_s, np.random.default_rng(held_seq), lambda rng, t0: _held_episode(rng, t0, options))
        self._roll = _Stream(options.rolling_ball_gap_s, np.random.default_rng(roll_seq), lambda rng, t0: _rolling_episode(rng, t0, options))

    def held_ball(self, t_s: float, in_hand_m) -> Ball | None:
        """The orange ball in or above the person's hand at ``t_s``, or None. in_hand_m : (3,) world, where
        a ball closed in the hand is (``harness.sim.render.scenes.ball_in_hand(..., grip="fist")``, about half
        visible); a toss starts and ends there."""
        ep = self._held.at(t_s)
        if ep is None:
            return None
        tip = np.asarray(in_hand_m, float)
        for start, v0 in ep["tosses"]:
            tau = t_s - start
            if 0.0 <= tau <= 2.0 * v0 / GRAVITY_MPS2:  # in the air: a vertical throw above the moving hand
                return Ball(tip + [0.0, 0.0, v0 * tau - 0.5 * GRAVITY_MPS2 * tau * tau],
                            (0.0, 0.0, v0 - GRAVITY_MPS2 * tau), "orange")
        return Ball(tip, (0.0, 0.0, 0.0), "orange")

    def rolling_balls(self, t_s: float) -> list:
        """The stray balls rolling on the floor at ``t_s`` (0 or 1 Ball)."""
        ep = self._roll.at(t_s)
        if ep is None:
            return []
        tau = t_s - ep["start_s"]
        speed = max(ep["speed_mps"] - ROLL_DECEL_MPS2 * tau, 0.0)
        d = ep["direction"]
        p = ep["start_m"] + _rolled_m(ep["speed_mps"], tau) * d
        return [Ball([p[0], p[1], lab.BALL_RADIUS_M], speed * d, "orange")]

    def summary(self, t_end_s: float, t_start_s: float = 0.0) -> dict:
        """Per kind of episode: how many overlap [t_start_s, t_end_s], and the share of that time they are on."""
        out = {}
        span = t_end_s - t_start_s
        for name, stream in (("held_orange_ball", self._held), ("rolling_ball", self._roll)):
            eps = [e for e in stream.until(t_end_s) if e["end_s"] > t_start_s]
            on = sum(max(0.0, min(e["end_s"], t_end_s) - max(e["start_s"], t_start_s)) for e in eps)
            out[name] = {"episodes": len(eps), "share_of_time": round(on / span, 4) if span > 0 else 0.0}
            if name == "held_orange_ball":
                out[name]["with_tosses"] = sum(bool(e["tosses"]) for e in eps)
        return out


class _Stream:
    """Episodes of one kind in time order, drawn lazily (always in the same order from one generator)."""

    def __init__(self, mean_gap_s, rng, make):
        self.mean_gap_s, self.rng, self.make = mean_gap_s, rng, make
        self.episodes: list[dict] = []
        self._t = 0.0

    def _extend(self, t_s: float) -> None:
        while self.mean_gap_s is not None and self._t <= t_s:
            ep = self.make(self.rng, self._t + self.rng.exponential(self.mean_gap_s))
            self.episodes.append(ep)
            self._t = ep["end_s"]

    def at(self, t_s: float):
        self._extend(t_s)
        for ep in reversed(self.episodes):
            if ep["start_s"] <= t_s < ep["end_s"]:
                return ep
            if ep["end_s"] <= t_s:
                return None
        return None

    def until(self, t_s: float) -> list:
        self._extend(t_s)
        return [e for e in self.episodes if e["start_s"] < t_s]


def _held_episode(rng, t0: float, options) -> dict:
    end = t0 + rng.uniform(*options.orange_ball_hold_s)
    tosses = []
    if rng.random() < options.p_toss:
        t = t0 + rng.uniform(0.2, 0.6)
        while True:
            v0 = np.sqrt(2 * GRAVITY_MPS2 * rng.uniform(0.15, 0.45))
            if t + 2 * v0 / GRAVITY_MPS2 > end:
                break
            tosses.append((t, v0))
            t += 2 * v0 / GRAVITY_MPS2 + rng.uniform(0.3, 0.8)
    return {"start_s": t0, "end_s": end, "tosses": tosses}


def _rolled_m(speed: float, t: float) -> float:
    """Distance rolled after ``t`` seconds from ``speed`` under the constant deceleration."""
    t = min(t, speed / ROLL_DECEL_MPS2)
    return speed * t - 0.5 * ROLL_DECEL_MPS2 * t * t


def _rolling_episode(rng, t0: float, options) -> dict:
    duration = rng.uniform(2.0, 5.0)
    speed = rng.uniform(*options.rolling_speed_mps)
    for _ in range(50):  # a path that does not run through the robot's pedestal (0.5 m around its base)
        ang = rng.uniform(0, 2 * np.pi)
        d = np.array([np.cos(ang), np.sin(ang)])
        via = rng.uniform([-3.5, -2.5], [3.0, 2.5])
        start = via - _rolled_m(speed, duration / 2) * d  # the via point is passed halfway
        along = np.clip((lab.ROBOT_BASE_M[:2] - start) @ d, 0.0, _rolled_m(speed, duration))
        if np.linalg.norm(start + along * d - lab.ROBOT_BASE_M[:2]) > 0.5:
            break
    return {"start_s": t0, "end_s": t0 + duration, "speed_mps": speed, "direction": np.array([d[0], d[1], 0.0]),
            "start_m": np.array([start[0], start[1], 0.0])}
