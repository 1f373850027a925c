"""Many served balls per configuration (tracker x filter x source), in worker processes, reproducibly.

Seeds: ball i of a run with ``seed`` uses ``SeedSequence(seed).spawn(balls)[i]``, split into the serve's
seed (the launcher) and the session's (observation noise, the WAM's zero offsets and noise, the frame
phase). So every configuration of ``rt2 play compare`` plays the same served balls with the same robot
errors (common random numbers), and the results do not depend on ``--workers`` or on the order the
workers finish in (results are put back in ball order). The balls run on :mod:`harness.common.executor` (this
process, local worker processes, or Ray: ``--ray``).

The success rate's 95 % interval is Wilson's score interval (scipy ``binomtest(...).proportion_ci``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from harness.common.progress import progress_bar

from harness.common.executor import Executor, SweepOptions, SweepStopped
from harness.experiments.play.profiles import PROFILES, TrackerProfile, profile_for

__all__ = ["PlayConfig", "ball_seeds", "run_configuration", "summarise", "wilson_interval"]

DEFAULT_PROMP = Path(__file__).resolve().parents[3] / "data" / "promp" / "wam_hitting.npz"


@dataclass(frozen=True)
class PlayConfig:
    """One configuration: tracker kind, filter name, observation source, and the tracker's profile."""

    tracker: str
    filter: str
    source: str = "synthetic"
    profile: TrackerProfile | None = None
    promp_path: str = str(DEFAULT_PROMP)
    rig: str = "lab4_vga"
    scene: str = "default"  #: vision source: a preset of harness.experiments.play.play_scene.SCENES
    record: bool = False
    record_images_every: int = 0
    policy: dict = field(default_factory=dict)
    plan_latency_s: float = 0.0  #: the policy's modelled planning time (SessionOptions.plan_latency_s)
    robot: str = "wam"  #: the arm: a shipped arm's name or a robot config's path (harness.sim.robot.arms.load_arm)

    def resolved_profile(self) -> TrackerProfile:
        return self.profile if self.profile is not None else profile_for(self.tracker, PROFILES)


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (scipy)."""
    from scipy.stats import binomtest

    if n < 1 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n and n >= 1, got successes={successes}, n={n}")
    ci = binomtest(int(successes), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


def ball_seeds(seed: int, balls: int) -> list[tuple[np.random.SeedSequence, np.random.SeedSequence]]:
    """(serve seed, session seed) of each ball."""
    return [tuple(ss.spawn(2)) for ss in np.random.SeedSequence(int(seed)).spawn(int(balls))]


# ------------------------------------------------------------------------------------ worker side
_WORKER: dict = {}


def build_session(config: PlayConfig, *, wrap_source=None) -> dict:
    """The session objects of one configuration (once per worker process): ``{"config", "session",
    "launcher_params"}``, for :func:`play_ball`.

    wrap_source : callable(source) -> source, applied to the observation source before the session is
    built (``rt2 play profile`` records every observation through it); default: the source itself."""
    from threadpoolctl import threadpool_limits

    from harness.experiments.play.session import PlaySession, SessionOptions
    from harness.experiments.play.sources import make_source
    from tracker.rig_files import resolve_rig
    from policies.ball_model import BallParams
    from policies.filters import make_filter
    from policies.hitting import HittingOptions
    from policies.promp import ProMP
    from harness.sim.robot.arms import load_arm

    threadpool_limits(1)  # 140 x 140 linear algebra: BLAS threads only contend with the other workers
    arm = load_arm(config.robot, check_reach=False)
    kin = arm.kin
    promp = ProMP.load(config.promp_path, robot_id=str(kin.model.name), joint_names=kin.joint_names)
    rig = resolve_rig(config.rig)
    profile = config.resolved_profile()
    if config.source == "vision":
        from harness.experiments.play.play_scene import SCENES

        if config.scene not in SCENES:
            raise ValueError(f"unknown play scene {config.scene!r}; valid: {sorted(SCENES)}")
        kwargs = {"kinematics": kin, "scene_options": SCENES[config.scene]}
    else:
        kwargs = {}
    source = make_source(config.source, rig, profile, **kwargs)
    if wrap_source is not None:
        source = wrap_source(source)
    session = PlaySession(kin, promp, source, lambda: make_filter(config.filter), profile,
                          policy_options=HittingOptions(**config.policy), sim_options=arm.sim_options,
                          options=SessionOptions(plan_latency_s=config.plan_latency_s))
    return {"config": config, "session": session, "launcher_params": BallParams.load()}


def play_ball(built: dict, seed: int, index: int):
    """Ball ``index`` of a run seeded ``seed`` on the objects of :func:`build_session`:
    ``(index, BallResult, record, serve)``. The same ball whatever process plays it."""
    from harness.sim.launcher import BallLauncher

    config = built["config"]
    serve_ss, session_ss = ball_seeds(seed, index + 1)[index]
    serve = BallLauncher(built["launcher_params"], rng=np.random.default_rng(serve_ss)).serve()
    result, record = built["session"].run(serve, session_ss, ball=index, record=config.record,
                                          record_images_every=config.record_images_every)
    return index, result, record, serve


def _play_one(args):
    config, seed, index = args
    if _WORKER.get("config") != config:
        _WORKER.clear()
        _WORKER.update(build_session(config))
    return play_ball(_WORKER, seed, index)


def run_configuration(config: PlayConfig, *, balls: int, seed: int, workers: int = 1, progress: bool = True,
                      on_ball=None, executor: Executor | None = None, stopped: list | None = None) -> list:
    """Play ``balls`` balls of ``config``; returns the BallResults in ball order.

    on_ball(index, result, record, serve) is called in the parent, in ball order (e.g. to log).
    executor : an open :class:`harness.common.executor.Executor` to run on (default: ``workers`` local processes);
    stopped : if a list is given, a sweep stopped early (:class:`harness.common.executor.SweepStopped`) is appended
    to it and the balls that finished are handed to ``on_ball`` and returned (ball order, gaps skipped);
    else the stop propagates."""
    if balls < 1:
        raise ValueError(f"balls must be >= 1, got {balls}")
    if executor is None:
        with Executor(SweepOptions(workers=workers)) as ex:
            return run_configuration(config, balls=balls, seed=seed, progress=progress, on_ball=on_ball, executor=ex,
                                     stopped=stopped)
    jobs = [(config, int(seed), i) for i in range(balls)]
    desc = f"play {config.tracker}+{config.filter} ({config.source})"
    results, buffered, next_i = [None] * balls, {}, 0

    def hand_on(i, item):
        results[i] = item[0]
        if on_ball is not None:
            on_ball(i, *item)

    bar = progress_bar(total=balls, desc=desc, file=sys.stderr, disable=not progress, leave=False)
    try:
        for _, (index, result, record, serve) in executor.map(_play_one, jobs):
            with executor.hold_stop():  # a finished ball is kept and logged whole, or not at all
                buffered[index] = (result, record, serve)
                bar.update(1)
                while next_i in buffered:  # hand results on in ball order
                    hand_on(next_i, buffered.pop(next_i))
                    next_i += 1
    except SweepStopped as stop:
        if stopped is None:
            raise
        stopped.append(stop)
        for i in sorted(buffered):  # finished after a ball still running: keep them too
            hand_on(i, buffered.pop(i))
        return [r for r in results if r is not None]
    finally:
        bar.close()
    return results


def summarise(config: PlayConfig, results: list, seed: int) -> dict:
    """The JSON object of one configuration: tracker, filter, balls, successes, success_rate, ci_low,
    ci_high, plus source, seed, frame rate and latency, and the count of each outcome."""
    n = len(results)
    k = sum(r.success for r in results)
    lo, hi = wilson_interval(k, n)
    outcomes: dict[str, int] = {}
    for r in results:
        outcomes[r.outcome] = outcomes.get(r.outcome, 0) + 1
    no_attempt: dict[str, int] = {}
    for r in results:
        if r.outcome == "no_attempt":
            key = r.reason.split(" (")[0].split(":")[0] if r.reason else "unknown"
            no_attempt[key] = no_attempt.get(key, 0) + 1
    prof = config.resolved_profile()
    return {"tracker": config.tracker, "filter": config.filter, "balls": n, "successes": int(k),
            "success_rate": k / n, "ci_low": lo, "ci_high": hi, "source": config.source, "seed": int(seed),
            "rate_hz": prof.rate_hz, "latency_ms": 1e3 * prof.latency_s, "plan_latency_ms": 1e3 * config.plan_latency_s,
            "outcomes": outcomes,
            "no_attempt_reasons": no_attempt,
            "attempted": int(sum(r.attempted for r in results)),
            "hit": int(sum(r.contact_t_s is not None for r in results))}
