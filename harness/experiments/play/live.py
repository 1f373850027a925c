"""``rt2 play --live``: the hitting policy as its own process, over the tracker stream and the robot link.

The policy process (:func:`play_live`) subscribes to a tracker's rt2 stream (harness/live/publish.py:
``rt2 track`` or ``rt2 play observe``) and to the world's serve/outcome events (harness/experiments/play/world.py),
runs the chosen ball filter and the unchanged :class:`policies.hitting.HittingPolicy`, and commands the
robot through :class:`harness.link.WamClient` in real time. Per ball:

* the world announces the serve (robot and host time); at the first robot state after it the filter
  and the policy are reset (``q_ready`` = the reported joints), exactly as ``PlaySession.run`` does at 0;
* the policy's clock is **ball time on the robot clock** (0 at the serve): a thin
  ``WamInterface`` adapter shifts read_state / command_trajectory by the serve's robot time; an
  observation's capture time (host CLOCK_MONOTONIC) goes to ball time through the link's clock-offset
  estimate;
* each loop: take the robot states that arrived, deliver every observation that arrived (in order),
  then ``policy.step(now + lead, filter.predict, wam)``: ``now`` is the robot clock read through the
  offset estimate; ``lead`` (``plan_lead_s``; default: the longest of the last 5 planning steps of the
  same kind, at most 0.2 s) is how late a plan reaches the robot, so a planned movement starts after it
  arrives. The two kinds take very different times: the first plan of a ball (from rest, no warm start,
  every candidate tried) costs several re-plans (which continue a commanded movement from a warm start),
  so each kind is timed apart -- one slow first plan must not push every re-plan of the ball late;
* before the robot link opens, the policy and the filter are warmed up on a nominal ball against a robot
  stand-in (:func:`prepare_policy`, ``HittingPolicy.warm_up``): a fresh process's one-time costs (compiled
  kernels, first solver calls) had held the first ball's first steps ~0.2 s back and lost that ball in
  every run;
* the world reports the outcome (its ``world_summary``); the result is
  ``harness.experiments.play.session.ball_result`` of the policy and that summary -- the in-process rule.

Latency budget (:func:`latency_budget`), per run: exposure -> observation at the policy (capture time to
arrival in this process), observation -> command (arrival of the newest observation the plan used to the
trajectory request's send), command -> robot (send to the arrival here of the first robot state tracking
the new trajectory: the bridge's reaction plus the state's way back).

:func:`play_live_local` is the one-command form: it starts the world+robot bridge (``rt2 robot serve
--sim --world play``) and the tracker (``rt2 play observe``) as child processes and stops them at the end,
on an error and on SIGINT.
"""

from __future__ import annotations

import collections
import contextlib
import json
import sys
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import zmq

from harness.common.gc_pauses import GcPauses, frozen_gc
from robot_models.robot_interface import JointState

__all__ = ["MAX_PLAN_LEAD_S", "BallClockWam", "LivePolicy", "LiveRun", "latency_budget", "play_live", "play_live_local", "prepare_policy"]

#: the longest lead a plan is made with (s): a planning step that takes longer reaches the robot after the moment it
#: planned from (the robot may then refuse it: its start lies behind the arm), whatever the lead
MAX_PLAN_LEAD_S = 0.2


class BallClockWam:
    """A :class:`~robot_models.robot_interface.WamInterface` on ball time: robot time minus ``t0_s``."""

    def __init__(self, wam):
        self.wam, self.t0_s = wam, 0.0
        self.control_rate_hz, self.n_joints = wam.control_rate_hz, wam.n_joints
        self.sent: list[tuple[int, int]] = []  # (send start host ns, trajectory id)

    def read_state(self) -> JointState:
        st = self.wam.read_state()
        return JointState(st.t_s - self.t0_s, st.q, st.qdot)

    def command_trajectory(self, t_s, q, qdot=None) -> None:
        t_send = time.monotonic_ns()
        self.wam.command_trajectory(np.asarray(t_s, float) + self.t0_s, q, qdot)
        self.sent.append((t_send, self.wam.last_command_id))

    def advance_to(self, t_s: float):
        return self.wam.advance_to(float(t_s) + self.t0_s)


@dataclass
class LiveRun:
    """What a live session gives back: results (BallResult, ball order), the latency samples (ms), why it stopped."""

    results: list = field(default_factory=list)
    exposure_to_obs_ms: list = field(default_factory=list)
    obs_to_command_ms: list = field(default_factory=list)
    command_to_robot_ms: list = field(default_factory=list)
    plan_step_ms: list = field(default_factory=list)
    first_plan_ms: list = field(default_factory=list)  #: the planning steps that made (or tried) a ball's first plan
    world_lag_ms: list = field(default_factory=list)  #: per ball, the world+robot simulation's largest lag behind its clock
    warm_up_s: float = 0.0  #: the policy's and filter's warm-up before the first ball (HittingPolicy.warm_up)
    refused: int = 0
    error: str | None = None
    gc: dict | None = None  #: the garbage collector's runs while playing (GcPauses.summary; what was alive before, frozen)


def latency_budget(run: LiveRun) -> dict:
    """p50 / p95 / max (ms) and count of each stage of the latency budget."""
    out = {}
    for name in ("exposure_to_obs_ms", "obs_to_command_ms", "command_to_robot_ms", "plan_step_ms", "first_plan_ms",
                 "world_lag_ms"):
        v = np.asarray(getattr(run, name), float)
        out[name] = {"n": int(v.size)} if v.size == 0 else {
            "n": int(v.size), "p50": float(np.percentile(v, 50)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}
    return out


def _observation(msg: dict, t_ball_s: float):
    from tracker import BallObservation, Status

    pos = None if msg["position_m"] is None else np.asarray(msg["position_m"], float)
    cov = None if msg["covariance_m2"] is None else np.asarray(msg["covariance_m2"], float)
    return BallObservation(t_s=t_ball_s, position_m=pos, covariance_m2=cov, support=int(msg["support"]),
                           inliers=np.asarray(msg["inliers"], bool), status=Status(msg["status"]),
                           latency_s=float(msg["tracker_latency_s"]), tracker=str(msg["tracker"]),
                           notes=tuple(msg["notes"]))


@dataclass
class LivePolicy:
    """The policy process's ball filter and hitting policy, warmed up (:func:`prepare_policy`)."""

    policy: object
    ball_filter: object
    warm_up_s: float


def prepare_policy(kinematics, promp, filter_name: str, policy_options=None) -> LivePolicy:
    """The filter and the hitting policy of a live session, warmed up before the robot link opens: a fresh
    process's one-time costs (compiled kernels -- seconds with a cold numba cache --, first solver calls) are
    paid here, not at the first ball's first observations, and not while the world counts down to its first
    serve. One BLAS thread: the algebra is small (140 x 140), threads would only contend with the world and
    the tracker."""
    from threadpoolctl import threadpool_limits

    from policies.filters import make_filter
    from policies.hitting import HittingOptions, HittingPolicy

    threadpool_limits(1)
    filt = make_filter(filter_name)
    policy = HittingPolicy(promp, kinematics, policy_options or HittingOptions(), ball_params=filt.params)
    return LivePolicy(policy, filt, policy.warm_up(filt)["seconds"])


def play_live(wam, tracker_addr: str, world_addr: str, *, player: LivePolicy, balls: int,
              plan_lead_s: float | None = None, on_ball=None, stop=lambda: False, idle_timeout_s: float = 30.0) -> LiveRun:
    """Play ``balls`` balls live (module docstring) with ``player`` (:func:`prepare_policy`). wam : a connected
    WamClient; on_ball(index, result, record, serve) in ball order. Ends after the balls, at the world's ``end``,
    on ``stop()``, or after ``idle_timeout_s`` without any ball event (ValueError). A lost link raises
    LinkLostError (the run so far is in the exception's ``run`` attribute)."""
    from harness.experiments.play.session import BallRecord, ball_result
    from harness.link.client import LinkLostError
    from policies.hitting import PolicyStatus

    policy, filt = player.policy, player.ball_filter
    run = LiveRun(warm_up_s=player.warm_up_s)
    bwam = BallClockWam(wam)
    ctx = zmq.Context.instance()
    obs_sub, world_sub = ctx.socket(zmq.SUB), ctx.socket(zmq.SUB)
    for sock, addr in ((obs_sub, tracker_addr), (world_sub, world_addr)):
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SUBSCRIBE, b"")
        sock.setsockopt(zmq.RCVHWM, 100_000)
        sock.connect(addr)
    pending: dict[int, dict] = {}  # announced balls
    observations: collections.deque = collections.deque()  # (arrival ns, message) not yet delivered
    cur = None  # the ball being played
    done_balls = next_ball = 0
    world_ended = False
    ended: dict[int, dict] = {}  # ball -> the world's summary, until the ball's result is made
    last_event = time.monotonic()
    plan_times = {kind: collections.deque(maxlen=5) for kind in ("first", "replan")}  # wall s of planning steps
    dt = 1.0 / wam.control_rate_hz
    gc_pauses = GcPauses()
    frozen = contextlib.ExitStack()
    frozen.enter_context(frozen_gc(gc_pauses))  # the policy, its kernels and the filter leave the collector's generations
    try:
        while done_balls < balls and not stop():
            samples = wam.advance_to(wam.t_s)
            if len(samples) == 0:
                samples = wam.advance_to(wam.t_s + dt)  # waits for the next state
            est = wam.clock.estimate()
            while world_sub.poll(0):
                doc = json.loads(world_sub.recv())
                last_event = time.monotonic()
                if doc["type"] == "ball" and next_ball <= int(doc["ball"]) < balls:  # (repeated until the serve)
                    pending[int(doc["ball"])] = doc
                elif doc["type"] == "outcome":
                    ended[int(doc["ball"])] = doc["world"]
                    run.world_lag_ms.append(float(doc.get("lag_ms", 0.0)))
                elif doc["type"] == "end":
                    world_ended = True
            while obs_sub.poll(0):
                observations.append((time.monotonic_ns(), json.loads(obs_sub.recv())))
            if cur is not None and cur["index"] in ended:  # the world has judged the ball in play
                if not cur["started_in_time"]:
                    policy.reason = "the policy process started this ball after its end (the process was busy)"
                result = ball_result(cur["index"], cur["serve"], policy, ended.pop(cur["index"]), cur["n_frames"],
                                     cur["n_positions"], cur["n_accepted"])
                run.results.append(result)
                _finish_latencies(run, bwam, cur)
                if on_ball is not None:
                    on_ball(cur["index"], result, cur["record"], cur["serve"])
                cur, done_balls = None, done_balls + 1
                continue
            if world_ended and cur is None and not pending:
                break  # the world has served every ball (those the policy never saw are missing from the results)
            if time.monotonic() - last_event > idle_timeout_s:
                raise ValueError(f"no serve or outcome from the world at {world_addr} for {idle_timeout_s:g} s")
            if cur is None and pending:
                i = min(pending)
                doc = pending[i]
                if wam.t_s * 1e9 > doc["t_serve_robot_ns"]:  # the first state of the ball's robot
                    del pending[i]
                    next_ball = i + 1
                    bwam.t0_s = doc["t_serve_robot_ns"] * 1e-9
                    bwam.sent.clear()
                    filt.reset()
                    policy.reset(q_ready=wam.read_state().q)
                    sv = doc["serve"]
                    serve = SimpleNamespace(state=np.asarray(sv["state"], float), bounce_m=np.asarray(sv["bounce_m"], float),
                                            speed_mps=sv["speed_mps"], spin_kind=sv["spin_kind"])
                    cur = {"index": i, "serve": serve, "t_serve_host_ns": int(doc["t_serve_ns"]),
                           "t_serve_robot_ns": int(doc["t_serve_robot_ns"]), "n_frames": 0, "n_positions": 0,
                           "n_accepted": 0, "record": BallRecord(), "last_obs_ns": None, "cmd_obs": [],
                           "started_in_time": i not in ended}
                    continue  # (its outcome may be known already: a process busy for seconds)
            if cur is None:
                continue
            rec = cur["record"]
            if len(samples):
                tb = samples.t_s - bwam.t0_s
                keep = tb >= 0
                rec.truth_t_s.extend(tb[keep].tolist())
                rec.truth_m.extend([None] * int(keep.sum()))
                rec.q_reported.extend(samples.q[keep])
                rec.qdot_reported.extend(samples.qdot[keep])
                rec.q_command.extend([None] * int(keep.sum()))
            while observations:
                t_arr, msg = observations.popleft()
                t_cap_ns = int(round(msg["t_s"] * 1e9))
                if t_cap_ns < cur["t_serve_host_ns"]:
                    continue  # a previous ball's
                t_ball = (t_cap_ns + est.offset_ns - cur["t_serve_robot_ns"]) * 1e-9
                obs = _observation(msg, t_ball)
                upd = filt.update(obs)
                cur["n_frames"] += 1
                cur["n_positions"] += obs.position_m is not None
                cur["n_accepted"] += bool(upd.accepted)
                cur["last_obs_ns"] = t_arr
                run.exposure_to_obs_ms.append((t_arr - t_cap_ns) / 1e6)
                rec.observations.append((obs, upd))
                rec.filter_states.append((obs.t_s, filt.state()))
            if policy.status == PolicyStatus.DONE:
                continue
            kind = "first" if policy.plan is None else "replan"
            lead = plan_lead_s if plan_lead_s is not None else min(max(plan_times[kind], default=0.0), MAX_PLAN_LEAD_S)
            t_now = (time.monotonic_ns() + est.offset_ns) * 1e-9 - bwam.t0_s
            n_sent = len(bwam.sent)
            t0 = time.perf_counter()
            try:
                step = policy.step(t_now + lead, filt.predict, bwam)
            except LinkLostError:
                raise
            except ValueError as exc:  # the robot refused a command: the movement goes on as it was
                run.refused += 1
                policy.reason_counts["robot refused"] = policy.reason_counts.get("robot refused", 0) + 1
                step = None
                import logging

                logging.getLogger("rt2.play.live").warning("ball %d: %s", cur["index"], exc)
            took = time.perf_counter() - t0
            if step is None or step.planned:  # a planning step (step None: the robot refused its command)
                plan_times[kind].append(took)
                run.plan_step_ms.append(took * 1e3)
                if kind == "first":
                    run.first_plan_ms.append(took * 1e3)
            if len(bwam.sent) > n_sent and cur["last_obs_ns"] is not None:
                cur["cmd_obs"].append((bwam.sent[-1][0], cur["last_obs_ns"]))
            if step is not None and step.plan is not None:
                rec.plans.append(step.plan)
    except LinkLostError as exc:
        run.error = str(exc)
        exc.run = run
        raise
    finally:
        frozen.close()
        run.gc = gc_pauses.summary()
        obs_sub.close(linger=0)
        world_sub.close(linger=0)
    return run


def _finish_latencies(run: LiveRun, bwam: BallClockWam, cur: dict) -> None:
    for t_send, t_obs in cur["cmd_obs"]:
        run.obs_to_command_ms.append((t_send - t_obs) / 1e6)
    for t_send, cmd_id in bwam.sent:
        t_rx = bwam.wam.command_started.get(cmd_id)
        if t_rx is not None:
            run.command_to_robot_ms.append((t_rx - t_send) / 1e6)


def play_live_local(*, balls: int, seed: int, profile, run_policy, batch: int = 4, observe_args=(),
                    stopping=lambda: False):
    """The one-command form: start the world+robot bridge and the tracker as children, call
    ``run_policy(robot_addr, tracker_addr, world_addr)``, and stop the children (also on errors and SIGINT;
    ``stopping()`` True: the run was stopped by a signal, the children get :data:`STOP_GRACE_S` to leave)."""
    from harness.common.spawn import STOP_GRACE_S, stop_together
    from harness.link.spawn_bridge import ReadyProcess, SimBridgeProcess

    children = []
    try:
        bridge = SimBridgeProcess("--world", "play", "--balls", str(balls), "--seed", str(seed), "--batch", str(batch),
                                  timeout_s=60.0 + 6.0 * balls)  # it draws every serve before it starts
        children.append(bridge)
        tracker = ReadyProcess(["play", "observe", "--truth", bridge.ready["truth"], "--world-stream",
                                bridge.ready["world"], "--tracker", profile.tracker, "--seed", str(seed),
                                "--rate-hz", repr(profile.rate_hz), "--latency-ms", repr(profile.latency_s * 1e3),
                                "--publish", "tcp://127.0.0.1:0", "--ready-json", *observe_args],
                               what="the synthetic tracker (rt2 play observe)")
        children.append(tracker)
        return run_policy(bridge.address, tracker.ready["rt2"], bridge.ready["world"])
    finally:  # SIGTERM to every child first, then wait: they stop side by side, not one after the other;
        # after a signal they get STOP_GRACE_S, then SIGKILL (the 2 s promise, docs/reliability.md)
        signalled = stopping() or isinstance(sys.exc_info()[1], KeyboardInterrupt)
        stop_together(children, STOP_GRACE_S if signalled else None)
