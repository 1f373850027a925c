"""The real-time stand-in for the real lab of ``rt2 play --live``: the simulated WAM AND the ball world in one process.

``rt2 robot serve --sim --world play --balls N --seed S`` runs :class:`WorldBridge`: the robot link of
``rt2 robot serve --sim`` (docs/robot_link.md) plus, in the same control loop, the ball world of the
in-process session (harness/experiments/play/session.py): launcher serves, 1 ms physics with swept contacts, the
racket from the TRUE joints of the simulated WAM at every control tick, and the end rule and outcome of
``harness.experiments.play.session`` (``ball_over``, ``world_summary``). Racket contact needs the true arm every
millisecond, so the world lives next to the robot, never behind a network hop.

Ball i of a session with seed S uses the in-process run's seeds (``harness.experiments.play.experiment.ball_seeds``):
the same serve, and at the serve a fresh simulated WAM at rest at its home posture with the ball's zero
offsets -- exactly the robot the in-process run gives that ball (the simulated lab puts the arm back to
rest between balls; robot time runs on). So live and in-process runs of one seed differ only by timing.

Two more PUB sockets besides the robot link:

* **truth** (``truth_endpoint``): every control tick, one msgpack message
  ``{"v": 1, "t_ns": host CLOCK_MONOTONIC ns, "q": [7] true joints, "balls": [[x, y, z]] or [], "seq": n}``
  -- the lab truth stream's message (docs/play.md, "Live"), what a simulated tracker renders or samples;
* **world** (``world_endpoint``): JSON events, ``{"v": 1, "type": "ball", "ball": i, "balls": N,
  "t_serve_ns": host ns, "t_serve_robot_ns": robot ns, "serve": {...}}`` announced ``announce_s`` before
  the serve; ``{"v": 1, "type": "outcome", "ball": i, "t_ns": host ns, "world": world_summary, "lag_ms": the
  simulation's largest lag behind the robot clock during the ball}`` when the ball's session ends; ``{"v": 1, "type": "end", "balls": N}`` after the last one (repeated every second,
  so a late subscriber still learns it).

The first serve waits for a commanding client (its first ``trajectory``, ``hold`` or ``heartbeat``) plus
``start_delay_s``; a new ball is served ``gap_s`` after the last one ended.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field

import numpy as np
import zmq

from harness.sim.lab_truth import TruthError, TruthPublisher
from harness.sim.physics import BallWorld, EventKind, RacketState
from harness.experiments.play.session import SessionOptions, ball_over, lerp_racket, world_summary
from harness.link.bridge_sim import BridgeOptions, SimBridge
from harness.sim.robot.simulated_wam import SimulatedWam, SimWamOptions

__all__ = ["WorldBridge", "WorldOptions", "ball_robot_seed"]

log = logging.getLogger("rt2.play.world")
_MAX_CHUNK_TICKS = 8
_FAR_M = 0.8  #: beyond this from the racket no contact within the next ticks is possible
_FK_EVERY = 10  #: ticks between racket poses while the ball is far


def ball_robot_seed(seed: int, ball: int) -> int:
    """The simulated WAM's seed of ball ``ball`` in a session of ``seed``: the in-process run's
    (``PlaySession.run`` spawns (source, wam, phase) from the ball's session seed)."""
    from harness.experiments.play.experiment import ball_seeds

    _, session_ss = ball_seeds(seed, ball + 1)[ball]
    return int(session_ss.spawn(3)[1].generate_state(1)[0])


def draw_serve(seed: int, ball: int):
    """Ball ``ball``'s serve in a session of ``seed``: the in-process run's (``harness.experiments.play.experiment``)."""
    from harness.sim.launcher import BallLauncher
    from harness.experiments.play.experiment import ball_seeds
    from policies.ball_model import BallParams

    serve_ss, _ = ball_seeds(seed, ball + 1)[ball]
    return BallLauncher(BallParams.load(), rng=np.random.default_rng(serve_ss)).serve()


def _warm_up_world(params, session, kinematics) -> None:
    """One racket pose and a few world steps before the clock starts (first calls compile / load)."""
    fid = kinematics.frame_id("racket")
    T, J = kinematics.fk_and_jacobian(kinematics.q_home, fid)
    r = RacketState.from_pose(T, J[:3] @ np.zeros(kinematics.n_joints))
    w = BallWorld(params, session.world)
    w.reset(np.array([1.8, 0.0, 1.0, -4.5, 0.0, 0.5, 0.0, 0.0, 0.0]))
    for _ in range(5):
        w.step(r, r)


@dataclass(frozen=True)
class WorldOptions:
    """balls : serves in the session; seed : the session's seed (serves and robots as in process);
    truth_bind / world_bind : endpoints of the two streams (``*`` port: a free one);
    start_delay_s : first serve this long after a commanding client appears; gap_s : between balls;
    announce_s : the ``ball`` event this long before its serve; session : the in-process end rule."""

    balls: int
    seed: int = 0
    truth_bind: str = "tcp://127.0.0.1:*"
    world_bind: str = "tcp://127.0.0.1:*"
    start_delay_s: float = 3.0
    gap_s: float = 0.6
    announce_s: float = 0.3
    session: SessionOptions = field(default_factory=SessionOptions)
    sim: SimWamOptions = field(default_factory=SimWamOptions)

    def __post_init__(self):
        if isinstance(self.balls, bool) or not isinstance(self.balls, int) or self.balls < 1:
            raise ValueError(f"--balls must be an integer >= 1, got {self.balls!r}")
        for name in ("start_delay_s", "gap_s", "announce_s"):
            if not 0 <= float(getattr(self, name)) <= 60:
                raise ValueError(f"WorldOptions.{name} must be in [0, 60] s, got {getattr(self, name)!r}")
        if self.announce_s > self.gap_s or self.announce_s > self.start_delay_s:
            raise ValueError(f"WorldOptions.announce_s ({self.announce_s}) must not exceed gap_s and start_delay_s")


class WorldBridge(SimBridge):
    """The simulated WAM behind the robot link plus the ball world (module docstring)."""

    def __init__(self, kinematics, world: WorldOptions, options: BridgeOptions = BridgeOptions(), *, context=None):
        from policies.ball_model import BallParams

        self.world_options = world
        self.params = BallParams.load()
        # drawing a serve takes ~1-3 s of CPU: all of them are drawn before the robot's clock starts
        self._serves = [draw_serve(world.seed, i) for i in range(world.balls)]
        super().__init__(SimulatedWam(kinematics, world.sim, seed=ball_robot_seed(world.seed, 0)), options,
                         context=context)
        _warm_up_world(self.params, world.session, kinematics)
        try:
            self._world_truth = TruthPublisher(world.truth_bind, context=self._ctx)
        except TruthError as exc:
            self.close()
            raise ValueError(str(exc)) from None
        self._world_pub = self._ctx.socket(zmq.PUB)
        self._world_pub.setsockopt(zmq.LINGER, 0)
        try:
            self._world_pub.bind(world.world_bind)
        except zmq.ZMQError as exc:
            self.close()
            raise ValueError(f"cannot bind the world's event stream at {world.world_bind}: {exc}") from None
        self.truth_endpoint = self._world_truth.address
        self.world_endpoint = self._world_pub.getsockopt_string(zmq.LAST_ENDPOINT)
        self._fid = kinematics.frame_id("racket")
        self._next_ball = 0
        self._serve_tick: int | None = None  # the announced ball leaves the launcher at this tick
        self._earliest_tick: int | None = None  # no serve before this tick (start delay, gap after a ball)
        self._pending = None  # (ball index, Serve) announced, not yet served
        self._ball = None  # the ball in flight: dict of its world and bookkeeping
        self._ended_ns: int | None = None
        self.outcomes: list[dict] = []

    def close(self) -> None:
        super().close()
        if getattr(self, "_world_truth", None) is not None:
            self._world_truth.close()
        if getattr(self, "_world_pub", None) is not None:
            self._world_pub.close(linger=0)

    # -- clocks -----------------------------------------------------------------------------------
    def _host_ns(self, robot_ns: int) -> int:
        return int(robot_ns + self.epoch_ns - self.options.clock_skew_ns)

    def _racket(self, q, qd) -> RacketState:
        T, J = self.kin.fk_and_jacobian(q, self._fid)
        return RacketState.from_pose(T, J[:3] @ qd)

    def _send_event(self, doc: dict) -> None:
        self._world_pub.send(json.dumps({"v": 1, **doc}, allow_nan=False).encode())

    # -- the control loop -------------------------------------------------------------------------
    def _run_ticks(self) -> None:
        target = self.robot_ns() // self.dt_ns
        if self._ball is not None:  # how far the simulation is behind the robot clock (a machine short of CPU)
            self._ball["lag_ms"] = max(self._ball["lag_ms"], (target - self._ticks) * self.dt_ns / 1e6)
        self._schedule()
        while self._ticks < target:
            if self._serve_tick is not None and self._ticks >= self._serve_tick:
                self._serve()
            stop = target if self._serve_tick is None else min(target, max(self._serve_tick, self._ticks + 1))
            stop = min(stop, self._ticks + _MAX_CHUNK_TICKS)  # behind the clock: states keep flowing while catching up
            samples = self.wam.step(int(stop - self._ticks))
            self._ticks = int(stop)
            self._publish_states(samples)
            self._world_ticks(samples)

    def _schedule(self) -> None:
        """Announce the next ball once a client commands, the previous ball is over and its serve is drawn;
        repeat ``end`` after the last one."""
        o = self.world_options
        if self._pending is not None and self.robot_ns() - self._announced_ns > 0.1e9:
            self._send_event(self._announcement)  # again, for a subscriber that joined after the first one
            self._announced_ns = self.robot_ns()
        if self._ball is not None or self._pending is not None:
            return
        if self._next_ball >= o.balls:
            now = self.robot_ns()
            if self._ended_ns is None or now - self._ended_ns > 1e9:
                self._ended_ns = now
                self._send_event({"type": "end", "balls": o.balls})
            return
        if self._last_contact_ns is None:
            return  # nobody commands the robot yet
        if self._earliest_tick is None:  # the first ball: a delay after the client appeared
            self._earliest_tick = self._ticks + int(round(o.start_delay_s * 1e9 / self.dt_ns))
        i = self._next_ball
        serve = self._serves[i]
        self._serve_tick = max(self._earliest_tick, self._ticks + int(round(o.announce_s * 1e9 / self.dt_ns)))
        self._pending = (i, serve)
        t_robot = int(self._serve_tick * self.dt_ns)
        self._announcement = {"type": "ball", "ball": i, "balls": o.balls, "t_serve_ns": self._host_ns(t_robot),
                              "t_serve_robot_ns": t_robot,
                              "serve": {"state": [float(v) for v in serve.state],
                                        "bounce_m": [float(v) for v in serve.bounce_m],
                                        "speed_mps": float(serve.speed_mps), "spin_kind": str(serve.spin_kind)}}
        self._send_event(self._announcement)
        self._announced_ns = self.robot_ns()

    def _serve(self) -> None:
        """Ball ``_pending`` leaves the launcher now: a fresh simulated WAM at rest (the ball's), a fresh world."""
        i, serve = self._pending
        o = self.world_options
        self._pending, self._serve_tick = None, None
        self.wam = SimulatedWam(self.kin, o.sim, seed=ball_robot_seed(o.seed, i))
        self.wam_origin_ns = int(self._ticks * self.dt_ns)
        self._bias = np.asarray(self.wam.bias_rad, float).tolist()
        self.mode = "idle"
        world = BallWorld(self.params, o.session.world)
        world.reset(serve.state)
        st = self.wam.true_state()
        self._ball = {"index": i, "world": world, "racket": self._racket(st.q, st.qdot),
                      "closest": np.inf, "t_contact": None, "since_fk": 0, "lag_ms": 0.0}
        self._next_ball = i + 1

    def _world_ticks(self, samples) -> None:
        """Two 1 ms world steps per control tick with the racket from the true joints; one truth message per tick."""
        b = self._ball
        n_sub = max(int(round(self.wam.dt_s / self.world_options.session.world.dt_s)), 1)
        for k in range(len(samples)):
            t_robot = self.wam_origin_ns + int(round(samples.t_s[k] * 1e9))
            balls = []
            if b is not None:
                world = b["world"]
                prev = b["racket"]
                b["since_fk"] += 1
                # the racket from the true joints every tick while the ball is within FAR_M of it (and every
                # FK_EVERY ticks otherwise, to know where it is): a contact needs the ball within ~10 cm, the
                # racket moves < 10 cm in FK_EVERY ticks, so beyond FAR_M no contact is possible and the world
                # steps the free flight (as the in-process session does there, at a fraction of the cost)
                near = float(np.linalg.norm(world.state[:3] - prev.center_m)) < _FAR_M
                if near or b["since_fk"] >= _FK_EVERY:
                    racket_next, b["since_fk"] = self._racket(samples.q_true[k], samples.qdot_true[k]), 0
                else:
                    racket_next = None
                for sub in range(n_sub):
                    f0, f1 = sub / n_sub, (sub + 1) / n_sub
                    if near and racket_next is not None:
                        rb = lerp_racket(prev, racket_next, f1)
                        events = world.step(lerp_racket(prev, racket_next, f0), rb)
                        b["closest"] = min(b["closest"], float(np.linalg.norm(world.state[:3] - rb.center_m)))
                    else:
                        events = world.step(None, None)
                        b["closest"] = min(b["closest"], float(np.linalg.norm(world.state[:3] - prev.center_m)))
                    if b["t_contact"] is None and any(e.kind == EventKind.RACKET for e in events):
                        b["t_contact"] = world.t_s
                    if world.done:
                        break
                if racket_next is not None:
                    b["racket"] = racket_next
                balls = [world.state[:3]]
                if ball_over(world, float(samples.t_s[k]), b["t_contact"], self.world_options.session):
                    summary = world_summary(world, self.world_options.session.world.table, b["closest"])
                    self.outcomes.append({"ball": b["index"], **summary})
                    self._send_event({"type": "outcome", "ball": b["index"], "t_ns": self._host_ns(t_robot),
                                      "world": summary, "lag_ms": b["lag_ms"]})
                    log.info("ball %d: %s", b["index"], summary["outcome"] or "no racket contact")
                    self._ball = b = None
                    self._earliest_tick = self._ticks - len(samples) + k + 1 + int(
                        round(self.world_options.gap_s * 1e9 / self.dt_ns))
                    balls = []
            self._world_truth.publish(self._host_ns(t_robot), samples.q_true[k], balls)


